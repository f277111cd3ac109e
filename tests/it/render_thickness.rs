//! Thickness DRRs against analytic chord lengths, the homography law and the second backend.

use std::sync::Arc;

use glam::{DVec2, DVec3};
use spinedrr::anatomy::TriMesh;
use spinedrr::geometry::{Intrinsics, Perturbation, RigidTransform, View, apply_homography};
use spinedrr::render::{Backend, RenderScene, SceneMesh, ThicknessOptions};

fn scene(meshes: Vec<(TriMesh, f64)>) -> RenderScene {
    RenderScene::new(
        meshes
            .into_iter()
            .map(|(m, mu)| SceneMesh {
                object: m.name.clone(),
                mesh: Arc::new(m),
                mu_per_mm: mu,
            })
            .collect(),
    )
    .unwrap()
}

/// An oblique view of the origin from ~600 mm, small detector so tests stay fast.
fn oblique_view(size: u32) -> View {
    let k = Intrinsics {
        fx: 2600.0,
        fy: 2550.0,
        skew: 0.7,
        cx: size as f64 / 2.0 - 3.3,
        cy: size as f64 / 2.0 + 1.9,
        width: size,
        height: size,
    };
    let t = RigidTransform::look_at(
        DVec3::new(310.0, -480.0, 190.0),
        DVec3::new(0.4, -0.3, 0.2),
        DVec3::new(0.2, 0.1, 1.0),
    )
    .unwrap();
    View::new("oblique", k, t)
}

/// Exact chord of a ray through an axis-aligned box (slab method).
fn box_chord(lo: DVec3, hi: DVec3, o: DVec3, d: DVec3) -> f64 {
    let inv = d.recip();
    let t0 = (lo - o) * inv;
    let t1 = (hi - o) * inv;
    let near = t0.min(t1).max_element().max(0.0);
    let far = t0.max(t1).min_element();
    (far - near).max(0.0)
}

#[test]
fn box_matches_analytic_chords_on_every_backend() {
    let (lo, hi) = (
        DVec3::new(-20.0, -12.0, -15.0),
        DVec3::new(25.0, 18.0, 10.0),
    );
    let view = oblique_view(160);
    for backend in [Backend::Embree, Backend::Bvh, Backend::Raster] {
        let r = backend
            .renderer(scene(vec![(TriMesh::cuboid("box", lo, hi), 1.0)]))
            .unwrap();
        let drr = r.render(&view, &ThicknessOptions::default()).unwrap();
        let mut inside = 0;
        for v in 0..view.intrinsics.height {
            for u in 0..view.intrinsics.width {
                let ray = view.pixel_ray(u as f64, v as f64);
                let exact = box_chord(lo, hi, ray.origin, ray.dir);
                let got = drr.line_integral.get(u, v) as f64;
                assert!(
                    (got - exact).abs() <= 1e-3,
                    "{backend:?} ({u},{v}): {got} vs {exact}"
                );
                inside += usize::from(exact > 0.0);
            }
        }
        assert!(
            inside > 2000,
            "the box must cover a good part of the image ({inside} px)"
        );
        assert_eq!(drr.stats.rays_unrepaired, 0);
    }
}

