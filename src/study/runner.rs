//! Parallel, deterministic, resumable execution of a study's work units.
//!
//! Each unit's typed rows go atomically to `out/units/<id>.json`, tagged with the unit's identity (the
//! config's fingerprint and the content of every input file the unit reads, [`UnitIdentity`]); a unit
//! whose file exists with the same identity is skipped (resume), so a changed input reruns exactly the
//! units that read it. Tables, figures and the report are assembled only once every unit is present, in
//! the fixed unit order, so their bytes do not depend on the thread count or on interruptions. One run at
//! a time owns the output folder (`OUT/.study.lock`, [`super::lock`]), and a folder left by another
//! config is refused — or, with `--start-over`, cleared of that run's products — so a report never links
//! figures or units that are not its own and a finished run is never deleted implicitly
//! ([`super::folder`]).

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use rayon::prelude::*;

use super::config::StudyConfig;
use super::experiments::{self, Context};
use super::folder::{FolderPolicy, PRODUCT_DIRS, claim_folder, refuse_unowned_products};
use super::identity::UnitIdentity;
pub use super::lock::{LOCK_FILE, OutputLock};
use super::schema::StudyTables;
use super::shard::{self, Shard};
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
    /// Run only this shard's units ([`super::shard`]); tables, figures and report are left to an
    /// `assemble_only` run.
    pub shard: Option<Shard>,
    /// Run no unit: build tables, figures and report from the unit files present, and fail, naming
    /// them, when units are missing.
    pub assemble_only: bool,
    /// What to do when the folder holds another config's results (default: refuse).
    pub folder: FolderPolicy,
}

