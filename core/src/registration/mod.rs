//! Landmark 2D–3D registration of a rigid vertebra pose `T` (model → world).
//!
//! Three methods behind one call, [`register`]:
//! * [`Method::Direct`]: Levenberg–Marquardt over SE(3) on the reprojection error, any number of views;
//! * [`Method::Kabsch`]: two-view triangulation with the assumed K, then a closed-form rigid fit;
//! * [`Method::OpenCv`]: OpenCV `solvePnP` on a single view, the independent reference.
//!
//! Everything is a pure function of its inputs (no global state, no printing), so a study can run
//! thousands of registrations in parallel.

pub mod intensity;
mod kabsch;
mod lm;
mod pnp;
mod problem;
mod request;
mod synth;
pub mod tracking;

use glam::DVec3;
use serde::Serialize;

pub use kabsch::{fit_rigid, register_kabsch, triangulate};
pub use lm::{cost, register_direct};
pub(crate) use pnp::pose_of_rvec_tvec;
pub use pnp::{PnpSolver, opencv_project_points, register_opencv};
pub use problem::{LoadedProblem, ObservedView, RegistrationProblem};
pub use request::{RegisterOutcome, RegisterRequest, run_request};
pub use synth::{SplitMix64, add_pixel_noise, perturb_pose};

use crate::geometry::{RigidTransform, rotation_angle_deg};
use crate::{Error, Result};

/// Registration method.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    Direct,
    Kabsch,
    OpenCv(PnpSolver),
}

impl Method {
    /// Parses `direct`, `kabsch`, `opencv` (= `opencv-iterative`), `opencv-iterative`, `opencv-sqpnp`.
    pub fn parse(s: &str) -> Result<Method> {
        match s {
            "direct" => Ok(Method::Direct),
            "kabsch" => Ok(Method::Kabsch),
            "opencv" | "opencv-iterative" => Ok(Method::OpenCv(PnpSolver::Iterative)),
            "opencv-sqpnp" => Ok(Method::OpenCv(PnpSolver::Sqpnp)),
            _ => Err(Error::invalid(
                "method",
                format!(
                    "unknown method '{s}' (use direct, kabsch, opencv, opencv-iterative or opencv-sqpnp)"
                ),
            )),
        }
    }
}

/// Solver settings. The stopping rules are the paper's: relative cost decrease below `rel_cost_tol`,
/// step below `step_tol` (radians + translation relative to the working distance), or `max_iterations`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegistrationOptions {
    /// Initial pose (model → world). Without one, `direct` starts from the Kabsch solution (two or more
    /// views) or from OpenCV SQPnP (one view); `opencv-iterative` then runs without a guess.
    pub init: Option<RigidTransform>,
    pub max_iterations: usize,
    pub rel_cost_tol: f64,
    pub step_tol: f64,
}

impl Default for RegistrationOptions {
    fn default() -> Self {
        RegistrationOptions {
            init: None,
            max_iterations: 100,
            rel_cost_tol: 1e-12,
            step_tol: 1e-12,
        }
    }
}

/// The recovered pose and how well it explains the observations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegistrationResult {
    /// Model → world.
    pub pose: RigidTransform,
    /// Mean reprojection residual over all landmarks and views (px), `(1/N) Σ ‖x − x̂‖`.
    pub residual_px: f64,
    /// Iterations of the direct solver (0 for the closed-form and OpenCV methods).
    pub iterations: usize,
    pub converged: bool,
}

/// Registration error against the truth.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PoseError {
    /// Geodesic angle of `R_reg R_gtᵀ`.
    pub rot_err_deg: f64,
    /// `‖t_reg − t_gt‖`.
    pub trans_err_mm: f64,
}

/// Rotation error `rotation_angle_deg(R_reg R_gtᵀ)` and translation error `‖t_reg − t_gt‖`.
pub fn pose_errors(estimate: &RigidTransform, truth: &RigidTransform) -> PoseError {
    PoseError {
        rot_err_deg: rotation_angle_deg(estimate.rotation * truth.rotation.transpose()),
        trans_err_mm: (estimate.translation - truth.translation).length(),
    }
}

/// Mean reprojection residual `(1/N) Σ_v Σ_i ‖x_iv − π_v(T X_i)‖` in pixels.
pub fn mean_residual_px(problem: &RegistrationProblem, pose: &RigidTransform) -> f64 {
    let mut sum = 0.0;
    let mut n = 0usize;
    for ov in &problem.views {
        for &(i, x) in &ov.observed {
            sum += (x - ov.view.project(pose.apply(problem.model_points[i]))).length();
            n += 1;
        }
    }
    if n == 0 { 0.0 } else { sum / n as f64 }
}

/// Registers `problem` with `method`.
pub fn register(
    problem: &RegistrationProblem,
    method: Method,
    opts: &RegistrationOptions,
) -> Result<RegistrationResult> {
    problem.validate()?;
    match method {
        Method::Kabsch => register_kabsch(problem),
        Method::OpenCv(solver) => register_opencv(problem, solver, opts.init.as_ref()),
        Method::Direct => {
            let init = match opts.init {
                Some(t) => t,
                None if problem.views.len() >= 2 => register_kabsch(problem)?.pose,
                None => register_opencv(problem, PnpSolver::Sqpnp, None)?.pose,
            };
            register_direct(problem, &init, opts)
        }
    }
}

/// The centroid of the model landmarks (a natural centre for pose perturbations).
pub fn model_centroid(problem: &RegistrationProblem) -> DVec3 {
    let n = problem.model_points.len().max(1) as f64;
    problem.model_points.iter().fold(DVec3::ZERO, |a, &p| a + p) / n
}
