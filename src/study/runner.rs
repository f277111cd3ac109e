//! Parallel, deterministic, resumable execution of a study's work units.
//!
//! Each unit's typed rows go atomically to `out/units/<id>.json`, tagged with the config fingerprint; a
//! unit whose file exists with the same fingerprint is skipped (resume). Tables, figures and the report
//! are assembled only once every unit is present, in the fixed unit order, so their bytes do not depend
//! on the thread count or on interruptions.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use rayon::prelude::*;

use super::config::StudyConfig;
use super::experiments::{self, Context};
use super::schema::StudyTables;
use super::timings::{Phase, RunFacts, TimingRow, Timings, to_csv};
use super::units::{Unit, UnitFile, derive_seed, enumerate_units};
use super::{figures, report, report_html};
use crate::io::write_atomic_bytes;
use crate::{Error, Result};

/// How to run a study.
#[derive(Debug, Clone)]
pub struct RunOptions {
    pub out: PathBuf,
    /// Worker threads (default: rayon's choice).
    pub threads: Option<usize>,
    /// Stop after running this many units (for interruption tests).
    pub max_units: Option<usize>,
    /// Show a progress bar (only when stderr is a terminal and not in CI).
    pub progress: bool,
}

/// What a run did.
#[derive(Debug, Clone, PartialEq)]
pub struct RunSummary {
    pub total_units: usize,
    pub skipped_units: usize,
    pub ran_units: usize,
    /// All units present and the tables, figures and report written.
    pub complete: bool,
    /// Where this invocation's time went (also in `timings.csv` and the report).
    pub timings: Vec<TimingRow>,
}

/// The fingerprint of a config: FNV-1a over its canonical TOML.
pub fn fingerprint(cfg: &StudyConfig) -> Result<String> {
    Ok(format!("{:016x}", derive_seed(0, &config_toml(cfg)?, 0)))
}

/// The config's canonical TOML (`study.toml`, and what the fingerprint hashes).
fn config_toml(cfg: &StudyConfig) -> Result<String> {
    toml::to_string(cfg).map_err(|e| Error::encode("the study config", e))
}

fn unit_path(out: &Path, id: &str) -> PathBuf {
    out.join("units").join(format!("{id}.json"))
}

/// The unit file at `path` if it exists, parses and carries `fp`.
fn load_unit(path: &Path, fp: &str) -> Option<UnitFile> {
    let text = std::fs::read_to_string(path).ok()?;
    let f: UnitFile = serde_json::from_str(&text).ok()?;
    (f.fingerprint == fp).then_some(f)
}

fn create_dir(p: &Path) -> Result<()> {
    std::fs::create_dir_all(p).map_err(|e| Error::io(p, e))
}

