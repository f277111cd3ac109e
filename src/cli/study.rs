//! `spinedrr study`: the paper's sensitivity study (or one from a config file) as tables, figures and a
//! report.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args as ClapArgs;
use spinedrr::study::runner::max_threads;
use spinedrr::study::{RunOptions, StudyConfig, run_study};

#[derive(ClapArgs)]
pub struct Args {
    /// Study config (TOML; see examples/study.toml). Without it, the paper's defaults. Relative paths in
    /// it are relative to its folder.
    #[arg(long)]
    config: Option<PathBuf>,
    /// A tiny grid for a smoke test: 2× binned detector, Δf {100, 500}, piercing {0, 50}, 3 registration
    /// trials. Alone it studies L1 only; with --config, the config's targets and views on that grid.
    #[arg(long)]
    quick: bool,
    /// Output folder (tables/, figures/, units/, report.md).
    #[arg(long, default_value = "study-out")]
    out: PathBuf,
    /// Worker threads (default: all cores; at most 4 × the cores, and never fewer than 256).
    #[arg(long)]
    threads: Option<usize>,
    /// Stop after running this many work units (the rest run on the next invocation).
    #[arg(long)]
    max_units: Option<usize>,
    /// Print where the time went (also written to OUT/timings.csv and the report).
    #[arg(long)]
    timings: bool,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if let Some(n) = a.threads {
        let max = max_threads();
        if n == 0 || n > max {
            anyhow::bail!(
                "--threads {n}: must be between 1 and {max} (4 × the cores, and never fewer than 256)"
            );
        }
    }
    let cfg = match &a.config {
        Some(p) => {
            let cfg = StudyConfig::from_file(p)
                .with_context(|| format!("reading study config {}", p.display()))?;
            if a.quick { cfg.with_quick_grid() } else { cfg }
        }
        None if a.quick => StudyConfig::quick(),
        None => StudyConfig::default(),
    };
    let opts = RunOptions {
        out: a.out.clone(),
        threads: a.threads,
        max_units: a.max_units,
        progress: true,
    };
    let s = run_study(&cfg, &opts).context("running the study")?;
    if a.timings {
        eprintln!("{:<48} {:>7} {:>9}  count", "phase", "clock", "seconds");
        for r in &s.timings {
            eprintln!(
                "{:<48} {:>7} {:>9.2}  {}",
                r.phase,
                r.clock,
                r.seconds,
                if r.unit.is_empty() {
                    String::new()
                } else {
                    format!("{} {}", r.count, r.unit)
                }
            );
        }
    }
    if s.complete {
        eprintln!(
            "study complete: {} units ({} reused, {} run); see {}",
            s.total_units,
            s.skipped_units,
            s.ran_units,
            a.out.join("report.md").display()
        );
    } else {
        eprintln!(
            "study stopped after {} units ({} of {} done); run again to continue",
            s.ran_units,
            s.skipped_units + s.ran_units,
            s.total_units
        );
    }
    Ok(())
}
