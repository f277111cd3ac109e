//! Where a study's time goes: the wall-clock phases of one invocation (inputs and targets, the parallel
//! work units, tables, figures, report) and, inside the parallel phases, the time worker threads spend
//! per kind of work (anatomy and scene building; rendering, metrics, registration). Those are summed
//! over threads, so with T threads they add up to about T × their phase's wall time. Written to `timings.csv` beside the report (not under `tables/`: timings are a
//! property of the run, not of the data, and differ from run to run).

use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crate::{Error, Result};

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
    /// Everything a unit does, summed over threads (the phases above plus result files).
    UnitThreads,
    Tables,
    Figures,
    Report,
}

const PHASES: [Phase; 13] = [
    Phase::Build,
    Phase::Anatomy,
    Phase::Scene,
    Phase::Units,
    Phase::RenderTarget,
    Phase::RenderMarkers,
    Phase::RenderVolume,
    Phase::Metrics,
    Phase::Registration,
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
            Phase::UnitThreads => ("  all unit work", "threads", "units"),
            Phase::Tables => ("tables", "wall", "tables"),
            Phase::Figures => ("figures", "wall", "figures"),
            Phase::Report => ("report (md + html)", "wall", "files"),
        }
    }

    fn index(self) -> usize {
        PHASES.iter().position(|p| *p == self).unwrap_or(0)
    }
}

/// Accumulated time and counts per phase; shared by the worker threads.
#[derive(Debug, Default)]
pub struct Timings {
    nanos: [AtomicU64; 13],
    counts: [AtomicU64; 13],
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

    /// Runs `f`, adding its duration and `count` to `phase`.
    pub fn time<T>(&self, phase: Phase, count: u64, f: impl FnOnce() -> T) -> T {
        let t0 = Instant::now();
        let r = f();
        self.add(phase, t0.elapsed(), count);
        r
    }

    /// Seconds accumulated in `phase`.
    pub fn seconds(&self, phase: Phase) -> f64 {
        self.nanos[phase.index()].load(Ordering::Relaxed) as f64 * 1e-9
    }

    /// The table: every phase in order, then "other unit work" (unit thread time not in a named
    /// phase: result files, marker search) and the invocation's total wall time.
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
        let named: f64 = [
            Phase::RenderTarget,
            Phase::RenderMarkers,
            Phase::RenderVolume,
            Phase::Metrics,
            Phase::Registration,
        ]
        .iter()
        .map(|&p| self.seconds(p))
        .sum();
        let other = TimingRow {
            phase: "  other unit work (result files, bookkeeping)",
            clock: "threads",
            seconds: (self.seconds(Phase::UnitThreads) - named).max(0.0),
            count: 0,
            unit: "",
        };
        rows.insert(Phase::UnitThreads.index(), other);
        rows.push(TimingRow {
            phase: "total",
            clock: "wall",
            seconds: total.as_secs_f64(),
            count: 0,
            unit: "",
        });
        rows
    }
}

/// `timings.csv`: `phase,clock,seconds,count,count_of`.
pub fn to_csv(rows: &[TimingRow]) -> String {
    let mut s = String::from("phase,clock,seconds,count,count_of\n");
    for r in rows {
        s.push_str(&format!(
            "{},{},{:.3},{},{}\n",
            r.phase.trim(),
            r.clock,
            r.seconds,
            r.count,
            r.unit
        ));
    }
    s
}

/// A Markdown table of `rows` (used by the report and by `--timings`).
pub fn to_markdown(rows: &[TimingRow]) -> Result<String> {
    let mut s = String::from("| phase | clock | seconds | count |\n|---|---|---|---|\n");
    for r in rows {
        let count = if r.unit.is_empty() {
            String::new()
        } else {
            format!("{} {}", r.count, r.unit)
        };
        writeln!(
            s,
            "| {} | {} | {:.2} | {count} |",
            r.phase.replace("  ", "↳ "),
            r.clock,
            r.seconds
        )
        .map_err(|e| Error::Numerical(format!("formatting timings: {e}")))?;
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn other_unit_work_is_unit_time_minus_named_phases() {
        let t = Timings::default();
        t.add(Phase::UnitThreads, Duration::from_millis(1000), 4);
        t.add(Phase::RenderTarget, Duration::from_millis(300), 4);
        t.add(Phase::Metrics, Duration::from_millis(200), 4);
        t.add(Phase::Registration, Duration::from_millis(100), 10);
        let rows = t.rows(Duration::from_secs(2));
        let other = rows
            .iter()
            .find(|r| r.phase.contains("other unit work"))
            .unwrap();
        assert!((other.seconds - 0.4).abs() < 1e-9, "{other:?}");
        assert_eq!(rows.last().unwrap().seconds, 2.0);
        let csv = to_csv(&rows);
        assert_eq!(csv.lines().count(), rows.len() + 1);
        assert!(csv.contains("registration,threads,0.100,10,trials"));
    }
}
