//! Isosurface extraction against analytic shapes: closed, outward, volume within 1 % of the exact value.

use std::f64::consts::PI;

use glam::{DMat3, DMat4, DVec3};
use spinedrr::anatomy::{Inside, ScalarGrid, extract_isosurface, extract_isosurface_with};

/// A grid of `n³` samples with spacing `h` centred on `centre`, composed with an extra linear map.
fn grid_affine(n: usize, h: f64, centre: DVec3, linear: DMat3) -> DMat4 {
    let half = (n - 1) as f64 * h / 2.0;
    DMat4::from_translation(centre)
        * DMat4::from_mat3(linear)
        * DMat4::from_translation(DVec3::splat(-half))
        * DMat4::from_scale(DVec3::splat(h))
}

fn sphere(c: DVec3, r: f64) -> impl Fn(DVec3) -> f64 + Sync {
    move |p| (p - c).length() - r
}

#[test]
fn sphere_is_watertight_with_accurate_volume() {
    let c = DVec3::new(3.0, -2.0, 7.0);
    let g = ScalarGrid::from_fn(
        [60, 60, 60],
        grid_affine(60, 0.5, c, DMat3::IDENTITY),
        sphere(c, 12.0),
    )
    .unwrap();
    let m = extract_isosurface(&g, 0.0).unwrap();
    let chk = m.check();
    assert!(chk.is_watertight(), "{chk:?}");
    assert_eq!(chk.degenerate_triangles, 0);
    let exact = 4.0 / 3.0 * PI * 12f64.powi(3);
    assert!(
        (m.volume() / exact - 1.0).abs() < 0.01,
        "{} vs {exact}",
        m.volume()
    );
    // Vertices lie on the sphere to within the interpolation error of a voxel.
    assert!(
        m.vertices
            .iter()
            .all(|v| ((*v - c).length() - 12.0).abs() < 0.05)
    );
}

#[test]
fn box_is_watertight_with_accurate_volume() {
    let half = DVec3::new(8.0, 5.0, 3.0);
    let sdf = move |p: DVec3| {
        let q = p.abs() - half;
        q.max(DVec3::ZERO).length() + q.max_element().min(0.0)
    };
    let g = ScalarGrid::from_fn(
        [50, 50, 50],
        grid_affine(50, 0.43, DVec3::ZERO, DMat3::IDENTITY),
        sdf,
    )
    .unwrap();
    let m = extract_isosurface(&g, 0.0).unwrap();
    assert!(m.check().is_watertight(), "{:?}", m.check());
    let exact = 8.0 * half.x * half.y * half.z;
    assert!(
        (m.volume() / exact - 1.0).abs() < 0.01,
        "{} vs {exact}",
        m.volume()
    );
}

#[test]
fn oblique_and_mirrored_affines_stay_outward() {
    let c = DVec3::new(-1.0, 2.0, 0.5);
    let exact = 4.0 / 3.0 * PI * 1000.0;
    let rot = DMat3::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
    let mirror = DMat3::from_diagonal(DVec3::new(-1.0, 1.0, 1.0));
    let shear = DMat3::from_cols(
        DVec3::X,
        DVec3::new(0.3, 1.0, 0.0),
        DVec3::new(0.0, 0.2, 1.1),
    );
    for (name, lin) in [
        ("rotated", rot),
        ("mirrored", mirror * rot),
        ("sheared mirrored", shear * mirror),
    ] {
        let g = ScalarGrid::from_fn([56, 56, 56], grid_affine(56, 0.5, c, lin), sphere(c, 10.0))
            .unwrap();
        let m = extract_isosurface(&g, 0.0).unwrap();
        assert!(m.check().is_watertight(), "{name}: {:?}", m.check());
        assert!(
            (m.volume() / exact - 1.0).abs() < 0.01,
            "{name}: {} vs {exact}",
            m.volume()
        );
    }
}

#[test]
fn surfaces_touching_the_border_close_and_label_maps_work() {
    // A label map (inside = value > 0.5) whose solid fills the whole grid: the padding closes it.
    let g = ScalarGrid::new([4, 3, 5], vec![1.0; 60], DMat4::IDENTITY).unwrap();
    let m = extract_isosurface_with(&g, 0.5, Inside::Above).unwrap();
    assert!(m.check().is_watertight(), "{:?}", m.check());
    // The surface passes half a voxel beyond the outer samples (corners chamfered): between the
    // samples' hull (3·2·4) and the half-voxel-padded box (4·3·5).
    assert!(m.volume() > 24.0 && m.volume() < 60.0, "{}", m.volume());
    // The same map with the SDF convention is empty inside.
    assert!(extract_isosurface(&g, 0.5).unwrap().triangles.is_empty());
}

#[test]
fn two_touching_blobs_and_saddles_stay_manifold() {
    // Random-ish field with many ambiguous faces: marching cubes would leave holes here.
    let f =
        |p: DVec3| ((p.x * 1.7).sin() * (p.y * 1.3).cos() + (p.z * 1.1).sin() * 0.7) * 0.9 + 0.1;
    let g = ScalarGrid::from_fn([30, 30, 30], DMat4::from_scale(DVec3::splat(0.37)), f).unwrap();
    let m = extract_isosurface(&g, 0.0).unwrap();
    assert!(!m.triangles.is_empty());
    assert!(m.check().is_watertight(), "{:?}", m.check());
    assert!(m.volume() > 0.0);
}
