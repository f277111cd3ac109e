//! Physical geometry errors: the assumed (calibrated) focal spot and detector displaced or rotated
//! relative to the true ones, and the pinhole camera `P' = K' [R' | t']` they amount to.
//!
//! # Derivation
//!
//! In the true view's camera frame (source at the origin, x along detector rows u, y down the detector
//! v, z along the central ray), the detector is the plane `z = S` (S = SDD, mm) and the centre of pixel
//! `w = (u, v, 1)ᵀ` lies at `D(w) = S K⁻¹ w`. The assumed detector is the true one rotated by
//! `R_d = R_z(roll) R_y(tilt_v) R_x(tilt_u)` about the piercing point `p₀ = (0, 0, S)` (where the central
//! ray meets it) and then displaced by `d`; the assumed source sits at `c`. So the assumed detector puts
//! pixel `w` at `D'(w) = R_d (S K⁻¹ w − p₀) + p₀ + d = M w` (M is 3 × 3 because `w₃ = 1`).
//!
//! A point `X` (true camera frame) is imaged at the pixel whose detector point lies on the ray from
//! `c` through `X`: `M w − c = λ (X − c)`. With `A = M − c e₃ᵀ` (c subtracted from M's third column)
//! this reads `A w = λ (X − c)`, so `w ∝ A⁻¹ (X − c)`: a pinhole camera, as any central projection onto
//! a plane is. Factor `A = Q R_A` (QR, Gram–Schmidt on A's columns, `Q` a rotation: its columns are the
//! assumed detector's u direction, its v direction made orthogonal to u, and their cross product, the
//! assumed detector normal; `R_A` upper triangular). Then `A⁻¹ = R_A⁻¹ Qᵀ` and, scaled so that
//! `K'₃₃ = 1`,
//!
//! - `K' = r₃₃ R_A⁻¹`, where `r₃₃ = (Q e₃)ᵀ A e₃` is the assumed source's distance to the assumed
//!   detector plane (the new SDD; it must be positive: the detector in front of the source);
//! - `R'` (true camera → assumed camera) `= Qᵀ`, so the assumed `world_to_camera` is
//!   `X ↦ Qᵀ (R X + t − c)`: rotation `Qᵀ R`, translation `Qᵀ (t − c)`.
//!
//! Consequences, each asserted in the tests: a detector displaced in its own plane (d = (dx, dy, 0)) is a
//! pure piercing shift `Δc = −(dx / s_u, dy / s_v)` px; a displacement along the central ray scales
//! `fx, fy` (and the skew) by `(S + dz) / S` with `c` fixed; source and detector displaced together by
//! the same vector leave `K` unchanged and only translate the camera; a roll keeps `K` and rotates the
//! camera about its axis. A rigid tilt of a detector whose pixel axes are orthogonal produces **no skew
//! and equal focal lengths** in the camera aligned with the tilted detector (`fx' = fy' = S cos θ / s`, the
//! piercing point moved `S sin θ / s` px across the tilt axis): the skew and unequal focal lengths one attributes
//! to a tilt appear only if the tilt is forced into `K` with the rotation held at the calibrated `R`,
//! and then `K` is a general homography, not upper triangular. Skew in `K'` comes from skew in `K`.

use glam::{DMat3, DVec3};

use super::{Intrinsics, Perturbation, RigidTransform, View};
use crate::{Error, Result};

