//! `spinedrr calibrate`: a run writes calibrations.csv (one row per trial and view) and phantom.json
//! (the BB centres it was given, the true geometry, every placement), and bad input — too few BBs,
//! collinear BBs, coplanar BBs for the 3-D method, BBs off the detector, σ < 0, N = 0 — fails with a
//! clear message, a non-zero exit and nothing written.

use std::path::Path;

use crate::common::Spinedrr;

fn calibrate(args: &[&str], out: &Path) -> (bool, String) {
    Spinedrr::new()
        .arg("calibrate")
        .args(args)
        .arg("--quiet")
        .arg("--out")
        .arg(out)
        .outcome()
}

#[test]
fn a_helix_run_writes_one_row_per_trial_and_view_and_the_phantom_it_used() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("mine.json");
    // A user's 3-D phantom: two rings of 8 BBs on a 35 mm cylinder, 60 mm apart.
    let mut bbs = Vec::new();
    for (ring, z) in [(0, -30.0), (1, 30.0)] {
        for i in 0..8 {
            let a = std::f64::consts::TAU * (i as f64 + 0.5 * ring as f64) / 8.0;
            bbs.push([35.0 * a.cos(), 35.0 * a.sin(), z]);
        }
    }
    let text = serde_json::json!({ "name": "two rings", "bbs_mm": bbs }).to_string();
    std::fs::write(&file, text).unwrap();
    let out = dir.path().join("out");
    let (ok, err) = calibrate(
        &[
            "--phantom",
            file.to_str().unwrap(),
            "--noise-px",
            "0.2",
            "--trials",
            "6",
        ],
        &out,
    );
    assert!(ok, "{err}");
    let mut r = csv::Reader::from_path(out.join("calibrations.csv")).unwrap();
    let header = r.headers().unwrap().clone();
    for col in [
        "trial",
        "view",
        "fx",
        "fy",
        "cx",
        "cy",
        "skew",
        "reprojection_rms_px",
        "heldout_err_mm",
    ] {
        assert!(
            header.iter().any(|h| h == col),
            "{col} missing from {header:?}"
        );
    }
    let rows: Vec<csv::StringRecord> = r.records().map(|x| x.unwrap()).collect();
    assert_eq!(rows.len(), 6 * 2, "6 trials × AP, LAT");
    let col = |name: &str| header.iter().position(|h| h == name).unwrap();
    for row in &rows {
        let fx: f64 = row[col("fx")].parse().unwrap();
        let rms: f64 = row[col("reprojection_rms_px")].parse().unwrap();
        assert!((fx - 4500.0).abs() < 200.0, "{fx}");
        assert!(rms > 0.05 && rms < 0.3, "{rms}");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("phantom.json")).unwrap()).unwrap();
    let back = json["phantom"]["bbs_mm"].as_array().unwrap();
    assert_eq!(back.len(), 16);
    for (a, b) in back.iter().zip(&bbs) {
        for k in 0..3 {
            assert!((a[k].as_f64().unwrap() - b[k]).abs() < 1e-5);
        }
    }
    assert_eq!(json["placements"].as_array().unwrap().len(), 2);
    assert_eq!(json["views"][0]["name"], "ap");
}

#[test]
fn bad_input_fails_clearly_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, bbs: serde_json::Value| {
        let p = dir.path().join(name);
        std::fs::write(&p, serde_json::json!({ "bbs_mm": bbs }).to_string()).unwrap();
        p.to_str().unwrap().to_string()
    };
    let few = write(
        "few.json",
        serde_json::json!([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10], [10, 10, 10]]),
    );
    let line = write(
        "line.json",
        serde_json::json!([
            [0, 0, 0],
            [1, 1, 1],
            [2, 2, 2],
            [3, 3, 3],
            [4, 4, 4],
            [5, 5, 5],
            [6, 6, 6]
        ]),
    );
    let flat = write(
        "flat.json",
        serde_json::json!([
            [0, 0, 0],
            [10, 0, 0],
            [0, 10, 0],
            [10, 10, 0],
            [5, 5, 0],
            [20, 5, 0],
            [5, 20, 0]
        ]),
    );
    let huge = write(
        "huge.json",
        serde_json::json!([
            [-900, 0, 0],
            [900, 0, 0],
            [0, -900, 0],
            [0, 900, 0],
            [0, 0, -900],
            [0, 0, 900],
            [300, 300, 300]
        ]),
    );
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["--phantom", &few, "--noise-px", "0.1"], "at least 6"),
        (vec!["--phantom", &line, "--noise-px", "0.1"], "collinear"),
        (
            vec!["--phantom", &flat, "--noise-px", "0.1", "--method", "dlt"],
            "coplanar",
        ),
        (vec!["--phantom", &huge, "--noise-px", "0.1"], "off the"),
        (
            vec!["--phantom", "helix", "--noise-px=-0.5"],
            "must be a finite number ≥ 0",
        ),
        (
            vec!["--phantom", "plate", "--noise-px", "0.1", "--trials", "0"],
            "trials",
        ),
        (
            vec![
                "--phantom",
                "helix",
                "--noise-px",
                "0.1",
                "--method",
                "zhang",
            ],
            "not planar",
        ),
    ];
    for (args, expect) in cases {
        let out = dir.path().join("out");
        let (ok, err) = calibrate(&args, &out);
        assert!(!ok, "{args:?} succeeded");
        assert!(
            err.contains(expect),
            "{args:?}: expected '{expect}' in: {err}"
        );
        assert!(!out.exists(), "{args:?} wrote {}", out.display());
    }
}
