//! Hardening of `spinedrr study` (issue 11, study classes), each class run through the real binary on a
//! small config: runaway resources and work refused with the limit and the estimate; meaningless lists
//! refused naming the repeat; relative paths resolved against the config's folder; inside-out and open
//! meshes warned about (and fixed when closed); every late error moved before the first output and
//! naming its key; the output folder locked; another config's folder refused (cleared only on
//! `--start-over`); a changed input file rerunning exactly the units that read it.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use glam::DVec3;
use spinedrr::anatomy::{TriMesh, write_mesh};

use crate::common::{Spinedrr, outcome};

/// A study of L1 only, projection only, on an 8× binned detector: a second or two.
const SMALL: &str = "experiments = [\"projection\"]\nheatmaps_df_px = []\n\
[anatomy]\nlevels = [\"L1\"]\nsegment = false\nvoxel_mm = 1.5\n\
[geometry]\nbinning = 8\n[perturbations]\ndf_px = [100.0]\npiercing_px = [0.0]\n";

/// Writes `text` as `dir/name` and returns the path.
fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// `spinedrr study --config CFG --out OUT EXTRA…`.
fn study(cfg: &Path, out: &Path, extra: &[&str]) -> Output {
    Spinedrr::new()
        .arg("study")
        .arg("--config")
        .arg(cfg)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
}

/// Asserts a clean refusal: non-zero exit, no panic, every `must_name` in stderr.
fn refused(o: &Output, must_name: &[&str]) -> String {
    let (ok, err) = outcome(o);
    assert!(!ok, "accepted; stderr: {err}");
    assert!(!err.contains("panicked"), "{err}");
    for s in must_name {
        assert!(err.contains(s), "error does not name {s:?}: {err}");
    }
    err
}

/// A config `text` in a fresh folder must be refused naming `must_name`, before its output folder exists.
fn bad_config(text: &str, must_name: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write(dir.path(), "study.toml", text);
    let out = dir.path().join("out");
    refused(&study(&cfg, &out, &[]), must_name);
    assert!(!out.exists(), "{out:?} was created for {text:?}");
}

/// The box target of the mesh tests: a 40 × 30 × 24 mm cuboid (as given by `mesh`), landmarks at two
/// corners, on the small grid; returns the config.
fn box_study(dir: &Path, mesh: &TriMesh, landmarks: &str) -> PathBuf {
    write_mesh(&dir.join("box.stl"), mesh).unwrap();
    write(dir, "box.json", landmarks);
    let cfg = format!(
        "{}\n[[anatomy.meshes]]\nname = \"box\"\nfiles = [\"box.stl\"]\nlandmarks = \"box.json\"\n",
        SMALL.replace("levels = [\"L1\"]", "levels = []")
    );
    write(dir, "study.toml", &cfg)
}

const BOX_LANDMARKS: &str =
    r#"{"level": "box", "units": "mm", "landmarks": {"a": [-20, -15, -12], "b": [20, 15, 12]}}"#;

fn cuboid() -> TriMesh {
    TriMesh::cuboid(
        "box",
        DVec3::new(-20.0, -15.0, -12.0),
        DVec3::new(20.0, 15.0, 12.0),
    )
}

/// Every table of a finished study, by file name.
fn tables(out: &Path) -> Vec<(String, Vec<u8>)> {
    let mut t: Vec<_> = std::fs::read_dir(out.join("tables"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            (name, std::fs::read(&p).unwrap())
        })
        .collect();
    t.sort();
    t
}

#[test]
fn runaway_threads_and_work_are_refused_with_the_limit_and_the_estimate() {
    let o = crate::common::spinedrr(&[
        "study",
        "--quick",
        "--threads",
        "10000",
        "--out",
        "/nonexistent/x",
    ]);
    refused(&o, &["--threads 10000", "between 1 and"]);
    // The default grid has 6 targets × 6 methods × 6 Δf × 6 piercing shifts = 1296 registration cells.
    bad_config(
        "[registration]\ntrials = 1000000000\n",
        &[
            "registration.trials",
            "1296 registration cells",
            "1296000000000 trials",
        ],
    );
    bad_config(
        "[registration]\ntrials_per_unit = 1000000000\n",
        &["registration.trials_per_unit", "1000000000"],
    );
    // 20 000 focal offsets: 6 targets × 2 views × (20 000 focal + 5 piercing + 5 joint) projection units.
    let many: Vec<String> = (1..=20_000).map(|i| format!("{i}.0")).collect();
    bad_config(
        &format!("[perturbations]\ndf_px = [{}]\n", many.join(", ")),
        &["work units", &format!("{}", 6 * 2 * (20_000 + 5 + 5))],
    );
}