/// The assumed view of `view` (the true one) under the physical part of `p`, before its intrinsic part.
/// `sdd_mm` is the true source-to-detector distance (the camera z of the detector plane).
pub fn assumed_camera(view: &View, p: &Perturbation, sdd_mm: f64) -> Result<View> {
    let s = sdd_mm;
    if !(s.is_finite() && s > 0.0) {
        return Err(Error::invalid(
            "sdd_mm",
            format!("the source-to-detector distance must be positive, got {s}"),
        ));
    }
    let k = &view.intrinsics;
    let a0 = k.matrix().inverse() * s;
    let rd = DMat3::from_rotation_z(p.det_roll_deg.to_radians())
        * DMat3::from_rotation_y(p.det_tilt_v_deg.to_radians())
        * DMat3::from_rotation_x(p.det_tilt_u_deg.to_radians());
    let p0 = DVec3::new(0.0, 0.0, s);
    let d = DVec3::new(p.det_dx_mm, p.det_dy_mm, p.det_dz_mm);
    let c = DVec3::new(p.src_dx_mm, p.src_dy_mm, p.src_dz_mm);
    let m1 = rd * a0.x_axis;
    let m2 = rd * a0.y_axis;
    let m3 = rd * (a0.z_axis - p0) + p0 + d - c;
    // Gram–Schmidt: A = [m1 m2 m3] = Q R_A with Q = [q1 q2 q3] right-handed.
    let r11 = m1.length();
    let q1 = m1 / r11;
    let r12 = q1.dot(m2);
    let w2 = m2 - r12 * q1;
    let r22 = w2.length();
    let q2 = w2 / r22;
    let q3 = q1.cross(q2);
    let (r13, r23, r33) = (q1.dot(m3), q2.dot(m3), q3.dot(m3));
    if !(r33.is_finite() && r33 > 1e-6 * s) {
        return Err(Error::invalid(
            "perturbation",
            format!(
                "'{p}' puts the assumed source {r33:.3} mm from the assumed detector plane (on or \
                 behind it): no image"
            ),
        ));
    }
    // R_A⁻¹ for R_A = [[r11, r12, r13], [0, r22, r23], [0, 0, r33]], times r33.
    let fx = r33 / r11;
    let fy = r33 / r22;
    let skew = -r12 * r33 / (r11 * r22);
    let cx = (r12 * r23 - r13 * r22) / (r11 * r22);
    let cy = -r23 / r22;
    let intrinsics = Intrinsics {
        fx,
        fy,
        skew,
        cx,
        cy,
        width: k.width,
        height: k.height,
    };
    intrinsics.validate().map_err(|e| {
        Error::invalid(
            "perturbation",
            format!("'{p}' gives no valid camera for view '{}': {e}", view.name),
        )
    })?;
    let qt = DMat3::from_cols(q1, q2, q3).transpose();
    let w2c = &view.world_to_camera;
    let world_to_camera = RigidTransform::new(qt * w2c.rotation, qt * (w2c.translation - c));
    Ok(View {
        name: view.name.clone(),
        intrinsics,
        world_to_camera,
        sdd_mm: Some(r33),
    })
}

