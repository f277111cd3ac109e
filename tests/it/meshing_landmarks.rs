//! Automatic landmarks from a bare vertebra surface: every phantom level, moved by a random rigid
//! transform and stripped of its structure labels, gives each landmark within 3 mm of the analytic one.

use glam::{DMat3, DVec3};
use spinedrr::anatomy::{Landmarks, TriMesh, auto_landmarks, decimate};
use spinedrr::geometry::RigidTransform;

/// A deterministic pseudo-random number in [0, 1) (SplitMix64).
fn rand(state: &mut u64) -> f64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
}

fn random_rigid(state: &mut u64) -> RigidTransform {
    let mut r = || rand(state) * 2.0 - 1.0;
    let axis = DVec3::new(r(), r(), r()).normalize();
    let angle = r() * std::f64::consts::PI;
    let t = DVec3::new(r(), r(), r()) * 150.0;
    RigidTransform::new(DMat3::from_axis_angle(axis, angle), t)
}

fn assert_close(level: &str, auto: &Landmarks, truth: &Landmarks, tol_mm: f64) {
    assert_eq!(
        auto.points.keys().collect::<Vec<_>>(),
        truth.points.keys().collect::<Vec<_>>(),
        "{level}: landmark names"
    );
    let mut worst = (0.0, String::new());
    for (name, &p) in &truth.points {
        let e = (auto.points[name] - p).length();
        eprintln!("{level} {name:<28} {e:6.3} mm");
        if e > worst.0 {
            worst = (e, name.clone());
        }
    }
    assert!(
        worst.0 < tol_mm,
        "{level}: {} off by {:.2} mm",
        worst.1,
        worst.0
    );
}

#[test]
fn auto_landmarks_match_the_phantom_under_random_rigid_motion() {
    // The vertebrae alone are read: the shared default phantom's (its discs are meshed apart from them).
    let p = crate::common::default_phantom();
    let mut seed = 0x5EED_u64;
    for v in &p.vertebrae {
        let t = random_rigid(&mut seed);
        let mut mesh: TriMesh = v.cortical.clone();
        mesh.labels.clear();
        mesh.transform(&t);
        let mut truth = v.landmarks.clone();
        truth.points.values_mut().for_each(|q| *q = t.apply(*q));
        let auto = auto_landmarks(&mesh, v.level.name()).unwrap();
        assert_eq!(auto.level, v.level.name());
        assert_close(v.level.name(), &auto, &truth, 3.0);
        if v.level.name() == "L3" {
            let small = decimate(&mesh, 40_000).unwrap();
            let auto = auto_landmarks(&small, "L3").unwrap();
            assert_close("L3 decimated", &auto, &truth, 3.0);
        }
    }
}

#[test]
fn open_or_inverted_surfaces_are_refused() {
    let mut m = TriMesh::icosphere("s", DVec3::ZERO, 10.0, 2);
    m.flip();
    assert!(
        auto_landmarks(&m, "L1")
            .unwrap_err()
            .to_string()
            .contains("inward")
    );
    m.triangles.pop();
    assert!(
        auto_landmarks(&m, "L1")
            .unwrap_err()
            .to_string()
            .contains("closed")
    );
}
