//! A study never loses, mixes or silently reuses results, through the real binary: a folder of another
//! config is refused naming the differing keys and cleared only on `--start-over` (a run, `--assemble` and
//! `--slurm` alike); a changed input file reruns exactly the units that read it, and the tables equal a
//! fresh run's; the output folder's lock holds against a second run, and a run in another PID namespace
//! keeps its lock and its units.

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::DVec3;
use spinedrr::anatomy::{TriMesh, write_mesh};

use crate::common::outcome;
use crate::study_hardening::{BOX_LANDMARKS, SMALL, cuboid, refused, study, tables, write};

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
    let report = crate::common::read_report(&out);
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

/// A folder that is not a study's is never written over: one holding a report, a timing table or files
/// in a product folder but no study.toml is refused (a run, `--assemble`, `--slurm`, `--start-over`
/// alike) naming what it holds; a folder whose study.toml is the user's own config (no units/ beside
/// it) is refused even with `--start-over`; and a folder with only other files gets the study beside
/// them, every one of them untouched.
#[test]
fn a_folder_that_is_not_a_study_is_never_written_over() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write(dir.path(), "c.toml", SMALL);
    let mine = dir.path().join("mine");
    std::fs::create_dir_all(mine.join("tables")).unwrap();
    std::fs::write(mine.join("report.md"), "my notes").unwrap();
    std::fs::write(mine.join("tables/projection.csv"), "a,b\n").unwrap();
    std::fs::write(mine.join("report.docx"), "my report").unwrap();
    let snapshot = tree(&mine);
    let abs = std::path::absolute(&mine).unwrap();
    for extra in [&[][..], &["--assemble"], &["--slurm"], &["--start-over"]] {
        let out = if extra == ["--slurm"] { &abs } else { &mine };
        refused(
            &study(&cfg, out, extra),
            &[
                "holds no study (no study.toml)",
                "report.md",
                "tables/ (1 entries)",
            ],
        );
        assert_eq!(tree(&mine), snapshot, "{extra:?} changed the folder");
    }
    // The user's own config as study.toml, beside their files: refused, --start-over too.
    let project = dir.path().join("project");
    std::fs::create_dir_all(project.join("figures")).unwrap();
    std::fs::write(
        project.join("study.toml"),
        format!("# my comments\n{SMALL}"),
    )
    .unwrap();
    std::fs::write(project.join("figures/plot.png"), "png").unwrap();
    let snapshot = tree(&project);
    for extra in [&[][..], &["--start-over"]] {
        refused(
            &study(&cfg, &project, extra),
            &["is not a study's record (no units/ folder beside it"],
        );
        assert_eq!(
            tree(&project),
            snapshot,
            "{extra:?} changed the project folder"
        );
    }
    // Only other files: the study runs beside them.
    let notes = dir.path().join("notes");
    std::fs::create_dir_all(&notes).unwrap();
    std::fs::write(notes.join("readme.txt"), "keep me").unwrap();
    let (ok, err) = outcome(&study(&cfg, &notes, &[]));
    assert!(ok, "{err}");
    assert_eq!(
        std::fs::read_to_string(notes.join("readme.txt")).unwrap(),
        "keep me"
    );
    assert!(notes.join("report.md").is_file());
}

/// Unit files another build wrote are run again, never reused: a folder whose units carry the
/// fingerprint the previous release gave them (the config's alone, for a unit that reads no file) is
/// resumed by running every unit, and the tables equal a fresh run's. Without this, a report would
/// name this build in its provenance while stating numbers an older one computed.
#[test]
fn units_of_another_build_are_run_again() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = write(dir.path(), "c.toml", SMALL);
    let out = dir.path().join("out");
    let (ok, err) = outcome(&study(&cfg, &out, &[]));
    assert!(ok, "{err}");
    let fresh = tables(&out);
    let recorded = std::fs::read_to_string(out.join("study.toml")).unwrap();
    let config = spinedrr::study::StudyConfig::from_toml_str(&recorded, "study.toml").unwrap();
    let old = spinedrr::study::runner::fingerprint(&config).unwrap();
    let mut n = 0;
    for e in std::fs::read_dir(out.join("units")).unwrap() {
        let p = e.unwrap().path();
        let mut unit: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        assert_ne!(
            unit["fingerprint"], old,
            "this build's fingerprint is the bare config's"
        );
        unit["fingerprint"] = serde_json::Value::String(old.clone());
        std::fs::write(&p, serde_json::to_string(&unit).unwrap()).unwrap();
        n += 1;
    }
    assert!(n > 0);
    let (ok, err) = outcome(&study(&cfg, &out, &[]));
    assert!(ok, "{err}");
    assert!(err.contains(&format!("(0 reused, {n} run)")), "{err}");
    assert_eq!(tables(&out), fresh);
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
    let root = crate::common::is_root();
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
        .env("SPINEDRR_CACHE_DIR", crate::common::MESH_CACHE)
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
