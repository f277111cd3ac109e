//! Direct registration: Levenberg–Marquardt over SE(3) minimising the reprojection error
//! `Σ_v Σ_i ‖x_iv − π_v(R X_i + t)‖²` with an analytic Jacobian.
//!
//! Parametrisation: a left increment `(δω, δt)` about the current landmark centroid `c` in world
//! coordinates, `Y ↦ exp([δω]×)(Y − c) + c + δt`, so `∂Y/∂δω = −[Y − c]×` and `∂Y/∂δt = I`.
//! Damping follows Marquardt (1963): `(JᵀJ + λ diag(JᵀJ)) δ = −Jᵀr`, λ divided by 10 after an accepted
//! step and multiplied by 10 after a rejected one. Stopping rules are the paper's: relative cost decrease,
//! step size, or the iteration cap.

use glam::{DMat3, DVec3};

use super::{RegistrationOptions, RegistrationProblem, RegistrationResult, mean_residual_px};
use crate::geometry::{RigidTransform, View, rotation_exp};
use crate::math::cholesky_solve;
use crate::{Error, Result};

/// Sum of squared reprojection residuals (px²) of `pose` over every observation.
pub fn cost(problem: &RegistrationProblem, pose: &RigidTransform) -> f64 {
    problem
        .views
        .iter()
        .flat_map(|ov| {
            ov.observed.iter().map(move |&(i, x)| {
                (x - ov.view.project(pose.apply(problem.model_points[i]))).length_squared()
            })
        })
        .sum()
}

/// Jacobian (2×3) of the pixel with respect to the world point, `∂π/∂p · R_view`.
fn pixel_jacobian_world(view: &View, world: DVec3) -> [DVec3; 2] {
    let k = &view.intrinsics;
    let r = view.world_to_camera.rotation;
    let p = view.world_to_camera.apply(world);
    let iz = 1.0 / p.z;
    // d(u, v)/d(camera point), each row as a vector; then chain through R (row · R = Rᵀ row).
    let du = DVec3::new(
        k.fx * iz,
        k.skew * iz,
        -(k.fx * p.x + k.skew * p.y) * iz * iz,
    );
    let dv = DVec3::new(0.0, k.fy * iz, -k.fy * p.y * iz * iz);
    [r.transpose() * du, r.transpose() * dv]
}

/// Accumulates the normal equations `JᵀJ` and `Jᵀr` (r = observed − projected) about centre `c`.
fn normal_equations(
    problem: &RegistrationProblem,
    pose: &RigidTransform,
    c: DVec3,
) -> ([[f64; 6]; 6], [f64; 6]) {
    let mut jtj = [[0.0; 6]; 6];
    let mut jtr = [0.0; 6];
    for ov in &problem.views {
        for &(i, x) in &ov.observed {
            let y = pose.apply(problem.model_points[i]);
            let r = x - ov.view.project(y);
            let d = y - c;
            for (row, res) in pixel_jacobian_world(&ov.view, y)
                .into_iter()
                .zip([r.x, r.y])
            {
                // row · (−[d]× δω) = (d × row) · δω.
                let jw = d.cross(row);
                let j = [jw.x, jw.y, jw.z, row.x, row.y, row.z];
                for a in 0..6 {
                    jtr[a] += j[a] * res;
                    for b in 0..6 {
                        jtj[a][b] += j[a] * j[b];
                    }
                }
            }
        }
    }
    (jtj, jtr)
}

/// Applies the increment `(δω, δt)` about `c`.
fn apply_increment(pose: &RigidTransform, delta: &[f64; 6], c: DVec3) -> RigidTransform {
    let rot: DMat3 = rotation_exp(DVec3::new(delta[0], delta[1], delta[2]));
    let dt = DVec3::new(delta[3], delta[4], delta[5]);
    RigidTransform {
        rotation: rot * pose.rotation,
        translation: rot * (pose.translation - c) + c + dt,
    }
}

/// Runs Levenberg–Marquardt from `init`.
pub fn register_direct(
    problem: &RegistrationProblem,
    init: &RigidTransform,
    opts: &RegistrationOptions,
) -> Result<RegistrationResult> {
    let mut pose = *init;
    let mut f = cost(problem, &pose);
    if !f.is_finite() {
        return Err(Error::Numerical(
            "initial reprojection cost is not finite".into(),
        ));
    }
    let mut lambda = 1e-3;
    let mut converged = false;
    let mut iterations = 0;
    let n_model = problem.model_points.len() as f64;
    let centroid_model = problem.model_points.iter().fold(DVec3::ZERO, |a, &p| a + p) / n_model;
    while iterations < opts.max_iterations && !converged {
        iterations += 1;
        if f == 0.0 {
            converged = true;
            break;
        }
        let c = pose.apply(centroid_model);
        let (jtj, jtr) = normal_equations(problem, &pose, c);
        loop {
            let mut a = jtj;
            for (k, row) in a.iter_mut().enumerate() {
                row[k] += lambda * jtj[k][k].max(1e-12);
            }
            let Some(delta) = cholesky_solve(&a, &jtr) else {
                lambda *= 10.0;
                if lambda > 1e16 {
                    return Err(Error::Numerical("normal equations are singular".into()));
                }
                continue;
            };
            let candidate = apply_increment(&pose, &delta, c);
            let f_new = cost(problem, &candidate);
            let step = step_size(&delta, c);
            if f_new.is_finite() && f_new <= f {
                let rel = (f - f_new) / f;
                pose = candidate;
                f = f_new;
                lambda = (lambda / 10.0).max(1e-12);
                converged = rel < opts.rel_cost_tol || step < opts.step_tol;
                break;
            }
            // A rejected step smaller than the tolerance means we are at the minimum to rounding.
            if step < opts.step_tol {
                converged = true;
                break;
            }
            lambda *= 10.0;
            if lambda > 1e16 {
                converged = true;
                break;
            }
        }
    }
    Ok(RegistrationResult {
        pose,
        residual_px: mean_residual_px(problem, &pose),
        iterations,
        converged,
    })
}

/// Relative step size: rotation in radians plus translation relative to the working distance.
fn step_size(delta: &[f64; 6], c: DVec3) -> f64 {
    let w = DVec3::new(delta[0], delta[1], delta[2]).length();
    let t = DVec3::new(delta[3], delta[4], delta[5]).length();
    w + t / c.length().max(1.0)
}