/// Runs (or resumes) the study.
///
/// Order: validate the config; read and check the CT inputs (labels present, grids) when there is work
/// to do — so a bad input fails before the output folder is touched; create the output folder; build
/// the anatomy and scenes; run the pending units; assemble tables, figures, report.
pub fn run_study(cfg: &StudyConfig, opts: &RunOptions) -> Result<RunSummary> {
    let start = Instant::now();
    let timings = Arc::new(Timings::default());
    cfg.validate()?;
    let fp = fingerprint(cfg)?;
    let units = enumerate_units(cfg)?;
    let pending: Vec<&Unit> = units
        .iter()
        .filter(|u| load_unit(&unit_path(&opts.out, &u.id()), &fp).is_none())
        .collect();
    let skipped = units.len() - pending.len();
    let todo: Vec<&Unit> = match opts.max_units {
        Some(n) => pending.iter().take(n).copied().collect(),
        None => pending.clone(),
    };
    let pool = thread_pool(opts.threads)?;
    let build_start = Instant::now();
    let inputs = if todo.is_empty() {
        experiments::Inputs::default()
    } else {
        timings.time(Phase::Anatomy, 0, || experiments::load_inputs(cfg))?
    };
    let mut build_wall = build_start.elapsed();
    for d in ["units", "tables", "figures", experiments::REFERENCES_DIR] {
        create_dir(&opts.out.join(d))?;
    }
    write_atomic_bytes(&opts.out.join("study.toml"), config_toml(cfg)?.as_bytes())?;
    if !todo.is_empty() {
        let t0 = Instant::now();
        let mut ctx = Context::build(cfg, inputs, &opts.out, timings.clone(), &pool)?;
        build_wall += t0.elapsed();
        timings.add(Phase::Build, build_wall, ctx.targets.len() as u64);
        let t0 = Instant::now();
        ctx.prepare_references(&todo, &pool)?;
        run_units(&ctx, &pool, opts, &fp, &todo)?;
        timings.add(Phase::Units, t0.elapsed(), todo.len() as u64);
    }
    let complete = todo.len() == pending.len();
    let threads = pool.current_num_threads();
    let run = RunFacts {
        threads,
        total_units: units.len(),
        ran_units: todo.len(),
    };
    if complete {
        let t0 = Instant::now();
        let tables = assemble(&opts.out, &units, &fp)?;
        let n_tables = tables.write(&opts.out.join("tables"))?;
        timings.add(Phase::Tables, t0.elapsed(), n_tables as u64);
        let n_figures = timings.time(Phase::Figures, 0, || {
            figures::write_all(&opts.out, cfg, &tables)
        })?;
        timings.add(Phase::Figures, std::time::Duration::ZERO, n_figures as u64);
        let rows = timings.rows(start.elapsed());
        timings.time(Phase::Report, 2, || -> Result<()> {
            report::write(&opts.out, cfg, &tables, &rows, &run)?;
            report_html::write(&opts.out)
        })?;
    }
    let rows = timings.rows(start.elapsed());
    write_atomic_bytes(&opts.out.join("timings.csv"), &to_csv(&rows)?)?;
    Ok(RunSummary {
        total_units: units.len(),
        skipped_units: skipped,
        ran_units: todo.len(),
        complete,
        timings: rows,
    })
}

/// The worker pool of a run (`threads` workers, or rayon's default).
fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool> {
    let mut builder = rayon::ThreadPoolBuilder::new();
    if let Some(n) = threads {
        builder = builder.num_threads(n);
    }
    builder
        .build()
        .map_err(|e| Error::Resource(format!("building a pool of worker threads: {e}")))
}

fn run_units(
    ctx: &Context,
    pool: &rayon::ThreadPool,
    opts: &RunOptions,
    fp: &str,
    todo: &[&Unit],
) -> Result<()> {
    let bar = progress_bar(opts.progress, todo.len());
    pool.install(|| {
        // One job per unit: rayon's default splitting runs long stretches of units on one thread, and
        // units differ in cost by 100× (renders vs registration trials), which left a core idle.
        todo.par_iter()
            .with_max_len(1)
            .try_for_each(|u| -> Result<()> {
                ctx.timings.time(Phase::UnitThreads, 1, || -> Result<()> {
                    let rows = ctx.run(u)?;
                    let file = UnitFile {
                        id: u.id(),
                        fingerprint: fp.to_string(),
                        rows,
                    };
                    let text = serde_json::to_string(&file)
                        .map_err(|e| Error::encode(format!("unit {}", u.id()), e))?;
                    write_atomic_bytes(&unit_path(&opts.out, &u.id()), text.as_bytes())
                })?;
                if let Some(b) = &bar {
                    b.inc(1);
                }
                Ok(())
            })
    })?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    Ok(())
}

fn progress_bar(wanted: bool, n: usize) -> Option<indicatif::ProgressBar> {
    let ci = std::env::var_os("CI").is_some();
    if !(wanted && std::io::stderr().is_terminal() && !ci) {
        return None;
    }
    let bar = indicatif::ProgressBar::new(n as u64);
    if let Ok(style) = indicatif::ProgressStyle::with_template(
        "{bar:40} {pos}/{len} units, {elapsed_precise} elapsed, ETA {eta}",
    ) {
        bar.set_style(style);
    }
    Some(bar)
}

/// Every unit's rows, in unit order, as the study's tables.
fn assemble(out: &Path, units: &[Unit], fp: &str) -> Result<StudyTables> {
    let rows = units
        .iter()
        .map(|u| {
            let path = unit_path(out, &u.id());
            load_unit(&path, fp)
                .map(|f| f.rows)
                .ok_or_else(|| Error::format(&path, "unit result missing or from another config"))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(StudyTables::from_units(rows))
}
