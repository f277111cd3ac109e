//! CT volume DRR: Siddon against analytic chords, trilinear against Siddon, the homography law, masks.

use glam::{DMat3, DMat4, DVec2, DVec3};
use spinedrr::anatomy::MU_WATER_PER_MM;
use spinedrr::anatomy::ct::{CtVolume, LabelMap, Volume, VoxelMask};
use spinedrr::geometry::{Perturbation, Ray, View, apply_homography};
use spinedrr::render::volume::{VolumeMethod, VolumeRenderOptions, VolumeRenderer, render_volume};

/// A rotation (not axis aligned) and anisotropic spacings: the world box is an oblique cuboid.
fn oblique() -> (DMat3, DVec3, DVec3) {
    let rot = DMat3::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
    (rot, DVec3::new(1.2, 0.8, 2.0), DVec3::new(-10.0, 4.0, 7.0))
}

fn affine(rot: DMat3, spacing: DVec3, origin: DVec3) -> DMat4 {
    DMat4::from_mat3_translation(rot * DMat3::from_diagonal(spacing), origin)
}

/// Chord length of a ray through the cuboid `{origin + rot·q : lo ≤ q ≤ hi}` (q in mm, box frame):
/// slab method in the box's own orthonormal frame, independent of the renderer's index-space clipping.
fn chord(ray: &Ray, rot: DMat3, origin: DVec3, lo: DVec3, hi: DVec3) -> f64 {
    let o = rot.transpose() * (ray.origin - origin);
    let d = rot.transpose() * ray.dir;
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for a in 0..3 {
        if d[a].abs() < 1e-15 {
            if o[a] < lo[a] || o[a] > hi[a] {
                return 0.0;
            }
            continue;
        }
        let (ta, tb) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    (t1 - t0).max(0.0)
}

fn mu(hu: f64) -> f64 {
    MU_WATER_PER_MM * (1.0 + hu / 1000.0).max(0.0)
}

/// Deterministic pseudo-random numbers in [0, 1) (a 64-bit LCG), so the test needs no rng crate.
fn lcg(state: &mut u64) -> f64 {
    *state = state
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*state >> 11) as f64 / (1u64 << 53) as f64
}

fn siddon() -> VolumeRenderOptions {
    VolumeRenderOptions::default()
}

#[test]
fn siddon_through_uniform_box_is_mu_times_chord() {
    let (rot, sp, origin) = oblique();
    let dims = [20usize, 16, 12];
    let hu = 800.0;
    // A uniform sub-box (voxels 5..=14, 3..=12, 2..=9) inside air (−1000 HU, μ = 0).
    let mut ct = CtVolume::filled(dims, -1000.0, affine(rot, sp, origin)).unwrap();
    let (blo, bhi) = ([5, 3, 2], [14, 12, 9]);
    for k in blo[2]..=bhi[2] {
        for j in blo[1]..=bhi[1] {
            for i in blo[0]..=bhi[0] {
                let n = ct.linear(i, j, k);
                ct.values[n] = hu as f32;
            }
        }
    }
    let r = VolumeRenderer::new(&ct, &siddon(), None).unwrap();
    let lo = DVec3::new(
        blo[0] as f64 - 0.5,
        blo[1] as f64 - 0.5,
        blo[2] as f64 - 0.5,
    ) * sp;
    let hi = DVec3::new(
        bhi[0] as f64 + 0.5,
        bhi[1] as f64 + 0.5,
        bhi[2] as f64 + 0.5,
    ) * sp;
    let centre = origin + rot * (0.5 * (lo + hi));
    let mut s = 7u64;
    let mut hits = 0;
    for _ in 0..2000 {
        let dir = DVec3::new(lcg(&mut s) - 0.5, lcg(&mut s) - 0.5, lcg(&mut s) - 0.5).normalize();
        let jitter = DVec3::new(lcg(&mut s) - 0.5, lcg(&mut s) - 0.5, lcg(&mut s) - 0.5) * 14.0;
        let ray = Ray {
            origin: centre + jitter - 300.0 * dir,
            dir,
        };
        let want = mu(hu) * chord(&ray, rot, origin, lo, hi);
        let got = r.line_integral(&ray);
        if want > 0.0 {
            hits += 1;
        }
        assert!(
            (got - want).abs() <= 1e-4 * want.max(1e-3),
            "got {got}, want {want}, ray {ray:?}"
        );
    }
    assert!(hits > 1000, "most rays must hit the box ({hits})");
    // Axis-parallel rays along the index axes cross exactly n voxels.
    let along_i = Ray {
        origin: origin + rot * DVec3::new(-50.0, 7.0 * sp.y, 5.0 * sp.z),
        dir: rot.x_axis,
    };
    let want = mu(hu) * (bhi[0] - blo[0] + 1) as f64 * sp.x;
    let got = r.line_integral(&along_i);
    assert!((got - want).abs() < 1e-6 * want, "{got} vs {want}");
}

