//! Where a study's time goes: the wall-clock phases of one invocation (inputs and targets, the parallel
//! work units, tables, figures, report) and, inside the parallel phases, the time worker threads spend
//! per kind of work (anatomy and scene building; rendering, metrics, registration). Those are summed
//! over threads, so with T threads they add up to about T × their phase's wall time.
//!
//! Thread time is *exclusive*: each thread keeps a stack of the phases it is in, and only the innermost
//! one is charged. A rayon worker waiting inside a render for its stolen tiles runs other units
//! meanwhile; their time goes to their own phases, not to the render that was waiting. Written to `timings.csv` beside the report (not under `tables/`: timings are a
//! property of the run, not of the data, and differ from run to run).

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// The timing table's last row: the invocation's whole wall time.
const TOTAL: &str = "total";

/// A timed phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Reading the inputs and building every target (wall; targets are built in parallel).
    Build,
    /// Reading anatomy inputs, building the phantom, meshing labels, landmarks (build threads).
    Anatomy,
    /// Render scenes: target and marker BVHs, CT μ grids (build threads).
    Scene,
    /// The parallel stage of work units (wall).
    Units,
    /// Thickness renders of targets (unit threads).
    RenderTarget,
    /// Marker-sphere renders for landmark measurement (unit threads).
    RenderMarkers,
    /// CT volume DRRs (unit threads).
    RenderVolume,
    /// Silhouette, contour and image metrics, heatmaps (unit threads).
    Metrics,
    /// Registration trials (unit threads).
    Registration,
    /// Simulated calibrations (unit threads).
    Calibration,
    /// Unit time not in a phase above (result files, bookkeeping), summed over threads.
    UnitThreads,
    Tables,
    Figures,
    Report,
}

const PHASES: [Phase; 14] = [
    Phase::Build,
    Phase::Anatomy,
    Phase::Scene,
    Phase::Units,
    Phase::RenderTarget,
    Phase::RenderMarkers,
    Phase::RenderVolume,
    Phase::Metrics,
    Phase::Registration,
    Phase::Calibration,
    Phase::UnitThreads,
    Phase::Tables,
    Phase::Figures,
    Phase::Report,
];

impl Phase {
    /// Name, clock (`wall` or `threads`) and what the count counts.
    fn describe(self) -> (&'static str, &'static str, &'static str) {
        match self {
            Phase::Build => ("inputs and targets (parallel)", "wall", "targets"),
            Phase::Anatomy => ("  anatomy: phantom, meshes, CT", "threads", "targets"),
            Phase::Scene => ("  scenes: BVHs, CT μ grids", "threads", "renderers"),
            Phase::Units => ("work units (parallel)", "wall", "units"),
            Phase::RenderTarget => ("  rendering: thickness DRRs", "threads", "renders"),
            Phase::RenderMarkers => ("  rendering: landmark markers", "threads", "renders"),
            Phase::RenderVolume => ("  rendering: CT volume DRRs", "threads", "renders"),
            Phase::Metrics => ("  metrics and heatmaps", "threads", "image pairs"),
            Phase::Registration => ("  registration", "threads", "trials"),
            Phase::Calibration => ("  calibrations", "threads", "trials"),
            Phase::UnitThreads => (
                "  other unit work (result files, bookkeeping)",
                "threads",
                "units",
            ),
            Phase::Tables => ("tables", "wall", "tables"),
            Phase::Figures => ("figures", "wall", "figures"),
            Phase::Report => ("report (md + html)", "wall", "files"),
        }
    }

    fn index(self) -> usize {
        PHASES.iter().position(|p| *p == self).unwrap_or(0)
    }
}

/// One phase a thread is in: its [`Timings`] (by address), the phase, and since when it is charged.
struct Frame {
    owner: usize,
    phase: Phase,
    since: Instant,
}

thread_local! {
    static STACK: std::cell::RefCell<Vec<Frame>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Accumulated time and counts per phase; shared by the worker threads.
#[derive(Debug, Default)]
pub struct Timings {
    nanos: [AtomicU64; 14],
    counts: [AtomicU64; 14],
}

/// Facts about one invocation that the report states beside its timings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RunFacts {
    pub threads: usize,
    pub total_units: usize,
    pub ran_units: usize,
}

