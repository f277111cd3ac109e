//! A view's side outline of an object: every vertex in the view's camera frame (x along detector
//! columns, y along rows, z along the central ray, mm, source at the origin), reduced to the convex hull
//! of its (z, y) coordinates — the object as seen from beside the beam, in the plane of the central ray
//! and the detector's v axis. The study stores it with each reference DRR so the report can draw every
//! view to scale with the anatomy where it really is.

use glam::{DVec2, DVec3};

use super::View;

/// The convex hull of `points`, counter-clockwise from the lowest-x point (Andrew's monotone chain);
/// collinear points dropped. Fewer than three distinct points come back as they are (deduplicated).
pub fn convex_hull(points: &[DVec2]) -> Vec<DVec2> {
    let mut p: Vec<DVec2> = points.iter().copied().filter(|q| q.is_finite()).collect();
    p.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    let cross = |o: DVec2, a: DVec2, b: DVec2| (a - o).perp_dot(b - o);
    let mut hull: Vec<DVec2> = Vec::with_capacity(2 * p.len());
    for pass in [p.clone(), p.iter().rev().copied().collect()] {
        let start = hull.len();
        for q in pass {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0
            {
                hull.pop();
            }
            hull.push(q);
        }
        hull.pop(); // the last point of a pass is the first of the next
    }
    hull
}

/// The side outline of `vertices` (world, mm) in `view`: the convex hull of their (z, y) camera
/// coordinates (depth from the source along the central ray, offset along the detector's v axis).
pub fn side_outline(vertices: impl Iterator<Item = DVec3>, view: &View) -> Vec<DVec2> {
    let pts: Vec<DVec2> = vertices
        .map(|w| {
            let c = view.world_to_camera.apply(w);
            DVec2::new(c.z, c.y)
        })
        .collect();
    convex_hull(&pts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hull_of_a_square_with_inner_and_edge_points_is_its_corners() {
        let mut pts = vec![
            DVec2::new(0.0, 0.0),
            DVec2::new(2.0, 0.0),
            DVec2::new(2.0, 2.0),
            DVec2::new(0.0, 2.0),
        ];
        pts.extend([
            DVec2::new(1.0, 1.0),
            DVec2::new(1.0, 0.0),
            DVec2::new(0.5, 1.5),
        ]);
        let h = convex_hull(&pts);
        assert_eq!(h.len(), 4, "{h:?}");
        for c in &pts[..4] {
            assert!(h.contains(c));
        }
        // Counter-clockwise: positive signed area (shoelace) = 4.
        let area: f64 = (0..h.len())
            .map(|i| h[i].perp_dot(h[(i + 1) % h.len()]))
            .sum::<f64>()
            / 2.0;
        assert!((area - 4.0).abs() < 1e-12);
    }

    #[test]
    fn a_point_ahead_of_the_source_sits_at_its_depth_and_height() {
        // The built-in AP view looks along world +y from (0, -1000, 0): a point at the world origin is
        // 1000 mm deep on the central ray; 50 mm up (world +z) is 50 mm towards the detector's top row
        // (camera y = −50, v grows downward).
        let carm = crate::geometry::CArm::default_paper();
        let ap = carm.view("ap").expect("ap");
        let o = side_outline(
            [
                DVec3::ZERO,
                DVec3::new(0.0, 0.0, 50.0),
                DVec3::new(0.0, 10.0, 0.0),
            ]
            .into_iter(),
            ap,
        );
        let has = |z: f64, y: f64| {
            o.iter()
                .any(|p| (p.x - z).abs() < 1e-9 && (p.y - y).abs() < 1e-9)
        };
        assert!(
            has(1000.0, 0.0) && has(1000.0, -50.0) && has(1010.0, 0.0),
            "{o:?}"
        );
    }
}