impl RunOptions {
    /// Options for an unsharded run into `out` (rayon's threads, no limit, no progress bar).
    pub fn new(out: impl Into<PathBuf>) -> RunOptions {
        RunOptions {
            out: out.into(),
            threads: None,
            max_units: None,
            progress: false,
            shard: None,
            assemble_only: false,
            folder: FolderPolicy::Keep,
        }
    }
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

/// The unit file of `u` under `out` if it exists, parses and carries the unit's identity.
fn load_unit(out: &Path, u: &Unit, ident: &UnitIdentity) -> Option<UnitFile> {
    let text = std::fs::read_to_string(unit_path(out, &u.id())).ok()?;
    let f: UnitFile = serde_json::from_str(&text).ok()?;
    (f.fingerprint == ident.of(u) && f.id == u.id()).then_some(f)
}

/// Runs (or resumes) the study.
///
/// Order: validate the config (keys, grid, work limits) and the thread count; when there is work to do,
/// read and check every input (meshes, landmarks, CT labels and grids), build the anatomy and scenes
/// and check that every target lands on the detector in every cell — so a bad input fails before the
/// output folder is touched; lock the output folder ([`OutputLock`]); clear the products of another
/// config ([`clear_foreign_products`]); run the pending units; assemble tables, figures, report.
pub fn run_study(cfg: &StudyConfig, opts: &RunOptions) -> Result<RunSummary> {
    let start = Instant::now();
    let timings = Arc::new(Timings::default());
    cfg.validate()?;
    let pool = thread_pool(opts.threads)?;
    refuse_unowned_products(&opts.out)?;
    // A cohort's cases become CT entries (checked once, then cached in OUT/cohort/).
    let resolved = super::cohort::resolve(cfg, &opts.out)?;
    let cfg = &resolved;
    let fp = fingerprint(cfg)?;
    let toml = config_toml(cfg)?;
    let units = enumerate_units(cfg)?;
    if units.is_empty() {
        return Err(no_units_error());
    }
    // This invocation's units: a shard's, or all.
    let mine: Vec<&Unit> = match opts.shard {
        Some(s) => shard::units_of(cfg, &units, s),
        None => units.iter().collect(),
    };
    // Every input file is read (or its cached digest) once, here: a missing one fails before any work.
    let ident = UnitIdentity::new(cfg, &fp, &opts.out)?;
    let is_pending = |u: &Unit| load_unit(&opts.out, u, &ident).is_none();
    // What is pending, read before the lock only to decide whether the anatomy must be built.
    let work_before =
        !opts.assemble_only && opts.max_units != Some(0) && mine.iter().any(|u| is_pending(u));
    let build_start = Instant::now();
    let mut ctx = if work_before {
        let pending: Vec<&Unit> = mine.iter().copied().filter(|u| is_pending(u)).collect();
        Some(build_context(cfg, &pending, opts, &timings, &pool)?)
    } else {
        None
    };
    let mut build_wall = build_start.elapsed();
    crate::io::create_output_dir(&opts.out, "--out")?;
    // A shard shares the folder with the other shards: no lock, no clearing, no removal of
    // temporaries (another host's live process cannot be told from a dead one).
    let _lock = match opts.shard {
        Some(_) => {
            shard::prepare_folder(&opts.out, &toml, &PRODUCT_DIRS)?;
            None
        }
        None => Some(claim_folder(&opts.out, &toml, &units, &ident, opts.folder)?),
    };
    ident.save_cache(&opts.out);
    if opts.assemble_only {
        let missing = missing_units(&opts.out, &units, &ident);
        if !missing.is_empty() {
            let shards = shard::planned_shards(&opts.out)
                .map(|n| (n, shard::shards_with(cfg, &units, &missing, n)));
            return Err(shard::missing_units_error(
                &opts.out, &units, &missing, shards,
            ));
        }
    }
    let pending: Vec<&Unit> = mine.iter().copied().filter(|u| is_pending(u)).collect();
    let skipped = mine.len() - pending.len();
    let todo: Vec<&Unit> = pending
        .iter()
        .take(opts.max_units.unwrap_or(usize::MAX))
        .copied()
        .collect();
    if opts.shard.is_none() {
        write_atomic_bytes(&opts.out.join("study.toml"), toml.as_bytes())?;
    }
    if !todo.is_empty() {
        let t0 = Instant::now();
        let mut ctx = match ctx.take() {
            Some(c) => c,
            None => build_context(cfg, &todo, opts, &timings, &pool)?,
        };
        build_wall += t0.elapsed();
        timings.add(Phase::Build, build_wall, ctx.targets.len() as u64);
        let t0 = Instant::now();
        ctx.prepare_references(&todo, &pool)?;
        run_units(&ctx, &pool, opts, &ident, &todo)?;
        timings.add(Phase::Units, t0.elapsed(), todo.len() as u64);
    }
    // A shard never assembles (the other shards' units may still be running).
    let complete = opts.shard.is_none() && todo.len() == pending.len();
    let threads = pool.current_num_threads();
    let run = RunFacts {
        threads,
        total_units: mine.len(),
        ran_units: todo.len(),
    };
    if complete {
        let t0 = Instant::now();
        let tables = assemble(&opts.out, &units, &ident)?;
        let n_tables = tables.write(&opts.out.join("tables"))?
            + super::cohort::write_tables(&opts.out, cfg, &tables)?;
        timings.add(Phase::Tables, t0.elapsed(), n_tables as u64);
        let n_figures = timings.time(Phase::Figures, 0, || {
            figures::write_all(&opts.out, cfg, &tables)
        })?;
        timings.add(Phase::Figures, std::time::Duration::ZERO, n_figures as u64);
        let rows = timings.rows(start.elapsed());
        timings.time(Phase::Report, 2, || -> Result<()> {
            report::write(&opts.out, cfg, &tables, &rows, (&run, ident.inputs()))?;
            report_html::write(&opts.out)
        })?;
    }
    let rows = timings.rows(start.elapsed());
    let timings_file = match opts.shard {
        Some(s) => format!("timings-{}.csv", s.tag()),
        None => "timings.csv".to_string(),
    };
    write_atomic_bytes(&opts.out.join(timings_file), &to_csv(&rows)?)?;
    Ok(RunSummary {
        total_units: mine.len(),
        skipped_units: skipped,
        ran_units: todo.len(),
        complete,
        timings: rows,
    })
}

/// The refusal of a config that describes no work (every grid of its experiments empty).
pub(super) fn no_units_error() -> Error {
    Error::invalid(
        "perturbations",
        "the config describes no work unit (the grids of its experiments are empty, e.g. df_px = [] and \
         piercing_px = []): a study of nothing would be reported complete; give at least one grid value",
    )
}

/// The config's canonical TOML and fingerprint.
pub(super) fn config_identity(cfg: &StudyConfig) -> Result<(String, String)> {
    Ok((config_toml(cfg)?, fingerprint(cfg)?))
}

/// The positions in `units` of those without a unit file of their identity under `out`.
pub(super) fn missing_units(out: &Path, units: &[Unit], ident: &UnitIdentity) -> Vec<usize> {
    (0..units.len())
        .filter(|&i| load_unit(out, &units[i], ident).is_none())
        .collect()
}

/// Reads the inputs the `units` need (printing their warnings), builds their targets and checks that
/// every cell puts its target on the detector; touches no file. Anatomy no unit of this invocation
/// studies is not read ([`shard::restrict_config`]).
fn build_context(
    cfg: &StudyConfig,
    units: &[&Unit],
    opts: &RunOptions,
    timings: &Arc<Timings>,
    pool: &rayon::ThreadPool,
) -> Result<Context> {
    let cfg = &shard::restrict_config(cfg, units);
    let inputs = timings.time(Phase::Anatomy, 0, || experiments::load_inputs(cfg))?;
    for w in &inputs.warnings {
        eprintln!("warning: {w}");
    }
    let ctx = Context::build(cfg, inputs, &opts.out, timings.clone(), pool)?;
    ctx.check_on_detector()?;
    Ok(ctx)
}

/// The most worker threads a run may ask for: 4 × the cores, and never fewer than 256.
pub fn max_threads() -> usize {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    (4 * cores).max(256)
}

/// The worker pool of a run (`threads` workers, or rayon's default).
fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool> {
    let mut builder = rayon::ThreadPoolBuilder::new();
    if let Some(n) = threads {
        let max = max_threads();
        if n == 0 || n > max {
            return Err(Error::invalid(
                "threads (--threads)",
                format!(
                    "{n}: must be between 1 and {max} (4 × the cores, and never fewer than 256)"
                ),
            ));
        }
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
    ident: &UnitIdentity,
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
                    let rows = ctx.run(u).map_err(|e| in_unit(e, u))?;
                    let file = UnitFile {
                        id: u.id(),
                        fingerprint: ident.of(u),
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
fn assemble(out: &Path, units: &[Unit], ident: &UnitIdentity) -> Result<StudyTables> {
    let rows = units
        .iter()
        .map(|u| {
            load_unit(out, u, ident).map(|f| f.rows).ok_or_else(|| {
                Error::format(
                    unit_path(out, &u.id()),
                    "unit result missing, or of another config or other input files",
                )
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(StudyTables::from_units(rows))
}

/// `e` with the unit it came from (target, view and perturbation, or registration cell) in front.
fn in_unit(e: Error, u: &Unit) -> Error {
    let cell = u.describe();
    match e {
        Error::Invalid { field, message } => Error::Invalid {
            field,
            message: format!("{cell}: {message}"),
        },
        Error::Numerical(m) => Error::Numerical(format!("{cell}: {m}")),
        Error::Resource(m) => Error::Resource(format!("{cell}: {m}")),
        Error::Internal(m) => Error::Internal(format!("{cell}: {m}")),
        Error::Format { path, message } => Error::Format {
            path,
            message: format!("{cell}: {message}"),
        },
        other => other,
    }
}
