//! One registration as `spinedrr register` (and Python's `register`) runs it on a problem file: select
//! views, add pixel noise, start from the truth perturbed when asked, solve, and the `R.json` record.

use glam::DVec3;
use serde_json::{Value, json};

use super::{
    LoadedProblem, Method, RegistrationOptions, RegistrationProblem, RegistrationResult,
    add_pixel_noise, model_centroid, perturb_pose, pose_errors, register,
};
use crate::geometry::{RigidTransform, rotation_exp};
use crate::{Error, Result};

/// The options of a registration run besides the problem.
#[derive(Debug, Clone)]
pub struct RegisterRequest {
    /// `direct | kabsch | opencv | opencv-sqpnp` (as [`Method::parse`] reads it).
    pub method: String,
    /// Use only these views (empty: all views of the problem).
    pub views: Vec<String>,
    /// Standard deviation (px) of Gaussian noise added to every observation.
    pub noise_px: f64,
    /// Seed of the noise and of the initial-pose perturbation.
    pub seed: u64,
    /// Start from the truth rotated by this angle (deg) about a random axis (needs the truth).
    pub init_rot_deg: Option<f64>,
    /// Start from the truth translated by this distance (mm) in a random direction (needs the truth).
    pub init_trans_mm: Option<f64>,
    /// Iteration cap of the direct solver.
    pub max_iterations: usize,
}

/// What a run produced: the solver's result and the `R.json` record (`R`, `t`, `residual_px`,
/// `iterations`, `converged`, `method`, `views`, `implausible` (why a pose the solver stopped at cannot
/// be the anatomy; `converged` is then false), and `rot_err_deg`, `trans_err_mm` when the truth is
/// known).
#[derive(Debug, Clone)]
pub struct RegisterOutcome {
    pub result: RegistrationResult,
    pub record: Value,
}

/// A clearly better fit than `result` reached from `result`'s pose turned 180° about one of the first
/// view's camera axes through the landmarks' centroid: `result` is then a flipped local minimum (a
/// single view from a start turned ~175°: the vertebra upside down in front of the source, at the right
/// scale, residual tens of px), which the plausibility checks cannot tell from a calibration error's
/// residual. Says which turn and both residuals. Only for the iterative solvers (Kabsch is closed-form).
fn better_flip(
    problem: &RegistrationProblem,
    method: Method,
    result: &RegistrationResult,
    opts: &RegistrationOptions,
) -> Option<String> {
    if matches!(method, Method::Kabsch) {
        return None;
    }
    let view = &problem.views.first()?.view;
    let to_world = view.world_to_camera.inverse();
    let centre = result.pose.apply(model_centroid(problem));
    for (name, axis) in [("u", DVec3::X), ("v", DVec3::Y), ("central-ray", DVec3::Z)] {
        let turn = rotation_exp(to_world.apply_vector(axis) * std::f64::consts::PI);
        let start = RigidTransform::new(
            turn * result.pose.rotation,
            turn * (result.pose.translation - centre) + centre,
        );
        let Ok(r) = register(
            problem,
            method,
            &RegistrationOptions {
                init: Some(start),
                ..*opts
            },
        ) else {
            continue;
        };
        // Clearly better: half the residual and at least 1 px less (a tie within noise is no flip).
        if r.converged
            && problem.implausible(&r.pose).is_none()
            && r.residual_px < 0.5 * result.residual_px
            && result.residual_px - r.residual_px > 1.0
        {
            return Some(format!(
                "a local minimum: the pose turned 180° about view '{}''s {name} axis fits the landmarks \
                 with a mean residual of {:.2} px against this pose's {:.2} px (a flipped solution)",
                view.name, r.residual_px, result.residual_px
            ));
        }
    }
    None
}

/// Runs `req` on `loaded`.
pub fn run_request(loaded: LoadedProblem, req: &RegisterRequest) -> Result<RegisterOutcome> {
    let method = Method::parse(&req.method)?;
    let mut problem = loaded.problem;
    if !req.views.is_empty() {
        problem = problem.select_views(&req.views)?;
    }
    if !(req.noise_px.is_finite() && req.noise_px >= 0.0) {
        return Err(Error::invalid(
            "noise_px",
            format!("must be a non-negative number, got {}", req.noise_px),
        ));
    }
    if req.noise_px > 0.0 {
        problem = add_pixel_noise(&problem, req.noise_px, req.seed);
    }
    let mut init = loaded.init;
    if req.init_rot_deg.is_some() || req.init_trans_mm.is_some() {
        let Some(truth) = loaded.truth else {
            return Err(Error::invalid(
                "init_rot_deg/init_trans_mm",
                "they perturb the truth, but the problem has no \"truth\"",
            ));
        };
        let (deg, mm) = (
            req.init_rot_deg.unwrap_or(0.0),
            req.init_trans_mm.unwrap_or(0.0),
        );
        if !(deg.is_finite() && mm.is_finite()) {
            return Err(Error::invalid(
                "init_rot_deg/init_trans_mm",
                "must be finite",
            ));
        }
        let centre = truth.apply(model_centroid(&problem));
        init = Some(perturb_pose(&truth, deg, mm, centre, req.seed));
    }
    let opts = RegistrationOptions {
        init,
        max_iterations: req.max_iterations,
        ..Default::default()
    };
    let mut result = register(&problem, method, &opts)?;
    // A solver that stopped by its tolerances at a pose that cannot be the observed anatomy (a local
    // minimum: the mirror solution, a run-off along the axis) has not registered.
    let implausible = result
        .converged
        .then(|| {
            problem
                .implausible(&result.pose)
                .or_else(|| better_flip(&problem, method, &result, &opts))
        })
        .flatten();
    result.converged &= implausible.is_none();
    let mut record = json!({
        "R": result.pose.rotation_rows(),
        "t": result.pose.translation.to_array(),
        "residual_px": result.residual_px,
        "iterations": result.iterations,
        "converged": result.converged,
        "method": req.method,
        "views": problem.views.iter().map(|v| v.view.name.clone()).collect::<Vec<_>>(),
        "tool": crate::io::TOOL,
        "kind": crate::io::kind::REGISTRATION,
    });
    if let Some(why) = implausible {
        record["implausible"] = json!(why);
    }
    if let Some(truth) = loaded.truth {
        let e = pose_errors(&result.pose, &truth);
        record["rot_err_deg"] = json!(e.rot_err_deg);
        record["trans_err_mm"] = json!(e.trans_err_mm);
    }
    Ok(RegisterOutcome { result, record })
}