#[test]
fn rendered_box_matches_analytic_chords_per_pixel() {
    let (rot, sp, origin) = oblique();
    let dims = [24usize, 20, 16];
    let ct = CtVolume::filled(dims, 300.0, affine(rot, sp, origin)).unwrap();
    let lo = -0.5 * sp;
    let hi = DVec3::new(
        dims[0] as f64 - 0.5,
        dims[1] as f64 - 0.5,
        dims[2] as f64 - 0.5,
    ) * sp;
    let centre = origin + rot * (0.5 * (lo + hi));
    let view = small_view(centre, 48);
    let img = render_volume(&ct, &view, &siddon(), None).unwrap();
    for v in 0..48u32 {
        for u in 0..48u32 {
            let want = mu(300.0) * chord(&view.pixel_ray(u as f64, v as f64), rot, origin, lo, hi);
            let got = f64::from(img.get(u, v));
            assert!(
                (got - want).abs() <= 1e-4 * want.max(1e-2),
                "({u},{v}) {got} vs {want}"
            );
        }
    }
}

/// A `n × n` view of `target` from 400 mm, oblique to the volume axes.
fn small_view(target: DVec3, n: u32) -> View {
    crate::common::view_from(target, DVec3::new(120.0, -370.0, 90.0), n)
}

/// A smooth volume: a Gaussian blob (σ = 3.5 voxels) of up to 1500 HU on water.
fn blob(dims: [usize; 3], a: DMat4) -> CtVolume {
    let c = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64) * 0.5 - 0.5;
    let mut ct = CtVolume::filled(dims, 0.0, a).unwrap();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let d2 = (DVec3::new(i as f64, j as f64, k as f64) - c).length_squared();
                let n = ct.linear(i, j, k);
                ct.values[n] = (1500.0 * (-d2 / (2.0 * 3.5 * 3.5)).exp()) as f32;
            }
        }
    }
    ct
}

#[test]
fn trilinear_agrees_with_siddon_on_a_smooth_volume() {
    let (rot, sp, origin) = oblique();
    let dims = [32usize, 28, 20];
    let ct = blob(dims, affine(rot, sp, origin));
    let centre = ct.voxel_centre(16, 14, 10);
    let view = small_view(centre, 40);
    let a = render_volume(&ct, &view, &siddon(), None).unwrap();
    let opts = VolumeRenderOptions {
        method: VolumeMethod::Trilinear,
        ..siddon()
    };
    let b = render_volume(&ct, &view, &opts, None).unwrap();
    let max = a.max();
    let mut compared = 0;
    for (x, y) in a.data.iter().zip(&b.data) {
        if *x > 0.1 * max {
            compared += 1;
            assert!((x - y).abs() <= 0.01 * x, "siddon {x} vs trilinear {y}");
        }
    }
    assert!(compared > 200, "{compared}");
}

#[test]
fn homography_law_holds_for_volume_drrs() {
    let (rot, sp, origin) = oblique();
    let ct = blob([32, 28, 20], affine(rot, sp, origin));
    let view = small_view(ct.voxel_centre(16, 14, 10), 40);
    for method in [VolumeMethod::Siddon, VolumeMethod::Trilinear] {
        let r =
            VolumeRenderer::new(&ct, &VolumeRenderOptions { method, ..siddon() }, None).unwrap();
        let reference = r.render(&view);
        // A focal change with shift and skew: pixel x' of the perturbed image sees the reference ray at H⁻¹x'.
        let p = Perturbation::parse("df=60,dcx=3.5,dcy=-2,skew=1.5").unwrap();
        let pv = view.perturbed(&p).unwrap();
        let img = r.render(&pv);
        let h_inv = view.homography_to(&pv).inverse();
        for v in (0..40).step_by(3) {
            for u in (0..40).step_by(3) {
                let x = apply_homography(&h_inv, DVec2::new(u as f64, v as f64));
                let want = r.line_integral(&view.pixel_ray(x.x, x.y));
                let got = f64::from(img.get(u, v));
                assert!(
                    (got - want).abs() <= 1e-5 * want.max(1e-3),
                    "{method} ({u},{v}): {got} vs {want}"
                );
            }
        }
        // An integer piercing shift moves the image by exactly that many pixels.
        let shifted = r.render(&view.perturbed(&Perturbation::piercing(5.0, -4.0)).unwrap());
        for v in 0..36u32 {
            for u in 0..35u32 {
                let (x, y) = (reference.get(u, v + 4), shifted.get(u + 5, v));
                assert!(
                    (x - y).abs() <= 1e-5 * x.max(1e-3),
                    "{method} shift ({u},{v}) {x} vs {y}"
                );
            }
        }
    }
}

