//! `spinedrr study`: the paper's sensitivity study (or one from a config file) as tables, figures and a
//! report.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args as ClapArgs;
use spinedrr::study::folder::FolderPolicy;
use spinedrr::study::runner::max_threads;
use spinedrr::study::shard::Shard;
use spinedrr::study::slurm::{self, SlurmOptions};
use spinedrr::study::{RunOptions, StudyConfig, run_study};

#[derive(ClapArgs)]
pub struct Args {
    /// Study config (TOML; see examples/study.toml). Without it, the paper's defaults. Relative paths in
    /// it are relative to its folder.
    #[arg(long)]
    config: Option<PathBuf>,
    /// A tiny grid for a smoke test: 2× binned detector, Δf {100, 500}, piercing {0, 50}, 3 registration
    /// trials. Alone it studies L1 only, without the calibration experiment; with --config, the config's
    /// targets, views and experiments on that grid.
    #[arg(long)]
    quick: bool,
    /// Output folder (tables/, figures/, units/, report.md).
    #[arg(long, default_value = "study-out")]
    out: PathBuf,
    /// Worker threads (default: all cores; at most 4 × the cores, and never fewer than 256).
    #[arg(long, value_parser = super::values::whole::<usize>)]
    threads: Option<usize>,
    /// Stop after running this many work units (the rest run on the next invocation).
    #[arg(long, value_parser = super::values::whole::<usize>)]
    max_units: Option<usize>,
    /// Print where the time went (also written to OUT/timings.csv and the report).
    #[arg(long)]
    timings: bool,
    /// Run only shard I of N (0 ≤ I < N) of the work units, writing their unit files into OUT; no
    /// tables or report (`--assemble` builds them once every shard has run). Shards are balanced by
    /// expected cost and may run at the same time on one OUT (a shared filesystem). Inside a Slurm job
    /// array, SLURM_ARRAY_TASK_ID / SLURM_ARRAY_TASK_COUNT are used when --shard is not given.
    #[arg(long, value_name = "I/N", conflicts_with_all = ["assemble", "slurm"])]
    shard: Option<String>,
    /// Build the tables, figures and report from the unit files of all shards in OUT; runs no unit and
    /// fails, naming them, when units are missing.
    #[arg(long, conflicts_with_all = ["slurm", "max_units"])]
    assemble: bool,
    /// Write a Slurm job array (one task per shard, only the shards with missing units) and an
    /// assemble job that waits for it (`--dependency=afterok`) into OUT/slurm/; with --submit, submit
    /// them. Needs a filesystem shared with the compute nodes at the same paths.
    #[arg(long)]
    slurm: bool,
    /// Slurm partition of both jobs (default: the cluster's default).
    #[arg(long, requires = "slurm")]
    partition: Option<String>,
    /// Slurm time limit of each job (e.g. 30:00 or 1-00:00:00).
    #[arg(long, requires = "slurm")]
    time: Option<String>,
    /// CPUs of each array task (also its worker threads).
    #[arg(long, requires = "slurm", default_value_t = 2, value_parser = super::values::whole::<usize>)]
    cpus_per_task: usize,
    /// Number of shards (array tasks).
    #[arg(long, requires = "slurm", default_value_t = 8, value_parser = super::values::whole::<usize>)]
    array_size: usize,
    /// Submit the jobs with sbatch and print their ids (else only write the scripts).
    #[arg(long, requires = "slurm")]
    submit: bool,
    /// When OUT holds the results of another study config (its OUT/study.toml differs), delete them —
    /// that run's unit files, tables, figures, references and report — and run this config. Without it
    /// such a folder is refused, naming the keys that differ, and nothing in it changes.
    #[arg(long, conflicts_with_all = ["shard", "assemble"])]
    start_over: bool,
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
    if a.slurm {
        return run_slurm(&a, &cfg);
    }
    let shard = match &a.shard {
        Some(s) => Some(Shard::parse(s)?),
        None if a.assemble => None,
        None => Shard::from_env()?,
    };
    let opts = RunOptions {
        out: a.out.clone(),
        threads: a.threads,
        max_units: a.max_units,
        progress: true,
        shard,
        assemble_only: a.assemble,
        folder: folder_policy(a.start_over),
    };
    let s = run_study(&cfg, &opts).context("running the study")?;
    if let Some(sh) = shard {
        eprintln!(
            "shard {sh}: {} units ({} reused, {} run) written to {}; `spinedrr study --assemble` \
             builds the report once every shard has run",
            s.total_units,
            s.skipped_units,
            s.ran_units,
            a.out.join("units").display()
        );
        return Ok(());
    }
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

fn folder_policy(start_over: bool) -> FolderPolicy {
    if start_over {
        FolderPolicy::StartOver
    } else {
        FolderPolicy::Keep
    }
}

/// `--slurm`: the scripts (and with `--submit` the jobs) of this study's shards.
fn run_slurm(a: &Args, cfg: &StudyConfig) -> anyhow::Result<()> {
    let absolute = |p: &std::path::Path| -> anyhow::Result<PathBuf> {
        Ok(if p.is_absolute() {
            p.to_path_buf()
        } else {
            std::env::current_dir()
                .context("reading the working directory")?
                .join(p)
        })
    };
    let exe = std::env::current_exe().context("locating the spinedrr binary")?;
    let mut command = vec![exe.display().to_string(), "study".to_string()];
    if let Some(c) = &a.config {
        command.extend(["--config".to_string(), absolute(c)?.display().to_string()]);
    }
    if a.quick {
        command.push("--quick".into());
    }
    let out = absolute(&a.out)?;
    let opts = SlurmOptions {
        partition: a.partition.clone(),
        time: a.time.clone(),
        cpus_per_task: a.cpus_per_task,
        array_size: a.array_size,
        command,
        folder: folder_policy(a.start_over),
    };
    let plan = slurm::prepare(cfg, &out, &opts).context("preparing the Slurm jobs")?;
    let shards: Vec<String> = plan.pending_shards.iter().map(|s| s.to_string()).collect();
    eprintln!(
        "{} of {} units missing; shards to run: {} of {}; scripts in {}",
        plan.missing_units,
        plan.total_units,
        if shards.is_empty() {
            "none".to_string()
        } else {
            shards.join(",")
        },
        plan.shards,
        out.join(slurm::SLURM_DIR).display()
    );
    if !a.submit {
        eprintln!("submit with: {}", plan.submit_script.display());
        return Ok(());
    }
    let ids = slurm::submit(&out, &plan).context("submitting the Slurm jobs")?;
    if let Some(id) = &ids.array_job {
        println!("array job {id}");
    }
    println!("assemble job {}", ids.assemble_job);
    Ok(())
}