#[test]
fn meaningless_lists_are_refused_naming_the_repeat() {
    bad_config("experiments = []\n", &["experiments", "at least one"]);
    bad_config(
        "experiments = [\"projection\", \"projection\"]\n",
        &["experiments", "projection is listed twice"],
    );
    bad_config(
        "[anatomy]\nlevels = [\"L1\", \"L1\"]\n",
        &["anatomy.levels", "\"L1\" is listed twice"],
    );
    bad_config(
        "[anatomy]\nlevels = [\"L2\", \"l2\"]\n",
        &["anatomy.levels", "listed twice"],
    );
    bad_config(
        "[geometry]\nviews = [\"ap\", \"lat\", \"ap\"]\n",
        &["geometry.views", "ap is listed twice"],
    );
    bad_config(
        "[registration]\nmethods = [\"kabsch\", \"kabsch\"]\n",
        &["registration.methods", "kabsch is listed twice"],
    );
    bad_config(
        "[perturbations]\ndf_px = [100.0, 100.0]\n",
        &["perturbations.df_px", "100 is listed twice"],
    );
    bad_config(
        "[perturbations]\npiercing_px = [0.0, 10.0, 0.0]\n",
        &["perturbations.piercing_px", "0 is listed twice"],
    );
    bad_config(
        "[registration]\ndf_px = [0.0, 0.0]\n",
        &["registration.df_px", "listed twice"],
    );
    bad_config(
        "heatmaps_df_px = [500.0, 500.0]\n",
        &["heatmaps_df_px", "500 is listed twice"],
    );
    // Binning merges b × b pixels: 3 does not divide the 1024 px built-in detector.
    bad_config(
        "[geometry]\nbinning = 3\n",
        &["geometry.binning", "1024 × 1024"],
    );
}

#[test]
fn late_errors_come_before_any_output_and_name_the_key() {
    // Δf = −4500 px on fx = 4500 px is a focal length of 0.
    bad_config(
        "[perturbations]\ndf_px = [-4500.0]\n",
        &["perturbations.df_px", "df=-4500", "fx = 0"],
    );
    bad_config(
        "[registration]\ndf_px = [0.0, -5000.0]\n",
        &["registration.df_px", "df=-5000"],
    );
    // A phantom grid of 2.5e14 samples: refused before allocating, naming the key.
    bad_config(
        "[anatomy]\nlevels = [\"L1\"]\nsegment = false\nvoxel_mm = 0.001\n",
        &["anatomy.voxel_mm", "0.001", "GiB"],
    );
    bad_config(
        "[perturbations]\nskew_px = [1e30]\n",
        &["perturbations.skew_px"],
    );
    // One cell whose target is off the detector: named (target, view, perturbation) before any output.
    bad_config(
        &SMALL.replace("piercing_px = [0.0]", "piercing_px = [0.0, 5000.0]"),
        &[
            "perturbations.piercing_px",
            "target 'L1'",
            "view 'ap'",
            "dcx=5000",
        ],
    );
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let cfg = box_study(dir.path(), &cuboid(), BOX_LANDMARKS);
    write(
        dir.path(),
        "box.stl",
        "solid box\n  facet normal 0 0 1\n    outer loop\n      vertex 0 0\n",
    );
    refused(
        &study(&cfg, &out, &[]),
        &["anatomy.meshes.files", "target 'box'", "box.stl"],
    );
    assert!(!out.exists());
    let cfg = box_study(dir.path(), &cuboid(), "");
    refused(
        &study(&cfg, &out, &[]),
        &["anatomy.meshes.landmarks", "box.json"],
    );
    assert!(!out.exists());
    let cfg = box_study(
        dir.path(),
        &cuboid(),
        r#"{"level": "box", "units": "mm", "landmarks": {}}"#,
    );
    refused(
        &study(&cfg, &out, &[]),
        &["anatomy.meshes.landmarks", "no landmarks"],
    );
    assert!(!out.exists());
}

