//! `spinedrr mesh` and `spinedrr phantom --ct` end to end, and their failures on bad input.

use std::path::Path;

use glam::{DMat4, DQuat, DVec3};
use spinedrr::anatomy::ct::{LabelMap, read_ct, read_labels, write_labels};
use spinedrr::anatomy::{read_landmarks, read_mesh};

use crate::common::run;

/// Two labels on an oblique, anisotropic grid: L1 (31) a box of voxels, L2 (30) an ellipsoid below it.
fn write_two_vertebrae(path: &Path) -> LabelMap {
    let rot = DQuat::from_axis_angle(DVec3::new(1.0, 2.0, 0.5).normalize(), 0.4);
    let affine = DMat4::from_scale_rotation_translation(
        DVec3::new(0.8, 0.9, 1.5),
        rot,
        DVec3::new(10.0, -20.0, 5.0),
    );
    let mut seg = LabelMap::filled([48, 44, 40], 0, affine).unwrap();
    for k in 0..40 {
        for j in 0..44 {
            for i in 0..48 {
                let n = seg.linear(i, j, k);
                if (8..38).contains(&i) && (10..34).contains(&j) && (22..34).contains(&k) {
                    seg.values[n] = 31;
                }
                let d = DVec3::new(i as f64 - 24.0, j as f64 - 22.0, k as f64 - 11.0)
                    / DVec3::new(14.0, 12.0, 8.0);
                if d.length() <= 1.0 {
                    seg.values[n] = 30;
                }
            }
        }
    }
    write_labels(path, &seg).unwrap();
    seg
}

#[test]
fn mesh_writes_a_closed_surface_with_the_voxel_volume() {
    let dir = tempfile::tempdir().unwrap();
    let seg_path = dir.path().join("seg.nii.gz");
    let seg = write_two_vertebrae(&seg_path);
    let d = |n: &str| dir.path().join(n).display().to_string();
    for (label, id, out, extra) in [
        ("L1", 31, "l1.stl", vec![]),
        ("L2", 30, "l2.obj", vec!["--smooth", "5"]),
        ("30", 30, "l2_small.ply", vec!["--target-triangles", "800"]),
    ] {
        let mut args = vec![
            "mesh",
            "--seg",
            &seg_path.to_str().unwrap(),
            "--label",
            label,
        ];
        let o = d(out);
        args.extend(["--out", o.as_str()]);
        args.extend(extra.iter().copied());
        let (ok, err) = run(&args);
        assert!(ok, "{err}");
        let m = read_mesh(Path::new(&o)).unwrap();
        assert!(m.check().is_watertight(), "{out}: {:?}", m.check());
        let voxels = seg.count(id) as f64 * seg.voxel_volume_mm3();
        let rel = (m.volume() - voxels).abs() / voxels;
        assert!(
            rel < 0.02,
            "{out}: mesh {} vs voxels {voxels} mm³",
            m.volume()
        );
        if out == "l2_small.ply" {
            assert!(
                (m.triangles.len() as f64 - 800.0).abs() <= 8.0,
                "{}",
                m.triangles.len()
            );
        }
    }
}

#[test]
fn phantom_ct_round_trips_into_mesh_and_auto_landmarks() {
    let dir = tempfile::tempdir().unwrap();
    let d = |n: &str| dir.path().join(n).display().to_string();
    let (ok, err) = run(&[
        "phantom",
        "--levels",
        "L3",
        "--no-discs",
        "--voxel-mm",
        "1.0",
        "--out",
        &d("ph"),
        "--ct",
        &d("ct.nii.gz"),
        "--ct-voxel-mm",
        "0.7",
        "--labels-out",
        &d("seg.nii.gz"),
    ]);
    assert!(ok, "{err}");
    let ct = read_ct(&dir.path().join("ct.nii.gz")).unwrap();
    let seg = read_labels(&dir.path().join("seg.nii.gz")).unwrap();
    assert!(ct.same_grid(&seg));
    assert_eq!(seg.labels_present(), vec![29]); // TotalSegmentator: L3 = 29
    let max = ct.values.iter().copied().fold(f32::MIN, f32::max);
    let min = ct.values.iter().copied().fold(f32::MAX, f32::min);
    assert!(min <= -999.0 && max > 500.0, "HU range {min}..{max}");
    // The label volume matches the phantom's cortical mesh volume.
    let cortical = read_mesh(&dir.path().join("ph/L3_cortical.stl")).unwrap();
    let lab = seg.count(29) as f64 * seg.voxel_volume_mm3();
    assert!((lab - cortical.volume()).abs() / cortical.volume() < 0.03);

    let (ok, err) = run(&[
        "mesh",
        "--seg",
        &d("seg.nii.gz"),
        "--label",
        "L3",
        "--smooth",
        "10",
        "--target-triangles",
        "30000",
        "--landmarks",
        "auto",
        "--out",
        &d("L3.ply"),
    ]);
    assert!(ok, "{err}");
    let auto = read_landmarks(&dir.path().join("L3_landmarks.json")).unwrap();
    let truth = read_landmarks(&dir.path().join("ph/landmarks.json")).unwrap();
    assert_eq!(auto.len(), 1);
    for (name, p) in &truth[0].points {
        let e = (auto[0].points[name] - *p).length();
        assert!(e < 3.0, "{name}: {e:.2} mm from the phantom's landmark");
    }
}

#[test]
fn bad_input_fails_with_a_clear_message() {
    let dir = tempfile::tempdir().unwrap();
    let seg_path = dir.path().join("seg.nii.gz");
    write_two_vertebrae(&seg_path);
    let s = seg_path.display().to_string();
    let out = dir.path().join("x.stl").display().to_string();
    let cases: [(Vec<&str>, &str); 6] = [
        (
            vec!["--seg", "/nonexistent/seg.nii.gz", "--label", "L1"],
            "nonexistent",
        ),
        (vec!["--seg", &s, "--label", "L5"], "not present"),
        (vec!["--seg", &s, "--label", "X9"], "X9"),
        (vec!["--seg", &s, "--label", "L1", "--labels", "mni"], "mni"),
        (
            vec!["--seg", &s, "--label", "L1", "--landmarks", "file"],
            "auto",
        ),
        (
            vec!["--seg", &s, "--label", "L1", "--landmarks", "auto"],
            "landmarks",
        ),
    ];
    for (args, needle) in cases {
        let mut full = vec!["mesh"];
        full.extend(args.iter().copied());
        full.extend(["--out", out.as_str()]);
        let (ok, err) = run(&full);
        assert!(!ok, "{full:?} succeeded");
        assert!(err.contains(needle), "{full:?}: {err}");
    }
    let (ok, err) = run(&["mesh", "--seg", &s, "--label", "L1", "--out", "x.vtk"]);
    assert!(!ok && err.contains("vtk"), "{err}");
    let bytes = std::fs::read(&seg_path).unwrap();
    std::fs::write(&seg_path, &bytes[..bytes.len() / 3]).unwrap();
    let (ok, err) = run(&["mesh", "--seg", &s, "--label", "L1", "--out", &out]);
    assert!(!ok && err.contains("seg.nii.gz"), "{err}");
    let ph = dir.path().join("ph").display().to_string();
    let (ok, err) = run(&[
        "phantom",
        "--levels",
        "L3",
        "--out",
        &ph,
        "--ct",
        "ct.nii.gz",
        "--ct-voxel-mm",
        "0",
    ]);
    assert!(!ok && err.contains("--ct-voxel-mm"), "{err}");
}
