//! `spinedrr render --ct` end to end: outputs with sidecar, and clear failures on bad input.

use std::path::Path;

use glam::{DMat4, DVec3};
use spinedrr::anatomy::ct::{CtVolume, LabelMap, write_ct, write_labels};
use spinedrr::io::{Sidecar, read_tiff_f32};

mod common;
use common::run;

fn write_inputs(dir: &Path) {
    let a = DMat4::from_scale_rotation_translation(
        DVec3::splat(1.0),
        Default::default(),
        DVec3::splat(-20.0),
    );
    let mut ct = CtVolume::filled([41, 41, 41], -1000.0, a).unwrap();
    let mut seg = LabelMap::filled([41, 41, 41], 0, a).unwrap();
    for k in 5..36 {
        for j in 10..30 {
            for i in 10..30 {
                let n = ct.linear(i, j, k);
                ct.values[n] = 700.0;
                seg.values[n] = if k < 20 { 31 } else { 30 };
            }
        }
    }
    write_ct(&dir.join("ct.nii.gz"), &ct).unwrap();
    write_labels(&dir.join("seg.nii.gz"), &seg).unwrap();
}

#[test]
fn render_ct_writes_tiff_sidecar_and_preview() {
    let dir = tempfile::tempdir().unwrap();
    write_inputs(dir.path());
    let d = |n: &str| dir.path().join(n).display().to_string();
    let (ok, err) = run(&["render", "--ct", &d("ct.nii.gz"), "--out", &d("full.tiff")]);
    assert!(ok, "{err}");
    let (ok, err) = run(&[
        "render",
        "--ct",
        &d("ct.nii.gz"),
        "--seg",
        &d("seg.nii.gz"),
        "--label",
        "L1",
        "--perturb",
        "df=300",
        "--method",
        "trilinear",
        "--out",
        &d("l1.tiff"),
    ]);
    assert!(ok, "{err}");
    let full = read_tiff_f32(&dir.path().join("full.tiff")).unwrap();
    let l1 = read_tiff_f32(&dir.path().join("l1.tiff")).unwrap();
    assert_eq!((full.width, full.height), (1024, 1024));
    assert!(full.max() > 0.0 && l1.max() > 0.0);
    let side = Sidecar::read(&dir.path().join("l1.json")).unwrap();
    assert_eq!(side.perturbation_spec, "df=300");
    assert_eq!(side.details["method"], "trilinear");
    assert!(dir.path().join("l1.png").exists());
}

#[test]
fn bad_input_fails_with_a_clear_message() {
    let dir = tempfile::tempdir().unwrap();
    write_inputs(dir.path());
    let d = |n: &str| dir.path().join(n).display().to_string();
    let bytes = std::fs::read(dir.path().join("ct.nii.gz")).unwrap();
    std::fs::write(dir.path().join("cut.nii.gz"), &bytes[..bytes.len() / 3]).unwrap();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (vec!["--ct".into(), d("cut.nii.gz")], "cut.nii.gz"),
        (vec!["--ct".into(), d("nope.nii.gz")], "nope.nii.gz"),
        (
            vec![
                "--ct".into(),
                d("ct.nii.gz"),
                "--seg".into(),
                d("seg.nii.gz"),
                "--label".into(),
                "L3".into(),
            ],
            "not present",
        ),
        (
            vec![
                "--ct".into(),
                d("ct.nii.gz"),
                "--seg".into(),
                d("seg.nii.gz"),
                "--label".into(),
                "Q9".into(),
            ],
            "Q9",
        ),
        (
            vec![
                "--ct".into(),
                d("ct.nii.gz"),
                "--method".into(),
                "mip".into(),
            ],
            "mip",
        ),
        (
            vec![
                "--ct".into(),
                d("ct.nii.gz"),
                "--labels".into(),
                "mni".into(),
            ],
            "mni",
        ),
    ];
    for (args, needle) in cases {
        let mut all = vec!["render".to_string()];
        all.extend(args);
        all.extend(["--out".to_string(), d("x.tiff")]);
        let refs: Vec<&str> = all.iter().map(String::as_str).collect();
        let (ok, err) = run(&refs);
        assert!(!ok, "{all:?} must fail");
        assert!(err.contains(needle), "{all:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
}
