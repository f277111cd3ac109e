//! Running a study as a Slurm job array (`spinedrr study --slurm`): one array task per shard
//! ([`super::shard`]), then an assemble job that starts when every task has succeeded
//! (`--dependency=afterok`) and builds the tables, figures and report.
//!
//! Assumes a filesystem shared by the submitting host and every compute node, at the same paths: the
//! binary, the config, its inputs and the output folder (how clusters are set up; the scripts use
//! absolute paths). [`prepare`] claims the output folder like an unsharded run (clears another
//! config's products), prepares the inputs every shard shares, finds the shards that still have
//! missing units, and writes `OUT/slurm/array.sbatch` (only those shards), `OUT/slurm/assemble.sbatch`
//! and `OUT/slurm/submit.sh`; [`submit`] submits them with `sbatch --parsable`. Submitting again after a
//! failure reruns only the shards with missing units: finished units are never redone.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

use serde::{Deserialize, Serialize};

use super::config::StudyConfig;
use super::folder::{FolderPolicy, claim_folder};
use super::identity::UnitIdentity;
use super::runner::{config_identity, missing_units};
use super::shard;
use super::units::enumerate_units;
use crate::io::{write_atomic_bytes, write_json};
use crate::{Error, Result};

/// The folder of the scripts, the plan and the job logs.
pub const SLURM_DIR: &str = shard::PLAN_DIR;

/// How to submit.
#[derive(Debug, Clone)]
pub struct SlurmOptions {
    /// `--partition` (default: the cluster's default partition).
    pub partition: Option<String>,
    /// `--time` limit of each task (Slurm's spelling, e.g. `30:00`, `2-00:00:00`).
    pub time: Option<String>,
    /// CPUs per task; also the worker threads of each shard.
    pub cpus_per_task: usize,
    /// Shards (array tasks).
    pub array_size: usize,
    /// The command line that runs this study, without `--out`, `--threads` and the mode flags:
    /// the binary and its arguments (`study --config ABS [--quick]`), absolute paths.
    pub command: Vec<String>,
    /// What to do when OUT holds another config's results (`--start-over`: delete them; else refuse).
    pub folder: FolderPolicy,
}

/// The written plan (`OUT/slurm/plan.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SlurmPlan {
    /// Shards the units are split into.
    pub shards: usize,
    /// The shards that still have missing units (the array's task ids).
    pub pending_shards: Vec<usize>,
    pub total_units: usize,
    pub missing_units: usize,
    pub array_script: Option<PathBuf>,
    pub assemble_script: PathBuf,
    pub submit_script: PathBuf,
}

/// Job ids of a submission.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Submitted {
    pub array_job: Option<String>,
    pub assemble_job: String,
}

/// `0-3,5,7-9`: a Slurm `--array` list of sorted ids.
pub fn array_spec(ids: &[usize]) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut i = 0;
    while i < ids.len() {
        let mut j = i;
        while j + 1 < ids.len() && ids[j + 1] == ids[j] + 1 {
            j += 1;
        }
        parts.push(if j == i {
            ids[i].to_string()
        } else {
            format!("{}-{}", ids[i], ids[j])
        });
        i = j + 1;
    }
    parts.join(",")
}

/// A word quoted for bash (single quotes; a single quote inside as `'\''`).
fn sh_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

