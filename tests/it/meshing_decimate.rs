//! Quadric edge-collapse decimation: closed meshes stay closed, volume and surface are preserved,
//! labels survive and the triangle target is honoured.

use std::collections::BTreeMap;

use glam::{DMat4, DVec3};
use spinedrr::anatomy::decimate::{DecimateOptions, decimate_with, deviation};
use spinedrr::anatomy::{
    Level, PhantomOptions, ScalarGrid, TriMesh, decimate, decimate_to_error, extract_isosurface,
};

fn assert_target(m: &TriMesh, target: usize) {
    let n = m.triangles.len() as f64;
    assert!(
        (n - target as f64).abs() <= 0.01 * target as f64,
        "{n} triangles for target {target}"
    );
}

fn rel_change(a: f64, b: f64) -> f64 {
    (b - a).abs() / a.abs()
}

#[test]
fn icosphere_stays_closed_round_and_on_target() {
    let r = 10.0;
    let m = TriMesh::icosphere("s", DVec3::new(3.0, -1.0, 2.0), r, 5);
    let d = decimate(&m, 3000).unwrap();
    let chk = d.check();
    assert!(chk.is_watertight(), "{chk:?}");
    assert_eq!(chk.degenerate_triangles, 0);
    assert_target(&d, 3000);
    // Euler characteristic of a sphere: V − E + F = 2 with E = 3F/2.
    assert_eq!(d.vertices.len() as i64 - d.triangles.len() as i64 / 2, 2);
    assert!(rel_change(m.volume(), d.volume()) < 0.005);
    // Every surviving vertex stays near the analytic sphere.
    let worst = d
        .vertices
        .iter()
        .map(|v| ((*v - DVec3::new(3.0, -1.0, 2.0)).length() - r).abs())
        .fold(0.0, f64::max);
    assert!(worst < 0.05, "vertex {worst} mm off the sphere");
}

/// A 20 × 14 × 9 mm box meshed by marching tetrahedra at 0.5 mm (many slivers, sharp edges).
fn box_mesh() -> TriMesh {
    let half = DVec3::new(10.0, 7.0, 4.5);
    let sdf = move |p: DVec3| {
        let q = p.abs() - half;
        q.max(DVec3::ZERO).length() + q.max_element().min(0.0)
    };
    let h = 0.5;
    let n = 52;
    let to_world = DMat4::from_translation(DVec3::splat(-h * (n as f64 - 1.0) / 2.0 + 0.013))
        * DMat4::from_scale(DVec3::splat(h));
    let grid = ScalarGrid::from_fn([n, n, n], to_world, sdf).unwrap();
    extract_isosurface(&grid, 0.0).unwrap()
}

#[test]
fn marching_box_decimates_to_a_few_hundred_triangles_keeping_its_volume() {
    let m = box_mesh();
    assert!(m.check().is_watertight());
    let d = decimate(&m, 400).unwrap();
    let chk = d.check();
    assert!(chk.is_watertight(), "{chk:?}");
    assert_target(&d, 400);
    assert!(rel_change(m.volume(), d.volume()) < 0.005);
    let there = deviation(&d, &m);
    let back = deviation(&m, &d);
    assert!(
        there.max_mm < 0.1 && back.max_mm < 0.1,
        "{there:?} {back:?}"
    );
}

#[test]
fn phantom_l3_comes_down_to_40k_within_a_tenth_of_a_millimetre() {
    let opts = PhantomOptions {
        levels: vec![Level::L3],
        discs: false,
        // The raw marching-tetrahedra surface (~300k triangles), not the phantom's own simplification.
        simplify_edge_mm: 0.0,
        ..PhantomOptions::default()
    };
    let p = crate::common::phantom(&opts).unwrap();
    let m = &p.vertebrae[0].cortical;
    assert!(m.triangles.len() > 150_000, "{}", m.triangles.len());
    let (d, stats) = decimate_with(
        m,
        &DecimateOptions {
            target_triangles: 40_000,
            ..DecimateOptions::default()
        },
    )
    .unwrap();
    let chk = d.check();
    assert!(chk.is_watertight(), "{chk:?}");
    assert_eq!(chk.degenerate_triangles, 0);
    assert_target(&d, 40_000);
    assert_eq!(stats.triangles_out, d.triangles.len());
    let dv = rel_change(m.volume(), d.volume());
    assert!(dv < 0.005, "volume change {dv}");
    let there = deviation(&d, m);
    let back = deviation(m, &d);
    eprintln!("decimated→original {there:?}, original→decimated {back:?}, volume {dv:e}");
    assert!(there.max_mm < 0.1 && there.mean_mm < 0.02, "{there:?}");
    assert!(back.max_mm < 0.2 && back.mean_mm < 0.02, "{back:?}");
    // Labels survive: each structure keeps its share of the surface area (to 2 % of the total).
    let share = |m: &TriMesh| {
        let mut a: BTreeMap<u8, f64> = BTreeMap::new();
        for i in 0..m.triangles.len() {
            let [p, q, r] = m.corners(i);
            *a.entry(m.labels[i]).or_default() += 0.5 * (q - p).cross(r - p).length();
        }
        let total: f64 = a.values().sum();
        a.values_mut().for_each(|v| *v /= total);
        a
    };
    let (s0, s1) = (share(m), share(&d));
    assert_eq!(d.labels.len(), d.triangles.len());
    assert_eq!(s0.keys().collect::<Vec<_>>(), s1.keys().collect::<Vec<_>>());
    for (k, v) in &s0 {
        assert!((v - s1[k]).abs() < 0.02, "label {k}: {v} → {}", s1[k]);
    }
}

#[test]
fn error_bounded_decimation_respects_its_bound() {
    let m = box_mesh();
    let d = decimate_to_error(&m, 0.02).unwrap();
    assert!(d.check().is_watertight());
    assert!(d.triangles.len() < m.triangles.len() / 4);
    // The bound is on the RMS plane distance of each collapse, so the mean deviation obeys it while
    // single vertices at the box's sharp corners may stray a few times further.
    let back = deviation(&m, &d);
    assert!(back.mean_mm < 0.02 && back.max_mm < 0.25, "{back:?}");
    // A zero bound still removes only coplanar collapses: the flat faces shrink, the volume does not.
    let z = decimate_to_error(&m, 0.0).unwrap();
    assert!(rel_change(m.volume(), z.volume()) < 1e-3);
}

#[test]
fn bad_arguments_are_errors() {
    let m = TriMesh::icosphere("s", DVec3::ZERO, 1.0, 2);
    assert!(decimate(&m, 3).is_err());
    assert!(decimate_to_error(&m, f64::NAN).is_err());
    let mut broken = m.clone();
    broken.triangles[0][0] = 10_000;
    let e = decimate(&broken, 50).unwrap_err().to_string();
    assert!(e.contains("triangle 0"), "{e}");
}
