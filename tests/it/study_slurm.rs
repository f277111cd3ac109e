//! `spinedrr study --slurm --submit` on a real single-node Slurm cluster (Debian's slurm-wlm and munge,
//! started by `scripts/slurm-local.sh` on localhost and stopped afterwards): a cohort study of two
//! synthetic CTs (`spinedrr phantom --ct`) as a 4-task job array and its dependent assemble job gives
//! the tables of the same study run unsharded, byte for byte; with one array task cancelled midway the
//! assemble job never runs, and submitting again runs only the shards with missing units and gives the
//! same tables.
//!
//! Needs root (slurmd) and the packages `scripts/install-deps.sh` installs; without them each test
//! says why on stderr and returns.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Mutex, OnceLock};
use std::time::{Duration, Instant};

use spinedrr::study::StudyConfig;
use spinedrr::study::identity::UnitIdentity;
use spinedrr::study::runner::fingerprint;
use spinedrr::study::shard::{Shard, units_of};
use spinedrr::study::units::enumerate_units;

use crate::common::{Spinedrr, csv_tables};

/// One cluster at a time (they share the Slurm ports and munged).
static CLUSTER: Mutex<()> = Mutex::new(());

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/slurm-local.sh")
}

/// Why this machine cannot run the cluster, if it cannot.
fn cannot_run() -> Option<String> {
    if !crate::common::is_root() {
        return Some("not root: slurmd must run as root".into());
    }
    for b in [
        "/usr/sbin/slurmctld",
        "/usr/sbin/slurmd",
        "/usr/sbin/munged",
    ] {
        if !Path::new(b).exists() {
            return Some(format!(
                "{b} is not installed (Debian's slurm-wlm and munge; scripts/install-deps.sh installs them)"
            ));
        }
    }
    None
}

/// A running cluster; stopped (jobs cancelled, daemons killed by pid) when dropped.
struct Cluster {
    dir: PathBuf,
    conf: PathBuf,
    pids: Vec<u32>,
}

impl Cluster {
    fn start(dir: &Path) -> Cluster {
        let dir = dir.join("slurm");
        let out = Command::new("bash")
            .arg(script())
            .arg("start")
            .env("SLURM_LOCAL_DIR", &dir)
            .output()
            .expect("running slurm-local.sh");
        let mut c = Cluster {
            conf: dir.join("slurm.conf"),
            dir,
            pids: Vec::new(),
        };
        c.pids = ["slurmctld", "slurmd", "munged"]
            .iter()
            .filter_map(|n| std::fs::read_to_string(c.dir.join(format!("run/{n}.pid"))).ok())
            .filter_map(|s| s.trim().parse().ok())
            .collect();
        assert!(
            out.status.success(),
            "slurm-local.sh start failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        c
    }

    /// A Slurm client command against this cluster.
    fn cmd(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf);
        c
    }

    fn stdout(&self, program: &str, args: &[&str]) -> String {
        let o = self.cmd(program).args(args).output().expect(program);
        String::from_utf8_lossy(&o.stdout).into_owned()
    }

    /// Waits until none of `jobs` is queued or running (at most `limit`).
    fn wait_gone(&self, jobs: &[&str], limit: Duration) {
        let t0 = Instant::now();
        let list = jobs.join(",");
        loop {
            let q = self.stdout("squeue", &["-h", "-r", "-j", &list, "-o", "%i %T"]);
            if q.trim().is_empty() {
                return;
            }
            assert!(
                t0.elapsed() < limit,
                "jobs still queued after {limit:?}:\n{q}\n{}",
                self.logs()
            );
            std::thread::sleep(Duration::from_millis(500));
        }
    }

    /// `JobState` of a job (`scontrol show job`; finished jobs stay visible for MinJobAge = 600 s).
    fn state(&self, job: &str) -> String {
        let s = self.stdout("scontrol", &["show", "job", "-o", job]);
        s.split_whitespace()
            .find_map(|w| w.strip_prefix("JobState="))
            .unwrap_or("")
            .to_string()
    }