#[test]
fn sphere_chords_lie_within_the_tessellation_bound() {
    let (c, r) = (DVec3::new(3.0, -2.0, 4.0), 18.0);
    let mesh = TriMesh::icosphere("sphere", c, r, 5);
    // The polyhedron lies between the sphere of radius r (its vertices) and the sphere touching its
    // closest face plane, so every chord lies between the two spheres' chords.
    let r_in = (0..mesh.triangles.len())
        .map(|i| {
            let [a, b, cc] = mesh.corners(i);
            (b - a).cross(cc - a).normalize().dot(a - c)
        })
        .fold(f64::INFINITY, f64::min);
    assert!(r_in > 0.999 * r);
    let chord = |rad: f64, d: f64| 2.0 * (rad * rad - d * d).max(0.0).sqrt();
    let view = oblique_view(128);
    for backend in [Backend::Embree, Backend::Raster] {
        let drr = backend
            .renderer(scene(vec![(mesh.clone(), 1.0)]))
            .unwrap()
            .render(&view, &ThicknessOptions::default())
            .unwrap();
        let mut checked = 0;
        for v in 0..128 {
            for u in 0..128 {
                let ray = view.pixel_ray(u as f64, v as f64);
                let d = (c - ray.origin).reject_from(ray.dir).length();
                let got = drr.line_integral.get(u, v) as f64;
                let (lo, hi) = (chord(r_in, d), chord(r, d));
                assert!(
                    got >= lo - 1e-4 && got <= hi + 1e-4,
                    "{backend:?} ({u},{v}): {got} not in [{lo}, {hi}]"
                );
                checked += usize::from(d < r_in);
            }
        }
        assert!(checked > 1000);
    }
}

#[test]
fn nested_shells_integrate_differential_mu() {
    // A shell of μ = 0.05 between radii 10 and 16 around a core of μ = 0.02: the inner surface carries the
    // differential μ (0.02 − 0.05). Compare against the same shapes with the analytic chord formula,
    // bounded as in the single-sphere test.
    let c = DVec3::ZERO;
    let outer = TriMesh::icosphere("outer", c, 16.0, 5);
    let inner = TriMesh::icosphere("inner", c, 10.0, 5);
    let view = oblique_view(96);
    let drr = Backend::Bvh
        .renderer(scene(vec![(outer, 0.05), (inner, 0.02 - 0.05)]))
        .unwrap()
        .render(&view, &ThicknessOptions::default())
        .unwrap();
    let chord = |rad: f64, d: f64| 2.0 * (rad * rad - d * d).max(0.0).sqrt();
    let mut worst: f64 = 0.0;
    for v in 0..96 {
        for u in 0..96 {
            let ray = view.pixel_ray(u as f64, v as f64);
            let d = (c - ray.origin).reject_from(ray.dir).length();
            let exact = 0.05 * (chord(16.0, d) - chord(10.0, d)) + 0.02 * chord(10.0, d);
            // Tessellation of level 5: faces sit within 0.03% of the radius; away from the rims (where the
            // chord's slope is unbounded) that changes the integral by well under 1e-3.
            if (d - 16.0).abs() > 0.5 && (d - 10.0).abs() > 0.5 {
                worst = worst.max((drr.line_integral.get(u, v) as f64 - exact).abs());
            }
        }
    }
    assert!(worst < 2e-3, "worst deviation {worst}");
}

#[test]
fn every_backend_agrees_with_the_bvh_per_pixel() {
    let meshes = vec![
        (
            TriMesh::icosphere("a", DVec3::new(-8.0, 0.0, 2.0), 14.0, 4),
            0.3,
        ),
        (
            TriMesh::icosphere("b", DVec3::new(9.0, 3.0, -1.0), 11.0, 3),
            1.0,
        ),
        (
            TriMesh::cuboid(
                "c",
                DVec3::new(-5.0, -30.0, -20.0),
                DVec3::new(5.0, -10.0, 20.0),
            ),
            0.7,
        ),
    ];
    let view = oblique_view(200);
    let b = Backend::Bvh
        .renderer(scene(meshes.clone()))
        .unwrap()
        .render(&view, &ThicknessOptions::default())
        .unwrap();
    for backend in [Backend::Embree, Backend::Raster] {
        let a = backend
            .renderer(scene(meshes.clone()))
            .unwrap()
            .render(&view, &ThicknessOptions::default())
            .unwrap();
        let worst = a
            .line_integral
            .data
            .iter()
            .zip(&b.line_integral.data)
            .map(|(x, y)| (x - y).abs())
            .fold(0f32, f32::max);
        assert!(
            worst <= 1e-4,
            "{backend:?}: worst per-pixel difference {worst}"
        );
        assert_eq!(
            a.masks, b.masks,
            "{backend:?}: silhouette pixels differ from the BVH's"
        );
        let (da, db) = (a.depth().unwrap(), b.depth().unwrap());
        let worst_depth = da
            .data
            .iter()
            .zip(&db.data)
            .map(|(x, y)| (x - y).abs())
            .fold(0f32, f32::max);
        assert!(
            worst_depth <= 1e-3,
            "{backend:?}: depth differs by {worst_depth} mm"
        );
    }
}