#[test]
fn relative_paths_are_relative_to_the_config_folder() {
    let dir = tempfile::tempdir().unwrap();
    let sub = dir.path().join("inputs");
    std::fs::create_dir(&sub).unwrap();
    let cfg = box_study(&sub, &cuboid(), BOX_LANDMARKS);
    let elsewhere = tempfile::tempdir().unwrap();
    // From an unrelated working directory, with the config given by absolute path …
    let o = Spinedrr::new()
        .current_dir(elsewhere.path())
        .args(["study", "--config"])
        .arg(&cfg)
        .args(["--out", "out"])
        .output();
    let (ok, err) = outcome(&o);
    assert!(ok, "{err}");
    assert!(elsewhere.path().join("out/tables/projection.csv").is_file());
    // … and from the config's parent, with a relative --config: the same tables.
    let o = Spinedrr::new()
        .current_dir(dir.path())
        .args(["study", "--config", "inputs/study.toml", "--out", "out2"])
        .output();
    let (ok, err) = outcome(&o);
    assert!(ok, "{err}");
    assert_eq!(
        tables(&elsewhere.path().join("out")),
        tables(&dir.path().join("out2"))
    );
}

#[test]
fn inside_out_meshes_are_flipped_and_open_ones_warned_about() {
    let dir = tempfile::tempdir().unwrap();
    let outward = dir.path().join("outward");
    let cfg = box_study(dir.path(), &cuboid(), BOX_LANDMARKS);
    let (ok, err) = outcome(&study(&cfg, &outward, &[]));
    assert!(ok && !err.contains("warning"), "{err}");
    // The same box wound inward: flipped with a warning, and then the same study as the outward box.
    let mut inward = cuboid();
    inward.flip();
    let cfg = box_study(dir.path(), &inward, BOX_LANDMARKS);
    let flipped = dir.path().join("flipped");
    let (ok, err) = outcome(&study(&cfg, &flipped, &[]));
    assert!(ok, "{err}");
    assert!(
        err.contains("target 'box'") && err.contains("inside out"),
        "{err}"
    );
    assert_eq!(tables(&outward), tables(&flipped));
    // One face (two triangles) missing: runs, and says how open it is, as `render` does.
    let mut open = cuboid();
    open.triangles.truncate(open.triangles.len() - 2);
    let cfg = box_study(dir.path(), &open, BOX_LANDMARKS);
    let (ok, err) = outcome(&study(&cfg, &dir.path().join("open"), &[]));
    assert!(ok, "{err}");
    assert!(
        err.contains("not closed") && err.contains("4 boundary edges"),
        "{err}"
    );
}

#[test]
fn a_folder_of_another_config_is_refused_and_cleared_only_on_start_over() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    // Config A writes heatmaps at Δf 100 and has 2 × 2 projection units.
    let a = write(
        dir.path(),
        "a.toml",
        &SMALL
            .replace("heatmaps_df_px = []", "heatmaps_df_px = [100.0]")
            .replace("df_px = [100.0]", "df_px = [100.0, 200.0]"),
    );
    let (ok, err) = outcome(&study(&a, &out, &[]));
    assert!(ok, "{err}");
    let heatmaps = |out: &Path| -> Vec<String> {
        std::fs::read_dir(out.join("figures"))
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with("heatmap_"))
            .collect()
    };
    assert!(!heatmaps(&out).is_empty());
    let units = |out: &Path| std::fs::read_dir(out.join("units")).unwrap().count();
    assert_eq!(units(&out), 4, "2 views × 2 focal offsets");
    let snapshot = tree(&out);
    // Config B (no heatmaps, 2 units) into the same folder: refused, naming the keys that differ, and
    // not one file of A's run changed (a run, an --assemble and a --slurm preparation alike).
    let b = write(dir.path(), "b.toml", SMALL);
    for extra in [&[][..], &["--assemble"], &["--slurm"]] {
        let out_arg = if extra == ["--slurm"] {
            std::path::absolute(&out).unwrap()
        } else {
            out.clone()
        };
        let err = refused(
            &study(&b, &out_arg, extra),
            &[
                "another study config",
                "heatmaps_df_px: [100.0, 200.0] → []",
                "perturbations.df_px: [100.0, 200.0] → [100.0]",
                "--start-over",
            ],
        );
        assert_eq!(tree(&out), snapshot, "{extra:?} changed A's folder: {err}");
    }
    // --start-over: A's figures and units are gone, B runs.
    let (ok, err) = outcome(&study(&b, &out, &["--start-over"]));
    assert!(ok, "{err}");
    assert!(
        err.contains("another study config") && err.contains("figures/"),
        "{err}"
    );
    assert!(
        heatmaps(&out).is_empty(),
        "A's heatmaps remain: {:?}",
        heatmaps(&out)
    );
    assert_eq!(units(&out), 2);
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        !report.contains("heatmap_"),
        "B's report links A's heatmaps"
    );
    let recorded = std::fs::read_to_string(out.join("study.toml")).unwrap();
    let recorded = spinedrr::study::StudyConfig::from_toml_str(&recorded, "study.toml").unwrap();
    assert_eq!(
        recorded.perturbations.df_px,
        vec![100.0],
        "study.toml is not B's"
    );
    // The same config again: nothing to clear, everything reused.
    let (ok, err) = outcome(&study(&b, &out, &[]));
    assert!(
        ok && !err.contains("another study config") && err.contains("2 reused"),
        "{err}"
    );
}