    fn logs(&self) -> String {
        let mut s = String::new();
        for f in ["log/slurmctld.log", "log/slurmd.log"] {
            if let Ok(t) = std::fs::read_to_string(self.dir.join(f)) {
                let tail: Vec<&str> = t.lines().rev().take(15).collect();
                s.push_str(&format!(
                    "--- {f}\n{}\n",
                    tail.into_iter().rev().collect::<Vec<_>>().join("\n")
                ));
            }
        }
        s
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new("bash")
            .arg(script())
            .arg("stop")
            .env("SLURM_LOCAL_DIR", &self.dir)
            .status();
        for pid in &self.pids {
            let alive = Path::new(&format!("/proc/{pid}")).exists();
            if alive && !std::thread::panicking() {
                panic!("daemon PID {pid} still running after slurm-local.sh stop");
            }
        }
    }
}

/// The inputs (two synthetic CTs in the TotalSegmentator layout and the study config) and the
/// unsharded run's tables, made once.
struct Reference {
    _dir: tempfile::TempDir,
    config: PathBuf,
    tables: Vec<(String, Vec<u8>)>,
}

fn reference() -> &'static Reference {
    static R: OnceLock<Reference> = OnceLock::new();
    R.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        for (case, voxel) in [("case1", "1.5"), ("case2", "1.25")] {
            let d = dir.path().join("ds").join(case);
            std::fs::create_dir_all(&d).unwrap();
            let (ok, err) = Spinedrr::new()
                .args([
                    "phantom",
                    "--levels",
                    "L1",
                    "--no-discs",
                    "--voxel-mm",
                    "1.5",
                ])
                .args(["--ct-voxel-mm", voxel, "--ct"])
                .arg(d.join("ct.nii.gz"))
                .arg("--labels-out")
                .arg(d.join("segmentations.nii.gz"))
                .arg("--out")
                .arg(dir.path().join(format!("mesh-{case}")))
                .outcome();
            assert!(ok, "{err}");
        }
        let config = dir.path().join("study.toml");
        std::fs::write(
            &config,
            r#"[anatomy]
levels = []
[[anatomy.dataset]]
name = "syn"
folder = "ds"
layout = "totalseg"
levels = ["L1"]
[geometry]
binning = 4
[perturbations]
df_px = [100, 500]
piercing_px = [0, 50]
[registration]
methods = ["direct-ap+lat", "kabsch"]
df_px = [0, 500]
piercing_px = [0]
trials = 2
trials_per_unit = 1
"#,
        )
        .unwrap();
        let whole = dir.path().join("whole");
        let (ok, err) = Spinedrr::new()
            .args(["study", "--threads", "2", "--config"])
            .arg(&config)
            .arg("--out")
            .arg(&whole)
            .outcome();
        assert!(ok, "{err}");
        let tables = csv_tables(&whole);
        assert!(tables.iter().any(|(n, _)| n == "cohort.csv"));
        Reference {
            _dir: dir,
            config,
            tables,
        }
    })
}

/// `spinedrr study --slurm --submit` (4 tasks, 1 CPU each); returns (array job, assemble job).
fn submit(c: &Cluster, config: &Path, out: &Path) -> (Option<String>, String) {
    let o = Spinedrr::new()
        .args(["study", "--config"])
        .arg(config)
        .arg("--out")
        .arg(out)
        .args([
            "--slurm",
            "--array-size",
            "4",
            "--cpus-per-task",
            "1",
            "--submit",
        ])
        .env("SLURM_CONF", &c.conf)
        .output();
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "--slurm --submit: {}\n{stdout}",
        String::from_utf8_lossy(&o.stderr)
    );
    let id = |what: &str| {
        stdout
            .lines()
            .find_map(|l| l.strip_prefix(what).map(|s| s.trim().to_string()))
    };
    (
        id("array job "),
        id("assemble job ").expect("an assemble job id"),
    )
}

fn unit_count(out: &Path) -> usize {
    std::fs::read_dir(out.join("units")).map_or(0, |d| {
        d.filter(|e| {
            e.as_ref()
                .is_ok_and(|e| e.file_name().to_string_lossy().ends_with(".json"))
        })
        .count()
    })
}

