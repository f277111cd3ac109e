//! `spinedrr phantom` end to end: the real binary writes meshes and landmarks that read back.

use spinedrr::anatomy::{PhantomOptions, build_phantom, parse_levels, read_landmarks, read_mesh};

use crate::common::Spinedrr;

#[test]
fn phantom_command_writes_closed_meshes_and_landmarks() {
    let dir = tempfile::tempdir().unwrap();
    let out = Spinedrr::new()
        .args([
            "phantom",
            "--levels",
            "L3-L4",
            "--format",
            "ply",
            "--soft-tissue",
            "--out",
        ])
        .arg(dir.path())
        .output();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    for name in [
        "L3_cortical.ply",
        "L3_cancellous.ply",
        "L4_cortical.ply",
        "L4_cancellous.ply",
        "L3-L4_disc.ply",
        "soft_tissue.ply",
    ] {
        let m = read_mesh(&dir.path().join(name)).unwrap();
        assert!(m.check().is_watertight(), "{name}");
        assert!(stderr.contains(name), "summary lacks {name}: {stderr}");
    }
    assert!(!stderr.contains("NOT watertight"));
    // Labels survive the PLY file; landmarks equal the library's (placement rule: L3 at the origin).
    let cortical = read_mesh(&dir.path().join("L3_cortical.ply")).unwrap();
    assert_eq!(cortical.labels.len(), cortical.triangles.len());
    let lm = read_landmarks(&dir.path().join("landmarks.json")).unwrap();
    let lib = build_phantom(&PhantomOptions {
        levels: parse_levels("L3-L4").unwrap(),
        discs: false,
        ..PhantomOptions::default()
    })
    .unwrap();
    // JSON keeps ~17 significant digits; the last ulp may differ after parsing.
    let lib = lib.landmarks();
    assert_eq!(lm.len(), lib.len());
    for (a, b) in lm.iter().zip(&lib) {
        assert_eq!(a.level, b.level);
        assert_eq!(
            a.points.keys().collect::<Vec<_>>(),
            b.points.keys().collect::<Vec<_>>()
        );
        for (k, p) in &a.points {
            assert!((*p - b.points[k]).length() < 1e-9, "{} {k}", a.level);
        }
    }
    assert!(lm[0].get("center").unwrap().length() < 1e-12);
}

#[test]
fn bad_arguments_fail_with_a_clear_message() {
    let dir = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let out = Spinedrr::new()
            .arg("phantom")
            .args(args)
            .arg("--out")
            .arg(dir.path())
            .output();
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).to_string()
    };
    assert!(run(&["--levels", "L7"]).contains("L7"));
    assert!(run(&["--levels", "L3", "--voxel-mm=0"]).contains("voxel_mm"));
}