/// Every file under `dir` (relative path) with its bytes and modification time.
fn tree(dir: &Path) -> Vec<(PathBuf, Vec<u8>, std::time::SystemTime)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let m = std::fs::metadata(&p).unwrap().modified().unwrap();
                out.push((
                    p.strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                    m,
                ));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn a_changed_input_file_reruns_exactly_the_units_that_read_it() {
    let dir = tempfile::tempdir().unwrap();
    // Two mesh targets (box and its copy crate) and the phantom's L1: 3 targets × 2 views units.
    write_mesh(&dir.path().join("box.stl"), &cuboid()).unwrap();
    write_mesh(&dir.path().join("crate.stl"), &cuboid()).unwrap();
    write(dir.path(), "box.json", BOX_LANDMARKS);
    write(
        dir.path(),
        "crate.json",
        &BOX_LANDMARKS.replace("\"box\"", "\"crate\""),
    );
    let cfg = write(
        dir.path(),
        "study.toml",
        &format!(
            "{SMALL}\n[[anatomy.meshes]]\nname = \"box\"\nfiles = [\"box.stl\"]\nlandmarks = \"box.json\"\n\
             [[anatomy.meshes]]\nname = \"crate\"\nfiles = [\"crate.stl\"]\nlandmarks = \"crate.json\"\n"
        ),
    );
    let out = dir.path().join("out");
    let (ok, err) = outcome(&study(&cfg, &out, &[]));
    assert!(ok, "{err}");
    let (ok, err) = outcome(&study(&cfg, &out, &[]));
    assert!(ok && err.contains("6 reused, 0 run"), "{err}");
    // The crate grows by 4 mm: its two units rerun, the box's and L1's are reused.
    let bigger = TriMesh::cuboid(
        "crate",
        DVec3::new(-22.0, -17.0, -14.0),
        DVec3::new(22.0, 17.0, 14.0),
    );
    write_mesh(&dir.path().join("crate.stl"), &bigger).unwrap();
    let (ok, err) = outcome(&study(&cfg, &out, &[]));
    assert!(ok && err.contains("4 reused, 2 run"), "{err}");
    // The resumed tables are a fresh run's.
    let fresh = dir.path().join("fresh");
    let (ok, err) = outcome(&study(&cfg, &fresh, &[]));
    assert!(ok, "{err}");
    assert_eq!(tables(&out), tables(&fresh));
    // The landmarks file is an input too; and a missing input fails naming it, touching nothing.
    write(
        dir.path(),
        "box.json",
        &BOX_LANDMARKS.replace("[20, 15, 12]", "[20, 15, -12]"),
    );
    let (ok, err) = outcome(&study(&cfg, &out, &[]));
    assert!(ok && err.contains("4 reused, 2 run"), "{err}");
    let snapshot = tree(&out);
    std::fs::remove_file(dir.path().join("crate.json")).unwrap();
    refused(&study(&cfg, &out, &[]), &["crate.json"]);
    assert_eq!(tree(&out), snapshot);
}

