//! The X-ray image model (Poisson statistics, `spinedrr render --photons`) and `spinedrr register
//! --intensity` end to end: a registration from a problem file, and every bad input refused with an
//! error naming its field and nothing written.

use std::path::Path;
use std::sync::Arc;

use glam::DVec3;
use serde_json::{Value, json};
use spinedrr::anatomy::{TriMesh, write_mesh};
use spinedrr::geometry::{CArm, RigidTransform, View, rotation_exp};
use spinedrr::io::{ImageF32, expected_counts, poisson_counts, write_tiff_f32};
use spinedrr::registration::intensity::{binned_view, fixed_image};
use spinedrr::render::{Backend, RenderScene, SceneMesh};

#[test]
fn poisson_counts_have_mean_and_variance_i0_exp_minus_l() {
    // 10⁵ pixels at each of four line integrals: per-pixel draws, sample mean and variance against
    // λ = I0·exp(−L) (Poisson: both equal λ).
    let n = 100_000usize;
    let ls = [0.0f32, 1.0, 3.0, 6.0];
    let li = ImageF32 {
        width: n as u32,
        height: ls.len() as u32,
        data: ls.iter().flat_map(|&l| std::iter::repeat_n(l, n)).collect(),
    };
    let i0 = 1e4;
    let counts = poisson_counts(&expected_counts(&li, i0), 42);
    for (row, &l) in counts.data.chunks(n).zip(&ls) {
        let lambda = i0 * (-f64::from(l)).exp();
        let mean = row.iter().map(|&x| f64::from(x)).sum::<f64>() / n as f64;
        let var = row
            .iter()
            .map(|&x| (f64::from(x) - mean).powi(2))
            .sum::<f64>()
            / (n - 1) as f64;
        assert!(
            (mean / lambda - 1.0).abs() < 0.02,
            "L = {l}: mean {mean} vs {lambda}"
        );
        assert!(
            (var / lambda - 1.0).abs() < 0.02,
            "L = {l}: variance {var} vs {lambda}"
        );
        assert!(
            row.iter().all(|x| x.fract() == 0.0 && *x >= 0.0),
            "counts are integers"
        );
    }
}

#[test]
fn render_photons_writes_a_seeded_radiograph_and_records_the_model() {
    let dir = tempfile::tempdir().unwrap();
    let out = |name: &str| dir.path().join(name);
    let args = |o: &Path, seed: &str| {
        vec![
            "render".to_string(),
            "--phantom".into(),
            "L3".into(),
            "--photons".into(),
            "1e4".into(),
            "--blur-px".into(),
            "1".into(),
            "--seed".into(),
            seed.into(),
            "--log".into(),
            "--out".into(),
            o.display().to_string(),
        ]
    };
    for (name, seed) in [("a.tiff", "3"), ("b.tiff", "3"), ("c.tiff", "4")] {
        let (ok, err) = crate::common::run(&args(&out(name), seed));
        assert!(ok, "{err}");
    }
    let bytes = |n: &str| std::fs::read(out(n)).unwrap();
    assert_eq!(bytes("a.tiff"), bytes("b.tiff"), "same seed, same image");
    assert_ne!(
        bytes("a.tiff"),
        bytes("c.tiff"),
        "another seed, other noise"
    );
    let sc: Value = serde_json::from_slice(&bytes("a.json")).unwrap();
    let m = &sc["details"]["xray_model"];
    assert_eq!(m["photons_i0"], json!(1e4));
    assert_eq!(
        (m["blur_px"].as_f64(), m["seed"].as_u64()),
        (Some(1.0), Some(3))
    );
    assert_eq!(m["log"], json!(true));
    assert!(
        sc["units"].as_str().unwrap().contains("ln"),
        "{}",
        sc["units"]
    );
    let (ok, err) = crate::common::run(&[
        "render",
        "--phantom",
        "L3",
        "--photons=-5",
        "--out",
        &out("bad.tiff").display().to_string(),
    ]);
    assert!(!ok && err.contains("photons"), "{err}");
}

/// A box with a sphere on one corner (no symmetry), as two meshes of different μ.
fn body() -> Vec<TriMesh> {
    vec![
        TriMesh::cuboid(
            "box",
            DVec3::new(-20.0, -12.0, -15.0),
            DVec3::new(20.0, 12.0, 15.0),
        ),
        TriMesh::icosphere("ball", DVec3::new(14.0, 6.0, 18.0), 7.0, 3),
    ]
}

/// The default AP view binned by 8 (128 × 128 px).
pub(crate) fn ap() -> View {
    binned_view(CArm::default_paper().view("ap").unwrap(), 8).unwrap()
}