fn sh_line(words: &[String]) -> String {
    words
        .iter()
        .map(|w| {
            if w.starts_with('"') {
                w.clone()
            } else {
                sh_quote(w)
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// Refuses options Slurm or the scripts cannot take.
fn check(o: &SlurmOptions) -> Result<()> {
    if o.array_size == 0 || o.array_size > shard::MAX_SHARDS {
        return Err(Error::invalid(
            "--array-size",
            format!(
                "{}: must be between 1 and {}",
                o.array_size,
                shard::MAX_SHARDS
            ),
        ));
    }
    if o.cpus_per_task == 0 || o.cpus_per_task > super::runner::max_threads() {
        return Err(Error::invalid(
            "--cpus-per-task",
            format!(
                "{}: must be between 1 and {}",
                o.cpus_per_task,
                super::runner::max_threads()
            ),
        ));
    }
    if let Some(t) = &o.time
        && !is_slurm_time(t)
    {
        return Err(Error::invalid(
            "--time",
            format!(
                "{t:?} is not a Slurm time limit: use minutes, MM:SS, HH:MM:SS, D-HH, D-HH:MM or \
                 D-HH:MM:SS (e.g. 30, 2:00:00, 1-12:00:00), or UNLIMITED"
            ),
        ));
    }
    for (key, v) in [("--partition", &o.partition), ("--time", &o.time)] {
        if let Some(v) = v
            && (v.is_empty() || v.chars().any(|c| c.is_whitespace() || c == '\''))
        {
            return Err(Error::invalid(
                key,
                format!("{v:?}: must be one word without quotes"),
            ));
        }
    }
    Ok(())
}

/// Whether `t` is a time limit `sbatch --time` accepts: `M`, `M:S`, `H:M:S`, `D-H`, `D-H:M`, `D-H:M:S`
/// (numbers of digits), `UNLIMITED` or `INFINITE`.
pub fn is_slurm_time(t: &str) -> bool {
    if matches!(t, "UNLIMITED" | "INFINITE") {
        return true;
    }
    let number = |s: &str| !s.is_empty() && s.len() <= 6 && s.bytes().all(|b| b.is_ascii_digit());
    let (days, rest) = match t.split_once('-') {
        Some((d, r)) => (Some(d), r),
        None => (None, t),
    };
    let parts: Vec<&str> = rest.split(':').collect();
    days.is_none_or(number) && parts.iter().all(|p| number(p)) && (1..=3).contains(&parts.len())
}

/// A path `sbatch` reads from an `#SBATCH` line (the task logs under `--out`): no whitespace, quotes,
/// backslashes or `%` (Slurm expands `%j`, `%a`, … in `--output`). The `exec` lines quote their words.
fn check_script_path(what: &str, p: &Path) -> Result<()> {
    let s = p.display().to_string();
    if let Some(c) = s
        .chars()
        .find(|c| c.is_whitespace() || matches!(c, '\'' | '"' | '%' | '\\'))
    {
        return Err(Error::invalid(
            what,
            format!(
                "{s}: --slurm writes this path into #SBATCH lines, where {c:?} breaks it (sbatch splits on \
                 whitespace and expands %); use a path without whitespace, quotes, % or backslashes"
            ),
        ));
    }
    Ok(())
}

/// The `#SBATCH` header lines shared by both jobs.
fn header(o: &SlurmOptions, name: &str, log: &Path) -> String {
    let mut h = String::from("#!/bin/bash\n");
    let _ = writeln!(
        h,
        "# Generated by `spinedrr study --slurm`; rerun that command to regenerate (it submits only \
the shards with missing units)."
    );
    let _ = writeln!(h, "#SBATCH --job-name={name}");
    let _ = writeln!(h, "#SBATCH --cpus-per-task={}", o.cpus_per_task);
    let _ = writeln!(h, "#SBATCH --ntasks=1");
    if let Some(p) = &o.partition {
        let _ = writeln!(h, "#SBATCH --partition={p}");
    }
    if let Some(t) = &o.time {
        let _ = writeln!(h, "#SBATCH --time={t}");
    }
    let _ = writeln!(h, "#SBATCH --output={}", log.display());
    h
}

/// Claims `out`, prepares the shared inputs, and writes the scripts and the plan for the shards that
/// still have missing units. `out` must be absolute (the scripts run elsewhere).
pub fn prepare(cfg: &StudyConfig, out: &Path, o: &SlurmOptions) -> Result<SlurmPlan> {
    check(o)?;
    if !out.is_absolute() {
        return Err(Error::invalid(
            "--out",
            format!("{}: must be an absolute path for --slurm", out.display()),
        ));
    }
    check_script_path("--out", out)?;
    cfg.validate()?;
    super::folder::refuse_unowned_products(out)?;
    // The cohort's cases are checked here, once, and the manifest cached for the shards.
    let cfg = &super::cohort::resolve(cfg, out)?;
    let units = enumerate_units(cfg)?;
    if units.is_empty() {
        return Err(super::runner::no_units_error());
    }
    let (toml, fp) = config_identity(cfg)?;
    crate::io::create_output_dir(out, "--out")?;
    let ident = UnitIdentity::new(cfg, &fp, out)?;
    let _lock = claim_folder(out, &toml, &units, &ident, o.folder)?;
    ident.save_cache(out);
    write_atomic_bytes(&out.join("study.toml"), toml.as_bytes())?;
    let dir = out.join(SLURM_DIR);
    let logs = dir.join("logs");
    std::fs::create_dir_all(&logs).map_err(|e| Error::io(&logs, e))?;
    let missing = missing_units(out, &units, &ident);
    let pending = shard::shards_with(cfg, &units, &missing, o.array_size);
    let n = o.array_size;
    let out_s = out.display().to_string();
    let threads = o.cpus_per_task.to_string();
    let mut base = o.command.clone();
    base.extend(["--out".to_string(), out_s, "--threads".into(), threads]);

    let array_script = if pending.is_empty() {
        None
    } else {
        let mut s = header(o, "spinedrr-shards", &logs.join("shard-%a.out"));
        let _ = writeln!(s, "#SBATCH --array={}", array_spec(&pending));
        let _ = writeln!(s, "set -euo pipefail");
        let mut cmd = base.clone();
        cmd.extend([
            "--shard".to_string(),
            format!("\"${{SLURM_ARRAY_TASK_ID}}/{n}\""),
        ]);
        let _ = writeln!(s, "exec {}", sh_line(&cmd));
        let p = dir.join("array.sbatch");
        write_atomic_bytes(&p, s.as_bytes())?;
        Some(p)
    };
    if array_script.is_none() {
        // An earlier plan's array script would rerun finished shards.
        let _ = std::fs::remove_file(dir.join("array.sbatch"));
    }
    let mut s = header(o, "spinedrr-assemble", &logs.join("assemble.out"));
    let _ = writeln!(s, "set -euo pipefail");
    let mut cmd = base;
    cmd.push("--assemble".into());
    let _ = writeln!(s, "exec {}", sh_line(&cmd));
    let assemble_script = dir.join("assemble.sbatch");
    write_atomic_bytes(&assemble_script, s.as_bytes())?;

    let mut s = String::from(
        "#!/bin/bash\n# Submits the shards and the assemble job that waits for them.\n",
    );
    let _ = writeln!(
        s,
        "set -euo pipefail\ncd {}",
        sh_quote(&dir.display().to_string())
    );
    if array_script.is_some() {
        let _ = writeln!(
            s,
            "array=$(sbatch --parsable array.sbatch)\narray=${{array%%;*}}"
        );
        let _ = writeln!(
            s,
            "assemble=$(sbatch --parsable --kill-on-invalid-dep=yes --dependency=afterok:\"$array\" assemble.sbatch)"
        );
        let _ = writeln!(
            s,
            "echo \"array job $array, assemble job ${{assemble%%;*}}\""
        );
    } else {
        let _ = writeln!(s, "assemble=$(sbatch --parsable assemble.sbatch)");
        let _ = writeln!(s, "echo \"assemble job ${{assemble%%;*}}\"");
    }
    let submit_script = dir.join("submit.sh");
    write_atomic_bytes(&submit_script, s.as_bytes())?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        for p in [
            Some(&submit_script),
            array_script.as_ref(),
            Some(&assemble_script),
        ]
        .into_iter()
        .flatten()
        {
            std::fs::set_permissions(p, std::fs::Permissions::from_mode(0o755))
                .map_err(|e| Error::io(p, e))?;
        }
    }
    let plan = SlurmPlan {
        shards: n,
        pending_shards: pending,
        total_units: units.len(),
        missing_units: missing.len(),
        array_script,
        assemble_script,
        submit_script,
    };
    write_json(&dir.join("plan.json"), &plan)?;
    Ok(plan)
}

/// Runs `sbatch --parsable ARGS SCRIPT` and returns the job id.
fn sbatch(args: &[String], script: &Path) -> Result<String> {
    let output = Command::new("sbatch")
        .arg("--parsable")
        .args(args)
        .arg(script)
        .output()
        .map_err(|e| Error::External {
            library: "sbatch",
            message: format!(
                "could not run sbatch ({e}): submit from a host with Slurm's client commands, or run \
                 {} there",
                script.with_file_name("submit.sh").display()
            ),
        })?;
    let stdout = String::from_utf8_lossy(&output.stdout);
    if !output.status.success() {
        return Err(Error::External {
            library: "sbatch",
            message: format!(
                "{} was refused ({}): {}",
                script.display(),
                output.status,
                String::from_utf8_lossy(&output.stderr).trim()
            ),
        });
    }
    // `--parsable` prints `jobid` or `jobid;cluster`.
    let id = stdout.trim().split(';').next().unwrap_or("").to_string();
    if id.is_empty() || !id.bytes().all(|b| b.is_ascii_digit()) {
        return Err(Error::External {
            library: "sbatch",
            message: format!("unexpected output {stdout:?} for {}", script.display()),
        });
    }
    Ok(id)
}

/// Submits `plan`: the array (when shards are pending), then the assemble job with
/// `--dependency=afterok:<array>` (`--kill-on-invalid-dep=yes`: when a task fails the assemble job
/// is cancelled instead of waiting forever). Writes the ids to `OUT/slurm/submitted.json`.
pub fn submit(out: &Path, plan: &SlurmPlan) -> Result<Submitted> {
    let array_job = match &plan.array_script {
        Some(s) => Some(sbatch(&[], s)?),
        None => None,
    };
    let deps: Vec<String> = match &array_job {
        Some(id) => vec![
            "--kill-on-invalid-dep=yes".into(),
            format!("--dependency=afterok:{id}"),
        ],
        None => Vec::new(),
    };
    let assemble_job = sbatch(&deps, &plan.assemble_script)?;
    let s = Submitted {
        array_job,
        assemble_job,
    };
    write_json(&out.join(SLURM_DIR).join("submitted.json"), &s)?;
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn array_specs_compress_runs() {
        assert_eq!(array_spec(&[0, 1, 2, 3]), "0-3");
        assert_eq!(array_spec(&[0, 2, 3, 5, 7, 8, 9]), "0,2-3,5,7-9");
        assert_eq!(array_spec(&[4]), "4");
        assert_eq!(array_spec(&[]), "");
    }

    /// The formats `man sbatch` lists for `--time`, and what it does not.
    #[test]
    fn slurm_time_limits() {
        for ok in [
            "30",
            "30:00",
            "2:00:00",
            "1-12",
            "1-12:30",
            "1-12:30:00",
            "0",
            "UNLIMITED",
            "INFINITE",
        ] {
            assert!(is_slurm_time(ok), "{ok}");
        }
        for bad in [
            "",
            "1:2:3:4",
            "1-",
            "-5",
            "1h",
            "30m",
            "1-2-3",
            "1-2:3:4:5",
            ":30",
            "30:",
            "1.5",
            "forever",
            "1--2",
        ] {
            assert!(!is_slurm_time(bad), "{bad}");
        }
    }

    #[test]
    fn paths_sbatch_cannot_read_are_refused() {
        for bad in ["/a b/out", "/a\tb", "/out%j", "/it's", "/a\"b"] {
            let e = check_script_path("--out", Path::new(bad))
                .unwrap_err()
                .to_string();
            assert!(e.contains("--out") && e.contains("#SBATCH"), "{bad}: {e}");
        }
        check_script_path("--out", Path::new("/shared/run-1/out_2")).unwrap();
    }

    #[test]
    fn quoting_survives_bash() {
        let words = vec![
            "/a b/spinedrr".to_string(),
            "it's".into(),
            "\"$X/4\"".into(),
        ];
        let line = sh_line(&words);
        let out = Command::new("bash")
            .arg("-c")
            .arg(format!("X=2; printf '%s\\n' {line}"))
            .output()
            .unwrap();
        assert_eq!(
            String::from_utf8_lossy(&out.stdout),
            "/a b/spinedrr\nit's\n2/4\n"
        );
    }
}