#[test]
fn label_mask_renders_one_vertebra_only() {
    let dims = [30usize, 30, 40];
    let a = DMat4::from_scale(DVec3::new(1.0, 1.0, 1.5));
    let ct = blob(dims, a);
    let mut seg = LabelMap::filled(dims, 0, a).unwrap();
    for k in 0..dims[2] {
        for j in 5..25 {
            for i in 5..25 {
                let n = seg.linear(i, j, k);
                seg.values[n] = if k < 20 { 31 } else { 30 };
            }
        }
    }
    let mask = VoxelMask::from_labels(&seg, &[31]).unwrap();
    // Second method: the unmasked renderer on a CT whose other voxels are air (μ = 0).
    let mut only: Volume<f32> = ct.clone();
    for (v, &l) in only.values.iter_mut().zip(&seg.values) {
        if l != 31 {
            *v = -1000.0;
        }
    }
    let view = small_view(ct.voxel_centre(15, 15, 20), 40);
    for method in [VolumeMethod::Siddon, VolumeMethod::Trilinear] {
        let opts = VolumeRenderOptions { method, ..siddon() };
        let masked = render_volume(&ct, &view, &opts, Some(&mask)).unwrap();
        let full = render_volume(&only, &view, &opts, None).unwrap();
        let all = render_volume(&ct, &view, &opts, None).unwrap();
        assert!(masked.data.iter().zip(&all.data).any(|(m, f)| *m < 0.9 * f));
        if method == VolumeMethod::Siddon {
            for (m, f) in masked.data.iter().zip(&full.data) {
                assert!((m - f).abs() <= 1e-5 * f.max(1e-3), "{m} vs {f}");
            }
        }
    }
}

#[test]
fn bad_options_are_errors() {
    let ct = CtVolume::filled([4, 4, 4], 0.0, DMat4::IDENTITY).unwrap();
    let bad = VolumeRenderOptions {
        mu_water: -1.0,
        ..siddon()
    };
    assert!(
        VolumeRenderer::new(&ct, &bad, None)
            .unwrap_err()
            .to_string()
            .contains("mu_water")
    );
    let seg = LabelMap::filled([4, 4, 5], 1, DMat4::IDENTITY).unwrap();
    let m = VoxelMask::from_labels(&seg, &[1]).unwrap();
    assert!(VolumeRenderer::new(&ct, &siddon(), Some(&m)).is_err());
    assert!("mip".parse::<VolumeMethod>().is_err());
}

/// The render traces only the pixels inside the clip box's projected footprint: every pixel, inside or
/// outside it, must still equal the line integral of its own ray, for a masked level that covers a small
/// part of the detector, one cut by the detector's edge, and one entirely off the detector.
#[test]
fn footprint_culling_keeps_every_pixel() {
    let dims = [30usize, 30, 40];
    let a = DMat4::from_scale(DVec3::new(1.0, 1.0, 1.5));
    let ct = blob(dims, a);
    let mut seg = LabelMap::filled(dims, 0, a).unwrap();
    for k in 22..30 {
        for j in 10..18 {
            for i in 8..16 {
                let n = seg.linear(i, j, k);
                seg.values[n] = 31;
            }
        }
    }
    let mask = VoxelMask::from_labels(&seg, &[31]).unwrap();
    let r = VolumeRenderer::new(&ct, &siddon(), Some(&mask)).unwrap();
    let mut out = spinedrr::io::ImageF32::zeros(3, 3);
    let mut seen = [0usize; 3];
    // Across the view direction of `small_view`: the level moves towards the detector's edge.
    let c = ct.voxel_centre(12, 14, 26);
    let across = DVec3::new(120.0, -370.0, 90.0).cross(DVec3::Z).normalize();
    for (case, target) in [c, c + 50.0 * across, c + 300.0 * across]
        .into_iter()
        .enumerate()
    {
        let mut view = small_view(target, 96);
        view.intrinsics.fx = 4.0 * 96.0;
        view.intrinsics.fy = 4.0 * 96.0;
        r.render_into(&view, &mut out);
        assert_eq!((out.width, out.height), (96, 96));
        for v in 0..96u32 {
            for u in 0..96u32 {
                let want = r.line_integral(&view.pixel_ray(u as f64, v as f64));
                let got = f64::from(out.get(u, v));
                assert!(
                    (got - want).abs() <= 1e-5 * want.max(1e-3),
                    "case {case} ({u},{v}): {got} vs {want}"
                );
                seen[case] += usize::from(want > 0.0);
            }
        }
    }
    // The level fills part of the first detector, less of the second, none of the third.
    assert!(seen[0] > 50 && seen[0] < 96 * 96 / 4, "{seen:?}");
    assert!(seen[1] > 0 && seen[1] < seen[0], "{seen:?}");
    assert_eq!(seen[2], 0);
}