#[test]
fn job_array_and_assemble_job_give_the_unsharded_tables() {
    if let Some(why) = cannot_run() {
        eprintln!("skipping the Slurm test: {why}");
        return;
    }
    let _one = CLUSTER.lock().unwrap_or_else(|e| e.into_inner());
    let r = reference();
    let dir = tempfile::tempdir().unwrap();
    let cluster = Cluster::start(dir.path());
    let out = dir.path().join("study");
    let (array, assemble) = submit(&cluster, &r.config, &out);
    let array = array.expect("an array job");
    cluster.wait_gone(&[&array, &assemble], Duration::from_secs(600));
    assert_eq!(cluster.state(&assemble), "COMPLETED", "{}", cluster.logs());
    let script = std::fs::read_to_string(out.join("slurm/array.sbatch")).unwrap();
    assert!(script.contains("#SBATCH --array=0-3"), "{script}");
    assert!(
        csv_tables(&out) == r.tables,
        "the cluster's tables differ from the unsharded run's"
    );
}

#[test]
fn cancelled_task_is_rerun_alone_on_resubmission() {
    if let Some(why) = cannot_run() {
        eprintln!("skipping the Slurm test: {why}");
        return;
    }
    let _one = CLUSTER.lock().unwrap_or_else(|e| e.into_inner());
    let r = reference();
    let dir = tempfile::tempdir().unwrap();
    let cluster = Cluster::start(dir.path());
    let out = dir.path().join("study");
    let (array, assemble) = submit(&cluster, &r.config, &out);
    let array = array.expect("an array job");
    // The first task seen running is cancelled at once, before it can finish its units.
    let t0 = Instant::now();
    let victim = loop {
        let running = cluster.stdout("squeue", &["-h", "-r", "-j", &array, "-t", "R", "-o", "%i"]);
        if let Some(task) = running.split_whitespace().next() {
            break task.to_string();
        }
        assert!(
            t0.elapsed() < Duration::from_secs(300),
            "no task started\n{}",
            cluster.logs()
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    let st = cluster.cmd("scancel").arg(&victim).status().unwrap();
    assert!(st.success(), "scancel {victim}");
    cluster.wait_gone(&[&array, &assemble], Duration::from_secs(600));
    assert_ne!(
        cluster.state(&assemble),
        "COMPLETED",
        "the assemble job must not run after a task was cancelled"
    );
    let cfg = StudyConfig::from_file(&r.config).unwrap();
    let expanded = spinedrr::study::cohort::resolve(&cfg, &out).unwrap();
    let units = enumerate_units(&expanded).unwrap();
    assert!(
        unit_count(&out) < units.len(),
        "task {victim} finished before it was cancelled: nothing to resubmit"
    );
    let index: usize = victim.rsplit('_').next().unwrap().parse().unwrap();
    let ident = UnitIdentity::new(&expanded, &fingerprint(&expanded).unwrap(), &out).unwrap();
    let victim_units = units_of(&expanded, &units, Shard::new(index, 4).unwrap());

    let (array2, assemble2) = submit(&cluster, &r.config, &out);
    let plan: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("slurm/plan.json")).unwrap())
            .unwrap();
    assert_eq!(plan["pending_shards"], serde_json::json!([index]), "{plan}");
    let script = std::fs::read_to_string(out.join("slurm/array.sbatch")).unwrap();
    assert!(
        script.contains(&format!("#SBATCH --array={index}\n")),
        "{script}"
    );
    let array2 = array2.expect("an array job for the cancelled shard");
    cluster.wait_gone(&[&array2, &assemble2], Duration::from_secs(600));
    assert_eq!(cluster.state(&assemble2), "COMPLETED", "{}", cluster.logs());
    for u in victim_units {
        let p = out.join("units").join(format!("{}.json", u.id()));
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(text.contains(&ident.of(u)), "{}", p.display());
    }
    assert!(
        csv_tables(&out) == r.tables,
        "the resubmitted study's tables differ from the unsharded run's"
    );
}