#[test]
fn culling_changes_nothing() {
    let meshes = vec![(
        TriMesh::icosphere("s", DVec3::new(5.0, 0.0, 0.0), 9.0, 4),
        1.0,
    )];
    let view = oblique_view(120);
    let r = Backend::Embree.renderer(scene(meshes)).unwrap();
    let a = r.render(&view, &ThicknessOptions::default()).unwrap();
    let b = r
        .render(
            &view,
            &ThicknessOptions {
                cull: false,
                ..ThicknessOptions::default()
            },
        )
        .unwrap();
    assert_eq!(a.line_integral, b.line_integral);
    assert!(a.stats.rays_culled > 0 && b.stats.rays_culled == 0);
}

#[test]
fn homography_law_holds_for_rendered_images() {
    // Rendering with K' = the reference image warped by H = K' K⁻¹. Sample the reference image at
    // H⁻¹ x by rendering exactly that ray (no interpolation error): the perturbed render at x must equal the
    // reference ray through H⁻¹ x, and landmarks move by H.
    let meshes = vec![(
        TriMesh::icosphere("s", DVec3::new(2.0, 1.0, -3.0), 15.0, 4),
        1.0,
    )];
    let view = oblique_view(128);
    for backend in [Backend::Embree, Backend::Raster] {
        let r = backend.renderer(scene(meshes.clone())).unwrap();
        for spec in [
            "df=300",
            "dcx=20,dcy=-10",
            "alpha=1.05,skew=1.5",
            "sx=1.01,sy=0.99",
        ] {
            let p = Perturbation::parse(spec).unwrap();
            let pv = view.perturbed(&p).unwrap();
            let img = r
                .render(&pv, &ThicknessOptions::default())
                .unwrap()
                .line_integral;
            let h_inv = view.homography_to(&pv).inverse();
            for (u, v) in [(64u32, 64u32), (50, 70), (80, 55), (40, 40)] {
                let x0 = apply_homography(&h_inv, DVec2::new(u as f64, v as f64));
                let ray = view.pixel_ray(x0.x, x0.y);
                let (expected, _) = r.trace_ray(ray.origin, ray.dir);
                assert!(
                    (img.get(u, v) as f64 - expected).abs() < 1e-4,
                    "{backend:?} {spec} at ({u},{v})"
                );
            }
            let x = DVec3::new(5.0, -2.0, 7.0);
            let moved = apply_homography(&view.homography_to(&pv), view.project(x));
            assert!((moved - pv.project(x)).length() < 1e-9);
        }
    }
}

