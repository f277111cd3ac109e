//! `spinedrr render --ct` end to end: outputs with sidecar, and clear failures on bad input.

use std::path::Path;

use glam::{DMat4, DVec3};
use spinedrr::anatomy::ct::{CtVolume, LabelMap, write_ct, write_labels};
use spinedrr::io::{Sidecar, read_tiff_f32};

use crate::common::run;

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

/// The inputs of [`write_inputs`] moved by `offset` (mm) in the world, as a scanner would place them.
fn write_moved(dir: &Path, offset: DVec3, ct_name: &str, seg_name: &str) {
    let src = tempfile::tempdir().unwrap();
    write_inputs(src.path());
    let mut ct = spinedrr::anatomy::ct::read_ct(&src.path().join("ct.nii.gz")).unwrap();
    let mut seg = spinedrr::anatomy::ct::read_labels(&src.path().join("seg.nii.gz")).unwrap();
    ct.index_to_world = DMat4::from_translation(offset) * ct.index_to_world;
    seg.index_to_world = ct.index_to_world;
    write_ct(&dir.join(ct_name), &ct).unwrap();
    write_labels(&dir.join(seg_name), &seg).unwrap();
}

fn same_pixels(a: &Path, b: &Path) {
    let (a, b) = (read_tiff_f32(a).unwrap(), read_tiff_f32(b).unwrap());
    assert!(a.max() > 0.0);
    assert!(
        a.data
            .iter()
            .zip(&b.data)
            .all(|(x, y)| x.to_bits() == y.to_bits())
    );
}

#[test]
fn a_ct_at_scanner_coordinates_is_placed_where_the_views_aim() {
    let dir = tempfile::tempdir().unwrap();
    let d = |n: &str| dir.path().join(n).display().to_string();
    // Far from the world origin: as read, every ray misses it.
    let offset = DVec3::new(150.0, -180.0, -300.0);
    write_moved(dir.path(), offset, "far.nii.gz", "far_seg.nii.gz");
    // L1 (label 31) fills voxels i, j ∈ 10..30, k ∈ 5..20 of a grid whose voxel 0 sits at −20 mm: its
    // voxel centroid is (−0.5, −0.5, −8) mm before the move.
    let l1_centre = DVec3::new(-0.5, -0.5, -8.0) + offset;
    let shifted = tempfile::tempdir().unwrap();
    write_moved(
        shifted.path(),
        -DVec3::new(-0.5, -0.5, -8.0),
        "ct.nii.gz",
        "seg.nii.gz",
    );
    let s = |n: &str| shifted.path().join(n).display().to_string();
    let l1 = |ct: &str, seg: &str, extra: &[&str], out: &str| {
        let mut args = vec![
            "render", "--ct", ct, "--seg", seg, "--label", "L1", "--view", "lat",
        ];
        args.extend_from_slice(extra);
        args.extend(["--out", out]);
        run(&args)
    };
    // Default (auto = label-centre): the same pixels as the CT moved by hand so L1's centre is at the
    // origin and rendered where it is.
    let (ok, err) = l1(&d("far.nii.gz"), &d("far_seg.nii.gz"), &[], &d("auto.tiff"));
    assert!(ok, "{err}");
    let (ok, err) = l1(
        &s("ct.nii.gz"),
        &s("seg.nii.gz"),
        &["--placement", "keep"],
        &d("hand.tiff"),
    );
    assert!(ok, "{err}");
    same_pixels(&dir.path().join("auto.tiff"), &dir.path().join("hand.tiff"));
    let side = Sidecar::read(&dir.path().join("auto.json")).unwrap();
    let p = &side.details["placement"];
    assert_eq!(p["mode"], "label-centre");
    for a in 0..3 {
        let c = p["centre_mm"][a].as_f64().unwrap();
        let t = p["translation_mm"][a].as_f64().unwrap();
        assert!(
            (c - l1_centre[a]).abs() < 1e-9 && (t + l1_centre[a]).abs() < 1e-9,
            "{p}"
        );
    }
    // Without a label the volume's box centre goes to the origin: the unmoved grid, centred on 0.
    let (ok, err) = run(&["render", "--ct", &d("far.nii.gz"), "--out", &d("vol.tiff")]);
    assert!(ok, "{err}");
    write_inputs(dir.path());
    let (ok, err) = run(&[
        "render",
        "--ct",
        &d("ct.nii.gz"),
        "--placement",
        "keep",
        "--out",
        &d("origin.tiff"),
    ]);
    assert!(ok, "{err}");
    same_pixels(
        &dir.path().join("vol.tiff"),
        &dir.path().join("origin.tiff"),
    );
    let side = Sidecar::read(&dir.path().join("vol.json")).unwrap();
    assert_eq!(side.details["placement"]["mode"], "volume-centre");
    // Kept at scanner coordinates, nothing reaches the detector: a clear error naming the option.
    let (ok, err) = l1(
        &d("far.nii.gz"),
        &d("far_seg.nii.gz"),
        &["--placement", "keep"],
        &d("k.tiff"),
    );
    assert!(
        !ok && err.contains("--placement keep") && err.contains("nothing of the anatomy"),
        "{err}"
    );
    assert!(!dir.path().join("k.tiff").exists());
}

#[test]
fn a_label_map_off_the_cts_grid_is_named_with_the_field_that_differs() {
    let dir = tempfile::tempdir().unwrap();
    write_inputs(dir.path());
    let d = |n: &str| dir.path().join(n).display().to_string();
    let seg = spinedrr::anatomy::ct::read_labels(&dir.path().join("seg.nii.gz")).unwrap();
    let mut shifted = seg.clone();
    shifted.index_to_world =
        DMat4::from_translation(DVec3::new(0.0, 0.0, 5.0)) * seg.index_to_world;
    write_labels(&dir.path().join("shifted.nii.gz"), &shifted).unwrap();
    let mut flipped = seg.clone();
    flipped.index_to_world = seg.index_to_world * DMat4::from_scale(DVec3::new(-1.0, 1.0, 1.0));
    write_labels(&dir.path().join("flipped.nii.gz"), &flipped).unwrap();
    for (file, field) in [
        ("shifted.nii.gz", "origin"),
        ("flipped.nii.gz", "voxel axis i"),
    ] {
        let (ok, err) = run(&[
            "render",
            "--ct",
            &d("ct.nii.gz"),
            "--seg",
            &d(file),
            "--label",
            "L1",
            "--out",
            &d("x.tiff"),
        ]);
        assert!(!ok, "{file} accepted");
        assert!(
            err.contains(file) && err.contains("affine") && err.contains(field),
            "{file}: {err}"
        );
        assert!(!err.contains("panicked"), "{err}");
    }
}
