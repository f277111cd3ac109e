//! `--implant FILE:MATERIAL:POSE.json`: an implant mesh in its own frame placed by a pose file (the
//! layout of `spinedrr register`'s `R.json`, or a 4 × 4 matrix) renders as the same mesh written where
//! the pose puts it; a pose that is not a rigid transform is refused naming the file.

use glam::DVec3;
use spinedrr::geometry::{RigidTransform, rotation_exp};
use spinedrr::io::read_tiff_f32;

use crate::cli_hardening::{cube, refused, s};

#[test]
fn an_implant_placed_by_a_pose_file_is_the_mesh_written_where_the_pose_puts_it() {
    let d = tempfile::tempdir().unwrap();
    let c = s(&cube(d.path(), "c.stl", DVec3::ZERO, 30.0));
    // The screw in its own frame: along +z from the origin (entry) to 40 mm (tip).
    let (shank, _) = spinedrr::anatomy::screw::ScrewSpec::default()
        .meshes("s", DVec3::ZERO, DVec3::new(0.0, 0.0, 40.0))
        .unwrap();
    let pose = RigidTransform::new(
        rotation_exp(DVec3::new(0.9, -0.4, 0.2)),
        DVec3::new(3.0, 18.0, -5.0),
    );
    let mut placed = shank.clone();
    placed.transform(&pose);
    let (model_path, world_path) = (d.path().join("model.stl"), d.path().join("world.stl"));
    spinedrr::anatomy::write_mesh(&model_path, &shank).unwrap();
    spinedrr::anatomy::write_mesh(&world_path, &placed).unwrap();
    let r_json = d.path().join("R.json");
    let matrix_json = d.path().join("matrix.json");
    std::fs::write(
        &r_json,
        serde_json::json!({"R": pose.rotation_rows(), "t": pose.translation.to_array(),
            "residual_px": 0.2, "converged": true})
        .to_string(),
    )
    .unwrap();
    std::fs::write(
        &matrix_json,
        serde_json::json!({"matrix": pose.to_rows()}).to_string(),
    )
    .unwrap();
    let render = |implant: String, out: &str| {
        let o = d.path().join(out);
        let args = [
            "render".to_string(),
            "--mesh".into(),
            format!("{c}:soft_tissue"),
            "--view".into(),
            "ap".into(),
            "--spectrum".into(),
            "80".into(),
            "--implant".into(),
            implant,
            "--out".into(),
            s(&o),
        ];
        let (ok, err) = crate::common::run(&args);
        assert!(ok, "{err}");
        read_tiff_f32(&o).unwrap().data
    };
    let world = render(format!("{}:titanium", s(&world_path)), "world.tiff");
    let unposed = render(format!("{}:titanium", s(&model_path)), "unposed.tiff");
    for (pose_file, out) in [(&r_json, "r.tiff"), (&matrix_json, "m.tiff")] {
        let posed = render(format!("{}:titanium:{}", s(&model_path), s(pose_file)), out);
        // The same mesh, its vertices rounded to f32 once in each file: the same image.
        let worst = posed
            .iter()
            .zip(&world)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-3, "{out}: largest difference {worst}");
        // The sidecar holds the matrix applied, not only the file's name.
        let side: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(d.path().join(out).with_extension("json")).unwrap(),
        )
        .unwrap();
        let recorded: [[f64; 4]; 4] = serde_json::from_value(
            side["details"]["anatomy"]["implant_poses"][0]["matrix"].clone(),
        )
        .unwrap();
        assert_eq!(recorded, pose.to_rows());
    }
    // The pose matters: unposed, the screw is elsewhere.
    let moved = unposed
        .iter()
        .zip(&world)
        .filter(|(a, b)| (**a - **b).abs() > 0.1)
        .count();
    assert!(moved > 100, "{moved} pixels differ without the pose");
    // A reflection, a half pose and a missing pose file are refused naming the file, nothing written.
    let bad = d.path().join("bad_pose.json");
    for (text, needle) in [
        (
            Some(r#"{"R": [[1,0,0],[0,1,0],[0,0,-1]], "t": [0,0,0]}"#),
            "reflection",
        ),
        (Some(r#"{"R": [[1,0,0],[0,1,0],[0,0,1]]}"#), "only one"),
        (None, "bad_pose.json"),
    ] {
        match text {
            Some(t) => std::fs::write(&bad, t).unwrap(),
            None => std::fs::remove_file(&bad).unwrap(),
        }
        let out = d.path().join("bad.tiff");
        refused(
            &[
                "render",
                "--mesh",
                &format!("{c}:soft_tissue"),
                "--spectrum",
                "80",
                "--implant",
                &format!("{}:titanium:{}", s(&model_path), s(&bad)),
                "--out",
                &s(&out),
            ],
            &["bad_pose.json", needle],
        );
        assert!(!out.exists(), "written despite {text:?}");
    }
}