#[test]
fn rays_through_vertices_and_edges_do_not_spike() {
    // Rays aimed exactly at every vertex and every edge midpoint of a coarse sphere and of a box: each
    // value must be bounded by the longest chord, and the renderer reports how many needed repair.
    for backend in [Backend::Embree, Backend::Bvh] {
        for mesh in [
            TriMesh::icosphere("ico", DVec3::ZERO, 12.0, 1),
            TriMesh::cuboid("box", DVec3::splat(-10.0), DVec3::splat(10.0)),
        ] {
            let max_chord = mesh.max_chord();
            let mut targets: Vec<DVec3> = mesh.vertices.clone();
            for t in &mesh.triangles {
                for k in 0..3 {
                    targets.push(
                        0.5 * (mesh.vertices[t[k] as usize]
                            + mesh.vertices[t[(k + 1) % 3] as usize]),
                    );
                }
            }
            let r = backend.renderer(scene(vec![(mesh, 1.0)])).unwrap();
            for source in [
                DVec3::new(0.0, -700.0, 0.0),
                DVec3::new(400.0, -500.0, 300.0),
            ] {
                for &p in &targets {
                    let (l, _) = r.trace_ray(source, (p - source).normalize());
                    assert!(
                        l.abs() <= max_chord + 1e-9,
                        "{backend:?}: {l} through {p:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn raster_pixels_exactly_on_vertices_and_edges_pair_up() {
    // Looking straight down the y axis with f = 1000 px at 1000 mm, a cube face at depth 1000 mm projects
    // with one pixel per millimetre: every vertex and every edge (sides and face diagonals) of the front
    // faces of these cubes passes exactly through pixel centres. The raster's tie rule must still give
    // each ray every crossing once: the image equals the analytic chords, with no repairs left over.
    let k = Intrinsics {
        fx: 1000.0,
        fy: 1000.0,
        skew: 0.0,
        cx: 40.0,
        cy: 40.0,
        width: 81,
        height: 81,
    };
    let t = RigidTransform::look_at(
        DVec3::new(0.0, -1000.0, 0.0),
        DVec3::ZERO,
        DVec3::new(0.0, 0.0, 1.0),
    )
    .unwrap();
    let view = View::new("axis", k, t);
    for (lo, hi) in [
        (DVec3::new(-20.0, 0.0, -20.0), DVec3::new(20.0, 30.0, 20.0)),
        (DVec3::new(-7.0, 0.0, 3.0), DVec3::new(12.0, 4.0, 30.0)),
    ] {
        let cube = TriMesh::cuboid("cube", lo, hi);
        // The front face (y = 0) projects to whole pixels: check the premise.
        for p in cube.vertices.iter().filter(|p| p.y == 0.0) {
            let x = view.project(*p);
            assert_eq!((x.x.fract(), x.y.fract()), (0.0, 0.0), "{p:?} → {x:?}");
        }
        let drr = Backend::Raster
            .renderer(scene(vec![(cube, 1.0)]))
            .unwrap()
            .render(&view, &ThicknessOptions::default())
            .unwrap();
        for v in 0..81 {
            for u in 0..81 {
                let ray = view.pixel_ray(u as f64, v as f64);
                let exact = box_chord(lo, hi, ray.origin, ray.dir);
                let got = drr.line_integral.get(u, v) as f64;
                // Rays exactly on the box's side faces graze them: either 0 or the full chord is right.
                let on_side = exact == 0.0 || ray.origin.x + ray.dir.x * 1000.0 == lo.x;
                assert!(
                    (got - exact).abs() <= 1e-6 || on_side,
                    "({u},{v}): {got} vs {exact}"
                );
            }
        }
        assert_eq!(drr.stats.rays_unrepaired, 0);
    }
}

/// Bilinear sample of an image at a sub-pixel position (pixel centres at integers); `None` outside.
fn bilinear(img: &spinedrr::io::ImageF32, x: f64, y: f64) -> Option<f64> {
    let (x0, y0) = (x.floor(), y.floor());
    if x0 < 0.0 || y0 < 0.0 || x0 + 1.0 >= img.width as f64 || y0 + 1.0 >= img.height as f64 {
        return None;
    }
    let (fx, fy) = (x - x0, y - y0);
    let (u, v) = (x0 as u32, y0 as u32);
    let g = |du: u32, dv: u32| img.get(u + du, v + dv) as f64;
    Some(
        g(0, 0) * (1.0 - fx) * (1.0 - fy)
            + g(1, 0) * fx * (1.0 - fy)
            + g(0, 1) * (1.0 - fx) * fy
            + g(1, 1) * fx * fy,
    )
}

#[test]
fn perturbed_image_is_the_reference_warped_by_the_homography() {
    // A smooth object (a finely tessellated sphere) so that bilinear resampling is accurate away from the
    // silhouette rim, where the chord's slope is unbounded: compare only pixels well inside the disc.
    let (c, r) = (DVec3::new(1.0, -2.0, 3.0), 20.0);
    let meshes = vec![(TriMesh::icosphere("s", c, r, 5), 1.0)];
    let view = oblique_view(160);
    let rend = Backend::Embree.renderer(scene(meshes)).unwrap();
    let reference = rend
        .render(&view, &ThicknessOptions::default())
        .unwrap()
        .line_integral;
    for spec in ["df=300", "alpha=0.97,dcx=12.5,dcy=-7.25", "skew=2,sx=1.02"] {
        let pv = view.perturbed(&Perturbation::parse(spec).unwrap()).unwrap();
        let perturbed = rend
            .render(&pv, &ThicknessOptions::default())
            .unwrap()
            .line_integral;
        let h_inv = view.homography_to(&pv).inverse();
        let (mut n, mut worst) = (0, 0f64);
        for v in 0..160u32 {
            for u in 0..160u32 {
                let x = apply_homography(&h_inv, DVec2::new(u as f64, v as f64));
                let ray = view.pixel_ray(x.x, x.y);
                let d = (c - ray.origin).reject_from(ray.dir).length();
                if d > 0.8 * r {
                    continue;
                }
                let Some(warped) = bilinear(&reference, x.x, x.y) else {
                    continue;
                };
                worst = worst.max((perturbed.get(u, v) as f64 - warped).abs());
                n += 1;
            }
        }
        assert!(n > 3000, "{spec}: only {n} interior pixels");
        // Chord 2√(r² − d²) over one pixel (~0.23 mm at this magnification) changes by at most ~0.35 mm
        // for d ≤ 0.8 r; bilinear interpolation errs by a small fraction of that.
        assert!(
            worst < 0.02,
            "{spec}: worst |perturbed − warped reference| = {worst} mm"
        );
    }
}

/// A box reaching behind the source plane cannot be projected: the raster backend traces that view
/// instead, and still gives the analytic chords (and the reference backend's image).
#[test]
fn raster_traces_a_view_with_vertices_behind_the_source() {
    let view = oblique_view(120);
    let to_world = view.world_to_camera.inverse();
    // Camera frame: beside the source, from 40 mm behind it to 400 mm in front.
    let (lo, hi) = (DVec3::new(4.0, -3.0, -40.0), DVec3::new(14.0, 3.0, 400.0));
    let mut mesh = TriMesh::cuboid("long", lo, hi);
    for p in &mut mesh.vertices {
        *p = to_world.apply(*p);
    }
    let meshes = vec![(mesh, 1.0)];
    let raster = Backend::Raster
        .renderer(scene(meshes.clone()))
        .unwrap()
        .render(&view, &ThicknessOptions::default())
        .unwrap();
    let bvh = Backend::Bvh
        .renderer(scene(meshes))
        .unwrap()
        .render(&view, &ThicknessOptions::default())
        .unwrap();
    let k = view.intrinsics;
    let mut hit = 0;
    for v in 0..k.height {
        for u in 0..k.width {
            let i = (v * k.width + u) as usize;
            let d = k.back_project(u as f64, v as f64).normalize();
            let truth = box_chord(lo, hi, DVec3::ZERO, d);
            let got = f64::from(raster.line_integral.data[i]);
            assert!(
                (got - truth).abs() <= 1e-3,
                "pixel ({u}, {v}): {got} vs analytic {truth}"
            );
            assert!((raster.line_integral.data[i] - bvh.line_integral.data[i]).abs() <= 1e-4);
            hit += usize::from(truth > 1.0);
        }
    }
    assert!(hit > 500, "only {hit} pixels see the box");
}
