//! Two-view ("Kabsch") registration: triangulate every landmark seen in two or more views with the
//! assumed intrinsics, then fit the rigid model → world transform to the triangulated points.
//!
//! * Triangulation: linear DLT (Hartley & Zisserman §12.2) on normalised image coordinates
//!   `K⁻¹ x`, the homogeneous point being the eigenvector of `AᵀA` with the smallest eigenvalue; then a
//!   Gauss–Newton refinement of the pixel reprojection error of each point.
//! * Alignment: Horn's closed form (1987) — the unit quaternion maximising `Σ (R X_i)·Y_i` is the top
//!   eigenvector of the 4×4 matrix built from the cross-covariance; equivalent to Kabsch/Umeyama without
//!   scale, and free of the SVD reflection case.

use glam::{DMat3, DQuat, DVec2, DVec3};

use super::{RegistrationProblem, RegistrationResult, mean_residual_px};
use crate::geometry::{RigidTransform, View};
use crate::math::{cholesky_solve, symmetric_eigen};
use crate::{Error, Result};

/// Triangulates one point from `(view, pixel)` observations (at least two).
pub fn triangulate(obs: &[(&View, DVec2)]) -> Result<DVec3> {
    if obs.len() < 2 {
        return Err(Error::invalid(
            "observations",
            format!("triangulation needs two views, got {}", obs.len()),
        ));
    }
    let mut ata = [[0.0; 4]; 4];
    for (view, x) in obs {
        let d = view.intrinsics.back_project(x.x, x.y);
        // The rows of the camera matrix [R | t].
        let [p1, p2, p3, _] = view.world_to_camera.to_rows();
        for (coord, p) in [(d.x, p1), (d.y, p2)] {
            let a: [f64; 4] = std::array::from_fn(|j| coord * p3[j] - p[j]);
            let norm = a.iter().map(|v| v * v).sum::<f64>().sqrt();
            for i in 0..4 {
                for j in 0..4 {
                    ata[i][j] += a[i] * a[j] / (norm * norm);
                }
            }
        }
    }
    // The smallest eigenvalue's eigenvector.
    let h = symmetric_eigen(ata).vectors[0];
    if h[3].abs() < 1e-15 {
        return Err(Error::Numerical(
            "triangulated point is at infinity (parallel rays)".into(),
        ));
    }
    let x0 = DVec3::new(h[0] / h[3], h[1] / h[3], h[2] / h[3]);
    Ok(refine_point(obs, x0))
}

/// Gauss–Newton on `Σ ‖x − π(X)‖²` over the 3D point (a few iterations; the DLT start is close).
fn refine_point(obs: &[(&View, DVec2)], mut x: DVec3) -> DVec3 {
    for _ in 0..10 {
        let mut jtj = [[0.0; 3]; 3];
        let mut jtr = [0.0; 3];
        for (view, px) in obs {
            let r = *px - view.project(x);
            let k = &view.intrinsics;
            let p = view.world_to_camera.apply(x);
            let iz = 1.0 / p.z;
            let rt = view.world_to_camera.rotation.transpose();
            let du = rt
                * DVec3::new(
                    k.fx * iz,
                    k.skew * iz,
                    -(k.fx * p.x + k.skew * p.y) * iz * iz,
                );
            let dv = rt * DVec3::new(0.0, k.fy * iz, -k.fy * p.y * iz * iz);
            for (j, res) in [(du, r.x), (dv, r.y)] {
                let j = j.to_array();
                for a in 0..3 {
                    jtr[a] += j[a] * res;
                    for b in 0..3 {
                        jtj[a][b] += j[a] * j[b];
                    }
                }
            }
        }
        let Some(d) = cholesky_solve(&jtj, &jtr) else {
            break;
        };
        let d = DVec3::from(d);
        x += d;
        if d.length() < 1e-13 * x.length().max(1.0) {
            break;
        }
    }
    x
}