#[test]
fn the_output_folder_is_locked_against_a_second_run() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let cfg = write(dir.path(), "study.toml", SMALL);
    let (ok, err) = outcome(&study(&cfg, &out, &[]));
    assert!(ok, "{err}");
    let lock = out.join(".study.lock");
    assert!(!lock.exists(), "the lock outlived its run");
    let before = tables(&out);
    // A live process holds the lock: refused, naming it, and the folder untouched.
    let mut holder = Command::new("sleep").arg("60").spawn().expect("sleep");
    std::fs::write(&lock, holder.id().to_string()).unwrap();
    let b = write(
        dir.path(),
        "b.toml",
        &SMALL.replace("df_px = [100.0]", "df_px = [300.0]"),
    );
    let err = refused(
        &study(&b, &out, &[]),
        &[&format!("PID {}", holder.id()), ".study.lock"],
    );
    assert!(!err.contains("another study config"), "{err}");
    assert_eq!(tables(&out), before);
    assert!(lock.exists(), "a live run's lock was removed");
    // The holder dies: its lock is stale, taken over with a warning, and released at the end.
    holder.kill().unwrap();
    holder.wait().unwrap();
    let (ok, err) = outcome(&study(&cfg, &out, &[]));
    assert!(ok, "{err}");
    assert!(
        err.contains("stale lock") && err.contains(&format!("PID {}", holder.id())),
        "{err}"
    );
    assert!(!lock.exists());
    assert_eq!(tables(&out), before);
}

#[test]
fn a_run_in_another_pid_namespace_keeps_its_lock_and_its_units() {
    let root = Command::new("id")
        .arg("-u")
        .output()
        .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0");
    let unshare = Command::new("unshare").arg("--version").output().is_ok();
    if !(root && unshare) {
        eprintln!("skipping: a PID namespace needs root and unshare (util-linux)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    // 2 views × 24 focal offsets on one thread: long enough to be caught holding the lock.
    let dfs: Vec<String> = (1..=24).map(|i| format!("{}.0", 20 * i)).collect();
    let cfg = write(
        dir.path(),
        "study.toml",
        &SMALL.replace("df_px = [100.0]", &format!("df_px = [{}]", dfs.join(", "))),
    );
    let a = Command::new("unshare")
        .args(["--pid", "--fork", "--mount-proc"])
        .arg(env!("CARGO_BIN_EXE_spinedrr"))
        .arg("study")
        .arg("--config")
        .arg(&cfg)
        .arg("--out")
        .arg(&out)
        .args(["--threads", "1"])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("unshare");
    let lock = out.join(".study.lock");
    let t0 = std::time::Instant::now();
    while !lock.exists() && t0.elapsed() < std::time::Duration::from_secs(120) {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let owner = std::fs::read_to_string(&lock).expect("the run in the namespace took no lock");
    // PID 1 or 2 of its namespace, which here is a process of ours, or none at all.
    assert!(owner.contains("pid_namespace"), "{owner}");
    let err = refused(
        &study(&cfg, &out, &["--max-units", "0"]),
        &["another PID namespace", ".study.lock"],
    );
    assert!(!err.contains("taking over"), "{err}");
    let o = a.wait_with_output().unwrap();
    assert!(
        o.status.success(),
        "the first run failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let units = std::fs::read_dir(out.join("units")).unwrap().count();
    assert_eq!(units, 48, "the first run's units");
    assert!(out.join("report.md").exists() && !lock.exists());
}

#[test]
fn slurm_scripts_sbatch_would_reject_are_never_written() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write(dir.path(), "study.toml", SMALL);
    let spaced = std::path::absolute(dir.path().join("out dir")).unwrap();
    refused(&study(&cfg, &spaced, &["--slurm"]), &["--out", "#SBATCH"]);
    assert!(!spaced.exists());
    let out = std::path::absolute(dir.path().join("out")).unwrap();
    for t in ["1:2:3:4", "30m", "1-"] {
        refused(
            &study(&cfg, &out, &["--slurm", "--time", t]),
            &["--time", t, "not a Slurm time limit"],
        );
    }
    assert!(!out.exists());
}

#[test]
fn a_config_with_no_work_is_refused_not_reported_complete() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write(
        dir.path(),
        "study.toml",
        &SMALL
            .replace("df_px = [100.0]", "df_px = []")
            .replace("piercing_px = [0.0]", "piercing_px = []"),
    );
    let out = dir.path().join("out");
    refused(&study(&cfg, &out, &[]), &["no work unit", "df_px"]);
    assert!(!out.exists());
}
