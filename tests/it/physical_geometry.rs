//! Physical perturbations (focal spot and detector moved in mm, detector rotated in degrees) against
//! cameras derived by hand: each `render --perturb KEY=V` must equal the render of an explicit geometry
//! file whose K and world_to_camera were worked out here from the moved source or detector.

use std::path::Path;

use glam::{DMat3, DVec3};
use spinedrr::analysis::ncc;
use spinedrr::geometry::{CArm, RigidTransform};
use spinedrr::io::{Sidecar, read_tiff_f32};

use crate::common::{spinedrr, stderr};

const W: u32 = 128;
const PITCH: f64 = 1.2;
const SDD: f64 = 1350.0;

/// An oblique view, so that the camera axes are not the world axes.
fn geometry(dir: &Path) -> String {
    let path = dir.join("true.toml");
    let text = format!(
        "[detector]\nwidth = {W}\nheight = {W}\npixel_spacing_mm = [{PITCH}, {PITCH}]\nsdd_mm = {SDD}\n\n\
         [[view]]\nname = \"v\"\nsource_mm = [-420.0, -880.0, 90.0]\ntarget_mm = [3.0, -2.0, 4.0]\n\
         up = [0.1, 0.0, 1.0]\n"
    );
    std::fs::write(&path, text).unwrap();
    path.to_string_lossy().into_owned()
}

/// An explicit geometry file with `k` and `world_to_camera` (rows), the same detector size.
fn explicit(dir: &Path, name: &str, k: [[f64; 3]; 3], t: &RigidTransform) -> String {
    let path = dir.join(format!("{name}.toml"));
    let text = format!(
        "[detector]\nwidth = {W}\nheight = {W}\npixel_spacing_mm = [{PITCH}, {PITCH}]\nsdd_mm = {SDD}\n\
         K = {k:?}\n\n[[view]]\nname = \"v\"\nworld_to_camera = {:?}\n",
        t.to_rows()
    );
    std::fs::write(&path, text).unwrap();
    path.to_string_lossy().into_owned()
}