/// The rigid transform minimising `Σ ‖R X_i + t − Y_i‖²` (Horn's quaternion method).
pub fn fit_rigid(model: &[DVec3], world: &[DVec3]) -> Result<RigidTransform> {
    if model.len() != world.len() || model.len() < 3 {
        return Err(Error::invalid(
            "points",
            format!(
                "a rigid fit needs at least 3 point pairs of equal count, got {} model and {} world points",
                model.len(),
                world.len()
            ),
        ));
    }
    let n = model.len() as f64;
    let cm = model.iter().fold(DVec3::ZERO, |a, &p| a + p) / n;
    let cw = world.iter().fold(DVec3::ZERO, |a, &p| a + p) / n;
    let mut s = [[0.0; 3]; 3]; // S_ab = Σ X_a Y_b
    for (x, y) in model.iter().zip(world) {
        let (x, y) = ((*x - cm).to_array(), (*y - cw).to_array());
        for a in 0..3 {
            for b in 0..3 {
                s[a][b] += x[a] * y[b];
            }
        }
    }
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = s;
    let nmat = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    // The largest eigenvalue's eigenvector.
    let [w, x, y, z] = symmetric_eigen(nmat).vectors[3];
    let q = DQuat::from_xyzw(x, y, z, w).normalize();
    let r = DMat3::from_quat(q);
    if !r.is_finite() {
        return Err(Error::Numerical(
            "rigid fit produced a non-finite rotation".into(),
        ));
    }
    Ok(RigidTransform::new(r, cw - r * cm))
}

/// Two-view registration: triangulate, then [`fit_rigid`] onto the model landmarks.
pub fn register_kabsch(problem: &RegistrationProblem) -> Result<RegistrationResult> {
    let idx = problem.multi_view_landmarks();
    if problem.views.len() < 2 || idx.len() < 3 {
        return Err(Error::invalid(
            "method",
            "kabsch needs at least two views sharing at least 3 landmarks",
        ));
    }
    let mut model = Vec::with_capacity(idx.len());
    let mut world = Vec::with_capacity(idx.len());
    for &i in &idx {
        let obs: Vec<(&View, DVec2)> = problem
            .views
            .iter()
            .flat_map(|ov| {
                ov.observed
                    .iter()
                    .filter(move |&&(j, _)| j == i)
                    .map(move |&(_, x)| (&ov.view, x))
            })
            .collect();
        world.push(triangulate(&obs)?);
        model.push(problem.model_points[i]);
    }
    let pose = fit_rigid(&model, &world)?;
    Ok(RegistrationResult {
        pose,
        residual_px: mean_residual_px(problem, &pose),
        iterations: 0,
        converged: true,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{CArm, rotation_angle_deg, rotation_exp};

    #[test]
    fn horn_fit_recovers_rotations_up_to_pi() {
        let model = [
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(30.0, 1.0, -2.0),
            DVec3::new(-4.0, 25.0, 3.0),
            DVec3::new(5.0, -6.0, 18.0),
        ];
        for w in [
            DVec3::new(0.1, -0.2, 0.3),
            DVec3::new(0.0, 0.0, std::f64::consts::PI),
            DVec3::ZERO,
        ] {
            let t = RigidTransform::new(rotation_exp(w), DVec3::new(10.0, -20.0, 5.0));
            let world: Vec<DVec3> = model.iter().map(|&p| t.apply(p)).collect();
            let got = fit_rigid(&model, &world).unwrap();
            assert!(rotation_angle_deg(got.rotation * t.rotation.transpose()) < 1e-9);
            assert!((got.translation - t.translation).length() < 1e-9);
        }
        assert!(fit_rigid(&model[..2], &model[..2]).is_err());
    }

    #[test]
    fn triangulation_inverts_projection() {
        let c = CArm::default_paper();
        let (ap, lat) = (c.view("ap").unwrap(), c.view("lat").unwrap());
        let x = DVec3::new(12.0, -30.0, 7.5);
        let got = triangulate(&[(ap, ap.project(x)), (lat, lat.project(x))]).unwrap();
        assert!((got - x).length() < 1e-9, "{got:?}");
        assert!(triangulate(&[(ap, ap.project(x))]).is_err());
    }
}
