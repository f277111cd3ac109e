//! A study of the user's own anatomy: a box mesh file plus a landmarks JSON through `[[anatomy.meshes]]`.
//! The homography law and the exact piercing translation must hold for it too.

use std::path::Path;
use std::process::Output;

use glam::DVec3;
use spinedrr::anatomy::{TriMesh, write_mesh};
use spinedrr::study::tables::Table;

mod common;
use common::Spinedrr;

/// Runs `spinedrr study --config CFG --out OUT [EXTRA…]`.
fn run_study(cfg: &Path, out: &Path, extra: &[&str]) -> Output {
    Spinedrr::new()
        .args([
            "study",
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .args(extra)
        .output()
}

/// A 40 × 30 × 24 mm box and five of its corners as landmarks in `dir`, studied on a small grid; returns
/// the config file.
fn box_study(dir: &Path) -> std::path::PathBuf {
    let (lo, hi) = (
        DVec3::new(-20.0, -15.0, -12.0),
        DVec3::new(20.0, 15.0, 12.0),
    );
    let stl = dir.join("box.stl");
    write_mesh(&stl, &TriMesh::cuboid("box", lo, hi)).expect("write box.stl");
    let mut lm = String::from("{\"level\": \"box\", \"units\": \"mm\", \"landmarks\": {");
    let mut corners = Vec::new();
    for (i, (x, y, z)) in [
        (lo.x, lo.y, lo.z),
        (hi.x, lo.y, lo.z),
        (lo.x, hi.y, lo.z),
        (lo.x, lo.y, hi.z),
        (hi.x, hi.y, hi.z),
    ]
    .iter()
    .enumerate()
    {
        corners.push(format!("\"c{i}\": [{x}, {y}, {z}]"));
    }
    lm.push_str(&corners.join(", "));
    lm.push_str("}}");
    let lm_path = dir.join("box-landmarks.json");
    std::fs::write(&lm_path, lm).unwrap();
    let cfg = format!(
        "[anatomy]\nlevels = []\nsegment = false\nmarker_radius_mm = 5.0\n\
[[anatomy.meshes]]\nname = \"box\"\nfiles = [{:?}]\nlandmarks = {:?}\n\
[geometry]\nbinning = 2\n[perturbations]\ndf_px = [100.0, 500.0]\npiercing_px = [0.0, 20.0]\n\
[registration]\nmethods = [\"kabsch\"]\ndf_px = [0.0, 300.0]\npiercing_px = [0.0]\ntrials = 2\n",
        stl.to_str().unwrap(),
        lm_path.to_str().unwrap()
    );
    let cfg_path = dir.join("study.toml");
    std::fs::write(&cfg_path, cfg).unwrap();
    cfg_path
}

#[test]
fn mesh_target_study_obeys_the_homography_law() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cfg_path = box_study(dir.path());
    let out = dir.path().join("out");
    let o = run_study(&cfg_path, &out, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let t = Table::read(&out.join("tables/landmarks.csv")).expect("landmarks.csv");
    assert_eq!(
        t.rows.len(),
        5 * 2 * 4,
        "5 landmarks × 2 views × 4 perturbations (focal 100, 500; piercing 20; joint (100, 20))"
    );
    for r in &t.rows {
        assert_eq!(t.str(r, "target").unwrap(), "box");
        assert!(t.num(r, "pred_error_px").unwrap() <= 0.05, "{r:?}");
        if t.str(r, "family").unwrap() == "piercing" {
            let du = t.num(r, "meas_u_px").unwrap() - t.num(r, "ref_u_px").unwrap();
            assert!((du - 20.0).abs() < 1e-6, "{r:?}");
        }
    }
    let p = Table::read(&out.join("tables/projection.csv")).expect("projection.csv");
    assert!(p.rows.iter().all(|r| p.num(r, "dice").unwrap() < 1.0));
    let s = Table::read(&out.join("tables/registration_summary.csv")).expect("summary");
    let zero = s
        .rows
        .iter()
        .find(|r| s.num(r, "df_px").unwrap() == 0.0)
        .expect("Δf 0");
    assert!(s.num(zero, "rot_err_deg_mean").unwrap() < 1e-6);
}

#[test]
fn missing_mesh_file_is_named_before_work() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cfg_path = dir.path().join("study.toml");
    std::fs::write(
        &cfg_path,
        "[anatomy]\nlevels = []\n[[anatomy.meshes]]\nname = \"mine\"\nfiles = [\"/nonexistent/x.stl\"]\nlandmarks = \"/nonexistent/l.json\"\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    let o = run_study(&cfg_path, &out, &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("anatomy.meshes") && err.contains("/nonexistent/x.stl"),
        "{err}"
    );
    assert!(!out.exists());
}

/// `--quick` with `--config`: the config's own target on the quick grid (piercing 50 px instead of the
/// config's 20, registration at Δf {0, 100, 500} instead of {0, 300}).
#[test]
fn quick_runs_a_config_on_the_quick_grid() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cfg_path = box_study(dir.path());
    let out = dir.path().join("out");
    let o = run_study(&cfg_path, &out, &["--quick"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let t = Table::read(&out.join("tables/landmarks.csv")).expect("landmarks.csv");
    assert_eq!(t.rows.len(), 5 * 2 * 4);
    for r in &t.rows {
        assert_eq!(t.str(r, "target").unwrap(), "box");
        if t.str(r, "family").unwrap() == "piercing" {
            let du = t.num(r, "meas_u_px").unwrap() - t.num(r, "ref_u_px").unwrap();
            assert!((du - 50.0).abs() < 1e-6, "{r:?}");
        }
    }
    let s = Table::read(&out.join("tables/registration_summary.csv")).expect("summary");
    let mut df: Vec<f64> = s.rows.iter().map(|r| s.num(r, "df_px").unwrap()).collect();
    df.sort_by(f64::total_cmp);
    df.dedup();
    assert_eq!(df, [0.0, 100.0, 500.0]);
}