/// The phantom's L1 as mesh files (cortical shell μ 0.05 /mm over a cancellous core 0.03 /mm less),
/// built once per test; the `--mesh` arguments that render it.
fn l1_meshes(dir: &Path) -> [String; 2] {
    let folder = dir.join("l1");
    if !folder.is_dir() {
        let o = spinedrr(&[
            "phantom",
            "--levels",
            "L1",
            "--no-discs",
            "--voxel-mm",
            "1.0",
            "--out",
            folder.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    [
        format!("{}:0.05", folder.join("L1_cortical.stl").display()),
        format!("{}:-0.03", folder.join("L1_cancellous.stl").display()),
    ]
}

fn render(dir: &Path, geom: &str, perturb: &str, name: &str) -> std::path::PathBuf {
    let out = dir.join(format!("{name}.tiff"));
    let [cortical, cancellous] = l1_meshes(dir);
    let o = spinedrr(&[
        "render",
        "--mesh",
        &cortical,
        "--mesh",
        &cancellous,
        "--geometry",
        geom,
        "--view",
        "v",
        "--perturb",
        perturb,
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{perturb}: {}", stderr(&o));
    out
}

/// Row-major rotation matrices written out (not glam's constructors, which the code uses).
fn rot(axis: char, deg: f64) -> DMat3 {
    let (s, c) = deg.to_radians().sin_cos();
    let rows = match axis {
        'x' => [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]],
        'y' => [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]],
        _ => [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]],
    };
    DMat3::from_cols_array_2d(&rows).transpose()
}

#[test]
fn each_physical_key_renders_as_the_camera_derived_by_hand() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let geom = geometry(d);
    let truth = CArm::from_file(Path::new(&geom)).unwrap().views[0].clone();
    let (r, t) = (
        truth.world_to_camera.rotation,
        truth.world_to_camera.translation,
    );
    let c = (f64::from(W) - 1.0) / 2.0;
    let f = SDD / PITCH;
    let k = |f: f64, cx: f64, cy: f64| [[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]];
    // The camera frame moves with the source (a translation) or turns with the detector (a rotation
    // about the piercing point (0, 0, S), which stays the image of pixel (c, c) for a roll).
    let moved = |delta: DVec3| RigidTransform::new(r, t - delta);
    let turned = |q: DMat3| RigidTransform::new(q.transpose() * r, q.transpose() * t);
    let th = 5.0f64;
    let (sin, cos) = th.to_radians().sin_cos();
    let cases: Vec<(&str, [[f64; 3]; 3], RigidTransform)> = vec![
        // Focal spot moved by δ: the foot of its perpendicular on the detector is pixel c + δ/p, its
        // distance to the detector S − δz.
        (
            "src_dx_mm=15",
            k(f, c + 15.0 / PITCH, c),
            moved(DVec3::new(15.0, 0.0, 0.0)),
        ),
        (
            "src_dy_mm=-12",
            k(f, c, c - 12.0 / PITCH),
            moved(DVec3::new(0.0, -12.0, 0.0)),
        ),
        (
            "src_dz_mm=60",
            k((SDD - 60.0) / PITCH, c, c),
            moved(DVec3::new(0.0, 0.0, 60.0)),
        ),
        // Detector moved by d: its pixels slide by −d/p under a fixed source, or recede by dz.
        (
            "det_dx_mm=6",
            k(f, c - 6.0 / PITCH, c),
            truth.world_to_camera,
        ),
        (
            "det_dy_mm=-5",
            k(f, c, c + 5.0 / PITCH),
            truth.world_to_camera,
        ),
        (
            "det_dz_mm=50",
            k((SDD + 50.0) / PITCH, c, c),
            truth.world_to_camera,
        ),
        // Detector rotated about the central ray: the camera turns about its own axis.
        ("det_roll_deg=5", k(f, c, c), turned(rot('z', th))),
        // Tilted about its row axis by θ: the plane's distance is S cos θ and the foot of the source's
        // perpendicular lies S sin θ up the tilted v axis from the piercing point; about its column
        // axis, S sin θ along +u.
        (
            "det_tilt_u_deg=5",
            k(SDD * cos / PITCH, c, c - SDD * sin / PITCH),
            turned(rot('x', th)),
        ),
        (
            "det_tilt_v_deg=5",
            k(SDD * cos / PITCH, c + SDD * sin / PITCH, c),
            turned(rot('y', th)),
        ),
    ];
    let reference = read_tiff_f32(&render(d, &geom, "none", "reference")).unwrap();
    for (i, (spec, k_hand, t_hand)) in cases.iter().enumerate() {
        let a = render(d, &geom, spec, &format!("p{i}"));
        let b = render(
            d,
            &explicit(d, &format!("hand{i}"), *k_hand, t_hand),
            "none",
            &format!("h{i}"),
        );
        // The sidecar's camera is the one derived by hand.
        let side = Sidecar::read(&a.with_extension("json")).unwrap();
        for (x, y) in side.k.iter().flatten().zip(k_hand.iter().flatten()) {
            assert!(
                (x - y).abs() < 1e-6,
                "{spec}: K {:?} vs by hand {k_hand:?}",
                side.k
            );
        }
        for (x, y) in side
            .world_to_camera
            .iter()
            .flatten()
            .zip(t_hand.to_rows().iter().flatten())
        {
            assert!(
                (x - y).abs() < 1e-9,
                "{spec}: world_to_camera {:?}",
                side.world_to_camera
            );
        }
        assert_eq!(
            side.world_to_camera_reference,
            Some(truth.world_to_camera.to_rows())
        );
        let (ia, ib) = (read_tiff_f32(&a).unwrap(), read_tiff_f32(&b).unwrap());
        let same = ncc(&ia, &ib).unwrap();
        let moved_image = ncc(&reference, &ia).unwrap();
        assert!(
            same >= 0.99999,
            "{spec}: NCC with the hand-derived camera {same}"
        );
        // The perturbation changes the image far more than the tolerance allows.
        assert!(
            1.0 - moved_image > 10.0 * 1e-5,
            "{spec}: NCC with the reference {moved_image}"
        );
    }
}

#[test]
fn physical_keys_need_a_physical_detector_and_a_sane_size() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let truth = CArm::from_file(Path::new(&geometry(d))).unwrap().views[0].clone();
    let with_k = explicit(
        d,
        "k",
        truth.intrinsics.matrix_rows(),
        &truth.world_to_camera,
    );
    let out = d.join("x.tiff");
    for (geom, spec, says) in [
        (with_k.as_str(), "det_dz_mm=5", "explicit K"),
        (geometry(d).as_str(), "det_dz_mm=900", "beyond ±500 mm"),
        (geometry(d).as_str(), "det_tilt_u_deg=60", "beyond ±45°"),
        (geometry(d).as_str(), "det_dz=5", "unknown key 'det_dz'"),
    ] {
        let [cortical, _] = l1_meshes(d);
        let o = spinedrr(&[
            "render",
            "--mesh",
            &cortical,
            "--geometry",
            geom,
            "--view",
            "v",
            "--perturb",
            spec,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(!o.status.success(), "{spec} was accepted");
        assert!(stderr(&o).contains(says), "{spec}: {}", stderr(&o));
        assert!(!out.exists());
    }
}