/// Writes meshes, the fixed image of `truth` and a problem file; returns the problem's JSON.
pub(crate) fn write_problem(dir: &Path, truth: &RigidTransform) -> Value {
    let mut meshes = Vec::new();
    let mut spec = Vec::new();
    for (i, m) in body().into_iter().enumerate() {
        let file = format!("m{i}.stl");
        write_mesh(&dir.join(&file), &m).unwrap();
        let mu = [0.05, 0.08][i];
        spec.push(json!({"file": file, "mu_per_mm": mu}));
        meshes.push(SceneMesh {
            mesh: Arc::new(m),
            mu_per_mm: mu,
            object: format!("m{i}"),
        });
    }
    let renderer = Backend::Raster
        .renderer(RenderScene::new(meshes).unwrap())
        .unwrap();
    let v = ap();
    let fixed = fixed_image(&renderer, &v, truth, None).unwrap();
    write_tiff_f32(&dir.join("ap.tiff"), &fixed).unwrap();
    let init = RigidTransform::new(
        rotation_exp(DVec3::new(0.03, -0.02, 0.04)),
        DVec3::new(2.0, 1.0, -2.0),
    )
    .compose(truth);
    let pose = |t: &RigidTransform| json!({"R": t.rotation_rows(), "t": t.translation.to_array()});
    json!({
        "anatomy": {"meshes": spec},
        "moving": "anatomy",
        "views": [{
            "name": "ap",
            "fixed": "ap.tiff",
            "K": v.intrinsics.matrix_rows(),
            "world_to_camera": v.world_to_camera.to_rows(),
            "width": v.intrinsics.width,
            "height": v.intrinsics.height,
        }],
        "init": pose(&init),
        "truth": pose(truth),
        "similarity": "ncc",
        "levels": [2, 1],
        "global": false,
    })
}

/// An edit that breaks a problem file.
type Edit = Box<dyn Fn(&mut Value)>;

fn register(dir: &Path, problem: &Value) -> (bool, String) {
    std::fs::write(
        dir.join("p.json"),
        serde_json::to_vec_pretty(problem).unwrap(),
    )
    .unwrap();
    crate::common::run(&[
        "register",
        "--intensity",
        "--problem",
        &dir.join("p.json").display().to_string(),
        "--out",
        &dir.join("r.json").display().to_string(),
    ])
}

#[test]
fn register_intensity_recovers_the_pose_and_refuses_bad_problems_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let truth = RigidTransform::new(
        rotation_exp(DVec3::new(0.05, 0.1, -0.02)),
        DVec3::new(3.0, 0.0, -4.0),
    );
    let good = write_problem(d, &truth);
    let (ok, err) = register(d, &good);
    assert!(ok, "{err}");
    let r: Value = serde_json::from_slice(&std::fs::read(d.join("r.json")).unwrap()).unwrap();
    for key in [
        "R",
        "t",
        "similarity",
        "evaluations",
        "seconds",
        "converged",
        "rot_err_deg",
        "trans_err_mm",
    ] {
        assert!(!r[key].is_null(), "R.json lacks {key}: {r}");
    }
    // Noise-free, the true K, the same meshes: the pose comes back (the initial mTRE is ~4 mm).
    assert!(r["initial_mtre_mm"].as_f64().unwrap() > 2.0, "{r}");
    assert!(r["mtre_mm"].as_f64().unwrap() < 0.05, "{r}");
    std::fs::remove_file(d.join("r.json")).unwrap();

    let wrong_size = ImageF32::zeros(64, 64);
    write_tiff_f32(&d.join("small.tiff"), &wrong_size).unwrap();
    let bad: Vec<(&str, Edit, &str)> = vec![
        (
            "missing fixed",
            Box::new(|p| p["views"][0]["fixed"] = json!("nope.tiff")),
            "views[0].fixed",
        ),
        (
            "wrong size",
            Box::new(|p| p["views"][0]["fixed"] = json!("small.tiff")),
            "views[0].fixed",
        ),
        (
            "singular K",
            Box::new(|p| p["views"][0]["K"][0][0] = json!(0.0)),
            "views[0].K",
        ),
        (
            "not visible",
            Box::new(|p| p["init"]["t"] = json!([900.0, 0.0, 0.0])),
            "init",
        ),
        (
            "similarity",
            Box::new(|p| p["similarity"] = json!("mutual")),
            "similarity",
        ),
        (
            "anatomy",
            Box::new(|p| p["anatomy"] = json!({"phantom": "L9"})),
            "anatomy.phantom",
        ),
        (
            "mesh file",
            Box::new(|p| p["anatomy"]["meshes"][0]["file"] = json!("gone.stl")),
            "anatomy.meshes[0].file",
        ),
    ];
    for (what, edit, field) in bad {
        let mut p = good.clone();
        edit(&mut p);
        let (ok, err) = register(d, &p);
        assert!(!ok, "{what}: accepted");
        assert!(
            err.contains(field),
            "{what}: the error should name {field}: {err}"
        );
        assert!(!err.contains("panicked"), "{what}: {err}");
        assert!(!d.join("r.json").exists(), "{what}: R.json was written");
    }
    // A start 500 mm behind the AP source: the pinhole formula would put its centre near the principal
    // point, inside the detector; the error says where it is instead of quoting those pixels.
    let mut behind = good.clone();
    behind["init"]["t"] = json!([0.0, -1500.0, 0.0]);
    let (ok, err) = register(d, &behind);
    assert!(!ok, "a start behind the source was accepted");
    assert!(
        err.contains("init") && err.contains("behind the source") && !err.contains("projects to"),
        "{err}"
    );
}