/// One line of the timing table.
#[derive(Debug, Clone, PartialEq)]
pub struct TimingRow {
    pub phase: &'static str,
    pub clock: &'static str,
    pub seconds: f64,
    pub count: u64,
    pub unit: &'static str,
}

impl Timings {
    /// Adds `elapsed` and `count` to `phase`.
    pub fn add(&self, phase: Phase, elapsed: Duration, count: u64) {
        let i = phase.index();
        let ns = u64::try_from(elapsed.as_nanos()).unwrap_or(u64::MAX);
        self.nanos[i].fetch_add(ns, Ordering::Relaxed);
        self.counts[i].fetch_add(count, Ordering::Relaxed);
    }

    /// Runs `f`, adding its duration and `count` to `phase`; while a nested `time` runs on this
    /// thread, `phase` is paused (exclusive time).
    pub fn time<T>(&self, phase: Phase, count: u64, f: impl FnOnce() -> T) -> T {
        let id = self as *const Timings as usize;
        let start = Instant::now();
        STACK.with(|s| {
            let mut s = s.borrow_mut();
            if let Some(outer) = s.last_mut()
                && outer.owner == id
            {
                self.add(outer.phase, start - outer.since, 0);
                outer.since = start;
            }
            s.push(Frame {
                owner: id,
                phase,
                since: start,
            });
        });
        let r = f();
        let end = Instant::now();
        STACK.with(|s| {
            let mut s = s.borrow_mut();
            if let Some(me) = s.pop() {
                self.add(me.phase, end - me.since, count);
            }
            if let Some(outer) = s.last_mut() {
                outer.since = end;
            }
        });
        r
    }

    /// Seconds accumulated in `phase`.
    pub fn seconds(&self, phase: Phase) -> f64 {
        self.nanos[phase.index()].load(Ordering::Relaxed) as f64 * 1e-9
    }

    /// The table: every phase in order, then "all unit work" (the unit phases together) and the
    /// invocation's total wall time.
    pub fn rows(&self, total: Duration) -> Vec<TimingRow> {
        let mut rows: Vec<TimingRow> = PHASES
            .iter()
            .map(|&p| {
                let (phase, clock, unit) = p.describe();
                TimingRow {
                    phase,
                    clock,
                    seconds: self.seconds(p),
                    count: self.counts[p.index()].load(Ordering::Relaxed),
                    unit,
                }
            })
            .collect();
        let unit_phases = [
            Phase::RenderTarget,
            Phase::RenderMarkers,
            Phase::RenderVolume,
            Phase::Metrics,
            Phase::Registration,
            Phase::Calibration,
            Phase::UnitThreads,
        ];
        let all = TimingRow {
            phase: "  all unit work",
            clock: "threads",
            seconds: unit_phases.iter().map(|&p| self.seconds(p)).sum(),
            count: self.counts[Phase::UnitThreads.index()].load(Ordering::Relaxed),
            unit: "units",
        };
        rows.insert(Phase::UnitThreads.index() + 1, all);
        rows.push(TimingRow {
            phase: TOTAL,
            clock: "wall",
            seconds: total.as_secs_f64(),
            count: 0,
            unit: "",
        });
        rows
    }
}

/// One line of `timings.csv`: `phase,clock,seconds,count,count_of` (seconds to the millisecond).
#[derive(Serialize)]
struct TimingCsvRow<'a> {
    phase: &'a str,
    clock: &'a str,
    #[serde(serialize_with = "millis")]
    seconds: f64,
    count: u64,
    count_of: &'a str,
}

fn millis<S: serde::Serializer>(x: &f64, s: S) -> std::result::Result<S::Ok, S::Error> {
    s.collect_str(&format_args!("{x:.3}"))
}