/// The 3 × 4 projection matrix `K [R | t]` of a view, row-major.
pub fn projection_matrix(view: &View) -> [[f64; 4]; 3] {
    let k = view.intrinsics.matrix();
    let r = view.world_to_camera.rotation;
    let t = view.world_to_camera.translation;
    let kr = k * r;
    let kt = k * t;
    std::array::from_fn(|i| {
        let row = kr.row(i);
        [row.x, row.y, row.z, kt[i]]
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::CArm;
    use glam::DVec2;

    fn ap() -> View {
        CArm::default_paper().view("ap").unwrap().clone()
    }

    fn perturb(spec: &str) -> View {
        ap().perturbed(&Perturbation::parse(spec).unwrap()).unwrap()
    }

    fn points() -> [DVec3; 4] {
        [
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(40.0, -30.0, 25.0),
            DVec3::new(-35.0, 60.0, -45.0),
            DVec3::new(10.0, 80.0, 70.0),
        ]
    }

    #[test]
    fn no_physical_change_is_the_same_camera() {
        let v = ap();
        let q = assumed_camera(&v, &Perturbation::NONE, 1350.0).unwrap();
        for x in points() {
            assert!((q.project(x) - v.project(x)).length() < 1e-9);
        }
    }

    #[test]
    fn a_detector_shift_in_its_plane_is_a_piercing_shift() {
        // 0.3 mm pixels: 3 mm along u and −1.5 mm along v move the image by −10 and +5 px.
        let moved = perturb("det_dx_mm=3,det_dy_mm=-1.5");
        let piercing = ap().perturbed(&Perturbation::piercing(-10.0, 5.0)).unwrap();
        assert!((moved.intrinsics.cx - piercing.intrinsics.cx).abs() < 1e-9);
        assert!((moved.intrinsics.cy - piercing.intrinsics.cy).abs() < 1e-9);
        assert!((moved.intrinsics.fx - 4500.0).abs() < 1e-9);
        for x in points() {
            assert!((moved.project(x) - piercing.project(x)).length() < 1e-9);
        }
    }

    #[test]
    fn source_and_detector_moved_together_only_translate_the_camera() {
        let v = ap();
        let moved =
            perturb("src_dx_mm=4,src_dy_mm=-2,src_dz_mm=7,det_dx_mm=4,det_dy_mm=-2,det_dz_mm=7");
        assert!((moved.intrinsics.matrix() - v.intrinsics.matrix()).abs_diff_eq(DMat3::ZERO, 1e-9));
        assert!(
            (moved.world_to_camera.rotation - v.world_to_camera.rotation)
                .abs_diff_eq(DMat3::ZERO, 1e-12)
        );
        let dt = moved.world_to_camera.translation - v.world_to_camera.translation;
        assert!((dt - DVec3::new(-4.0, 2.0, -7.0)).length() < 1e-9);
    }

    #[test]
    fn a_detector_moved_along_the_ray_scales_the_focal_lengths() {
        for dz in [-20.0, 5.0, 35.0] {
            let moved = perturb(&format!("det_dz_mm={dz}"));
            let scale = (1350.0 + dz) / 1350.0;
            assert!((moved.intrinsics.fx - 4500.0 * scale).abs() < 1e-9);
            assert!((moved.intrinsics.fy - 4500.0 * scale).abs() < 1e-9);
            assert!(moved.intrinsics.skew.abs() < 1e-9);
            assert!((moved.intrinsics.cx - 511.5).abs() < 1e-9);
            let (a, b) = (moved.world_to_camera, ap().world_to_camera);
            assert!((a.rotation - b.rotation).abs_diff_eq(DMat3::ZERO, 1e-12));
            assert!((a.translation - b.translation).length() < 1e-9);
            assert!((moved.sdd_mm.unwrap() - (1350.0 + dz)).abs() < 1e-9);
        }
    }

    #[test]
    fn a_tilt_is_the_camera_of_the_tilted_plane_by_hand() {
        // Tilt by θ about the row axis (camera x) through p0 = (0, 0, S): the plane's normal becomes
        // n = R_x(θ) z, its distance from the source S cos θ, and the foot of the perpendicular lies
        // S sin θ along the tilted v axis from p0 (towards −v for θ > 0).
        let th = 3.0f64.to_radians();
        let s = 1350.0;
        let moved = perturb("det_tilt_u_deg=3");
        let f = s * th.cos() / 0.3;
        assert!((moved.intrinsics.fx - f).abs() < 1e-6, "{moved:?}");
        assert!((moved.intrinsics.fy - f).abs() < 1e-6);
        assert!(moved.intrinsics.skew.abs() < 1e-9);
        assert!((moved.intrinsics.cy - (511.5 - s * th.sin() / 0.3)).abs() < 1e-6);
        // The image of every point is where its ray meets the tilted plane, by hand.
        let v = ap();
        let rx = DMat3::from_rotation_x(th);
        let (n, eu, ev) = (rx * DVec3::Z, rx * DVec3::X, rx * DVec3::Y);
        let p0 = DVec3::new(0.0, 0.0, s);
        for x in points() {
            let xc = v.world_to_camera.apply(x);
            let hit = xc * (p0.dot(n) / xc.dot(n));
            let by_hand = DVec2::new(
                (hit - p0).dot(eu) / 0.3 + 511.5,
                (hit - p0).dot(ev) / 0.3 + 511.5,
            );
            assert!((moved.project(x) - by_hand).length() < 1e-7);
        }
    }

    #[test]
    fn a_source_behind_the_detector_is_refused() {
        let e = ap()
            .perturbed(&Perturbation {
                src_dz_mm: 400.0,
                det_dz_mm: -1000.0,
                ..Perturbation::NONE
            })
            .unwrap_err()
            .to_string();
        assert!(e.contains("behind"), "{e}");
        let no_sdd = View::new("x", ap().intrinsics, ap().world_to_camera);
        let e = no_sdd
            .perturbed(&Perturbation::parse("det_dz_mm=5").unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("source-to-detector distance"), "{e}");
    }

    #[test]
    fn the_projection_matrix_projects_like_the_view() {
        let v = perturb("src_dx_mm=3,det_roll_deg=1,det_tilt_v_deg=2");
        let p = projection_matrix(&v);
        for x in points() {
            let h: [f64; 3] =
                std::array::from_fn(|i| p[i][0] * x.x + p[i][1] * x.y + p[i][2] * x.z + p[i][3]);
            let px = DVec2::new(h[0] / h[2], h[1] / h[2]);
            assert!((px - v.project(x)).length() < 1e-9);
        }
    }
}
