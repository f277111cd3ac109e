//! `spinedrr register` end to end: real binary, real files.

use std::path::Path;

use glam::DVec3;
use serde_json::{Value, json};
use spinedrr::geometry::{CArm, RigidTransform, rotation_exp};

mod common;
use common::Spinedrr;

fn landmarks() -> Vec<(&'static str, [f64; 3])> {
    vec![
        ("corner_ant_sup", [0.0, 15.0, 12.0]),
        ("corner_ant_inf", [0.0, 15.0, -12.0]),
        ("corner_post_sup", [0.0, -15.0, 12.5]),
        ("corner_post_inf", [0.0, -15.0, -12.0]),
        ("pedicle_left", [-12.0, -22.0, 4.0]),
        ("pedicle_right", [12.0, -22.0, 4.0]),
        ("spinous_tip", [0.0, -55.0, -8.0]),
    ]
}

fn truth() -> RigidTransform {
    RigidTransform::new(
        rotation_exp(DVec3::new(-0.04, 0.1, 0.07)),
        DVec3::new(-3.0, 4.0, 1.0),
    )
}

/// A problem JSON with noise-free observations of `lms` in the given views.
fn problem_json(lms: &[(&str, [f64; 3])], views: &[&str]) -> Value {
    let carm = CArm::default_paper();
    let t = truth();
    let views: Vec<Value> = views
        .iter()
        .map(|n| {
            let v = carm.view(n).unwrap();
            let observed: serde_json::Map<String, Value> = lms
                .iter()
                .map(|(name, p)| {
                    let x = v.project(t.apply(DVec3::from(*p)));
                    (name.to_string(), json!([x.x, x.y]))
                })
                .collect();
            json!({"name": n, "K": v.intrinsics.matrix_rows(),
                   "world_to_camera": v.world_to_camera.to_rows(), "observed": observed})
        })
        .collect();
    let l3: serde_json::Map<String, Value> =
        lms.iter().map(|(n, p)| (n.to_string(), json!(p))).collect();
    json!({"landmarks_3d": l3, "views": views,
           "truth": {"R": t.rotation_rows(), "t": t.translation.to_array()}})
}

fn run(dir: &Path, problem: &str, args: &[&str]) -> (bool, String, Option<Value>) {
    let p = dir.join("P.json");
    let out = dir.join("R.json");
    let _ = std::fs::remove_file(&out);
    std::fs::write(&p, problem).unwrap();
    let (ok, err) = Spinedrr::new()
        .arg("register")
        .arg("--problem")
        .arg(&p)
        .arg("--out")
        .arg(&out)
        .args(args)
        .outcome();
    let r = std::fs::read_to_string(&out)
        .ok()
        .map(|t| serde_json::from_str(&t).unwrap());
    (ok, err, r)
}

#[test]
fn every_method_recovers_the_truth_from_a_perturbed_init() {
    let dir = tempfile::tempdir().unwrap();
    let text = problem_json(&landmarks(), &["ap", "lat"]).to_string();
    for args in [
        &["--method", "direct"][..],
        &["--method", "kabsch"][..],
        &["--method", "direct", "--view", "lat"][..],
        &["--method", "opencv", "--view", "ap"][..],
        &["--method", "opencv-sqpnp", "--view", "lat"][..],
    ] {
        let mut a = args.to_vec();
        a.extend([
            "--init-rot-deg",
            "10",
            "--init-trans-mm",
            "20",
            "--seed",
            "3",
        ]);
        let (ok, err, r) = run(dir.path(), &text, &a);
        assert!(ok, "{args:?}: {err}");
        let r = r.unwrap();
        assert!(r["rot_err_deg"].as_f64().unwrap() <= 1e-6, "{args:?}: {r}");
        assert!(r["trans_err_mm"].as_f64().unwrap() <= 1e-6, "{args:?}: {r}");
        assert!(r["residual_px"].as_f64().unwrap() < 1e-6);
        assert_eq!(r["converged"], json!(true));
        let back = RigidTransform::from_rt(
            serde_json::from_value(r["R"].clone()).unwrap(),
            serde_json::from_value(r["t"].clone()).unwrap(),
            "R.json",
        );
        assert!(back.is_ok());
    }
    // Noise leaves a residual, reproducibly for a seed.
    let (ok, _, r1) = run(dir.path(), &text, &["--noise-px", "1", "--seed", "9"]);
    let (_, _, r2) = run(dir.path(), &text, &["--noise-px", "1", "--seed", "9"]);
    assert!(ok);
    assert_eq!(r1, r2);
    assert!(r1.unwrap()["residual_px"].as_f64().unwrap() > 0.1);
}

#[test]
fn bad_input_fails_with_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let good = problem_json(&landmarks(), &["ap", "lat"]);
    let mut cases: Vec<(String, Vec<&str>, &str)> = Vec::new();
    // Three landmarks in one view.
    let few = problem_json(&landmarks()[..3], &["ap"]).to_string();
    cases.push((few, vec![], "at least 4 landmarks"));
    // Two landmarks in two views.
    let two = problem_json(&landmarks()[..2], &["ap", "lat"]).to_string();
    cases.push((two, vec![], "at least 3 landmarks"));
    // A name that is not a model landmark.
    let mut renamed = good.clone();
    let obs = renamed["views"][0]["observed"].as_object_mut().unwrap();
    let v = obs.remove("spinous_tip").unwrap();
    obs.insert("spinous_tpi".into(), v);
    cases.push((renamed.to_string(), vec![], "views[0].observed.spinous_tpi"));
    // Collinear model landmarks.
    let line: Vec<(&str, [f64; 3])> = landmarks()
        .iter()
        .enumerate()
        .map(|(i, (n, _))| (*n, [0.0, 0.0, i as f64 * 5.0]))
        .collect();
    cases.push((
        problem_json(&line, &["ap"]).to_string(),
        vec![],
        "collinear",
    ));
    // NaN written as JSON cannot parse; a string where a number belongs names the place.
    let nan = good
        .to_string()
        .replacen("[0.0,15.0,12.0]", "[NaN,15.0,12.0]", 1);
    cases.push((nan, vec![], "P.json"));
    cases.push(("{\"landmarks_3d\": {".into(), vec![], "P.json"));
    cases.push(("{\"views\": []}".into(), vec![], "landmarks_3d"));
    cases.push((
        good.to_string(),
        vec!["--method", "simplex"],
        "unknown method",
    ));
    cases.push((good.to_string(), vec!["--method", "opencv"], "single-view"));
    cases.push((good.to_string(), vec!["--view", "oblique"], "oblique"));
    cases.push((good.to_string(), vec!["--noise-px", "NaN"], "noise"));
    for (text, args, expect) in cases {
        let (ok, err, r) = run(dir.path(), &text, &args);
        assert!(!ok, "{expect}: should fail");
        assert!(r.is_none());
        assert!(err.contains(expect), "expected '{expect}' in: {err}");
    }
}