/// `timings.csv`, through the csv crate.
pub fn to_csv(rows: &[TimingRow]) -> Result<Vec<u8>> {
    let mut w = csv::Writer::from_writer(Vec::new());
    for r in rows {
        w.serialize(TimingCsvRow {
            phase: r.phase.trim(),
            clock: r.clock,
            seconds: r.seconds,
            count: r.count,
            count_of: r.unit,
        })
        .map_err(|e| Error::encode("timings.csv", e))?;
    }
    w.into_inner().map_err(|e| Error::encode("timings.csv", e))
}

/// A shard's work as its timing table (`timings-shard-I-of-N.csv`) states it: the work units it ran,
/// their wall time, and its whole invocation's.
#[derive(Debug, Clone, PartialEq)]
pub struct ShardTiming {
    pub file: String,
    pub units: u64,
    pub units_wall_s: f64,
    pub total_wall_s: f64,
}

/// One line of a timing table as read back.
#[derive(Deserialize)]
struct TimingRecord {
    phase: String,
    seconds: f64,
    count: u64,
}

/// The shards' timing tables in `out` (`timings-shard-I-of-N.csv`, by name), each read through the csv
/// crate; a table that cannot be read is named with its error.
pub fn shard_timings(out: &std::path::Path) -> Vec<std::result::Result<ShardTiming, String>> {
    let mut files: Vec<String> = std::fs::read_dir(out)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("timings-shard-") && n.ends_with(".csv"))
        .collect();
    files.sort();
    let (units_phase, ..) = Phase::Units.describe();
    files
        .into_iter()
        .map(|file| {
            let records: Vec<TimingRecord> = csv::Reader::from_path(out.join(&file))
                .and_then(|mut r| r.deserialize().collect())
                .map_err(|e| format!("{file}: {e}"))?;
            let find = |phase: &str| records.iter().find(|r| r.phase == phase);
            let (Some(units), Some(total)) = (find(units_phase), find(TOTAL)) else {
                return Err(format!("{file}: no '{units_phase}' or '{TOTAL}' row"));
            };
            Ok(ShardTiming {
                units: units.count,
                units_wall_s: units.seconds,
                total_wall_s: total.seconds,
                file,
            })
        })
        .collect()
}

/// A Markdown table of `rows` (used by the report and by `--timings`).
pub fn to_markdown(rows: &[TimingRow]) -> String {
    let mut s = String::from("| phase | clock | seconds | count |\n|---|---|---|---|\n");
    for r in rows {
        let count = if r.unit.is_empty() {
            String::new()
        } else {
            format!("{} {}", r.count, r.unit)
        };
        s.push_str(&format!(
            "| {} | {} | {:.2} | {count} |\n",
            r.phase.replace("  ", "↳ "),
            r.clock,
            r.seconds
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nested_phases_are_charged_exclusively() {
        let t = Timings::default();
        let sleep = |ms| std::thread::sleep(Duration::from_millis(ms));
        t.time(Phase::UnitThreads, 1, || {
            sleep(5);
            t.time(Phase::RenderTarget, 1, || {
                sleep(5);
                // A unit run while the render waits: its 150 ms are its own, not the render's.
                t.time(Phase::Registration, 5, || sleep(150));
            });
            sleep(5);
        });
        let s = |p| t.seconds(p);
        assert!(
            s(Phase::Registration) >= 0.150,
            "{}",
            s(Phase::Registration)
        );
        for p in [Phase::RenderTarget, Phase::UnitThreads] {
            assert!((0.005..0.150).contains(&s(p)), "{p:?}: {}", s(p));
        }
        let rows = t.rows(Duration::from_secs(2));
        let all = rows
            .iter()
            .find(|r| r.phase.contains("all unit work"))
            .unwrap();
        let total = s(Phase::Registration) + s(Phase::RenderTarget) + s(Phase::UnitThreads);
        assert!((all.seconds - total).abs() < 1e-12 && all.count == 1);
        assert_eq!(rows.last().unwrap().seconds, 2.0);
        let csv = String::from_utf8(to_csv(&rows).unwrap()).unwrap();
        assert_eq!(csv.lines().count(), rows.len() + 1);
        assert!(
            csv.contains("\nregistration,threads,0.1")
                || csv.contains("\nregistration,threads,0.2")
        );
        assert!(csv.contains(",5,trials\n"));
    }
}
