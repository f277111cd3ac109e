//! The independent reference: OpenCV `solvePnP` (ITERATIVE, SQPNP) and `projectPoints`.
//!
//! OpenCV estimates the model → camera transform; the model → world pose is `T_view⁻¹ ∘ T_cam`.
//! OpenCV's pinhole model has no skew term, so views with skew are refused rather than silently
//! mis-modelled.

use glam::{DVec2, DVec3};
use spinedrr_cv::PnpMethod;

use super::{RegistrationProblem, RegistrationResult, mean_residual_px};
use crate::geometry::{RigidTransform, View, rotation_exp, rotation_log};
use crate::{Error, Result};

/// Which OpenCV PnP solver to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PnpSolver {
    /// `SOLVEPNP_ITERATIVE` (Levenberg–Marquardt; uses the initial pose as an extrinsic guess when given).
    Iterative,
    /// `SOLVEPNP_SQPNP` (Terzakis & Lourakis 2020, globally optimal; ignores any guess).
    Sqpnp,
}

fn camera_matrix(view: &View) -> Result<[[f64; 3]; 3]> {
    let k = &view.intrinsics;
    if k.skew != 0.0 {
        return Err(Error::invalid(
            format!("view '{}' K[0][1]", view.name),
            "OpenCV's pinhole model has no skew; the opencv method needs skew = 0",
        ));
    }
    Ok(k.matrix_rows())
}

/// OpenCV's form of a pose: the axis-angle rotation `rvec` and the translation `tvec`.
fn rvec_tvec(pose: &RigidTransform) -> ([f64; 3], [f64; 3]) {
    (
        rotation_log(pose.rotation).to_array(),
        pose.translation.to_array(),
    )
}

/// The pose of OpenCV's `(rvec, tvec)`.
pub(crate) fn pose_of_rvec_tvec((rvec, tvec): ([f64; 3], [f64; 3])) -> RigidTransform {
    RigidTransform::new(rotation_exp(DVec3::from(rvec)), DVec3::from(tvec))
}

/// OpenCV `projectPoints` of world points through `view` (no distortion): the cross-check of
/// [`View::project`].
pub fn opencv_project_points(view: &View, world: &[DVec3]) -> Result<Vec<DVec2>> {
    let k = camera_matrix(view)?;
    let pts: Vec<[f64; 3]> = world.iter().map(|p| p.to_array()).collect();
    let (rvec, tvec) = rvec_tvec(&view.world_to_camera);
    let out = spinedrr_cv::project_points(&pts, rvec, tvec, k).map_err(Error::opencv)?;
    Ok(out.into_iter().map(DVec2::from).collect())
}

/// Single-view pose by OpenCV `solvePnP`.
pub fn register_opencv(
    problem: &RegistrationProblem,
    solver: PnpSolver,
    init: Option<&RigidTransform>,
) -> Result<RegistrationResult> {
    let [ov] = problem.views.as_slice() else {
        return Err(Error::invalid(
            "method",
            format!(
                "the opencv method is single-view, the problem has {} views (select one with --view)",
                problem.views.len()
            ),
        ));
    };
    let k = camera_matrix(&ov.view)?;
    let obj: Vec<[f64; 3]> = ov
        .observed
        .iter()
        .map(|&(i, _)| problem.model_points[i].to_array())
        .collect();
    let img: Vec<[f64; 2]> = ov.observed.iter().map(|&(_, x)| x.to_array()).collect();
    let w2c = ov.view.world_to_camera;
    let (guess, method) = match (solver, init) {
        (PnpSolver::Iterative, Some(t)) => (Some(w2c.compose(t)), PnpMethod::Iterative),
        (PnpSolver::Iterative, None) => (None, PnpMethod::Iterative),
        (PnpSolver::Sqpnp, _) => (None, PnpMethod::Sqpnp),
    };
    let guess = guess.as_ref().map(rvec_tvec);
    let Some(found) =
        spinedrr_cv::solve_pnp(&obj, &img, k, method, guess).map_err(Error::opencv)?
    else {
        return Err(Error::opencv("solvePnP found no solution".into()));
    };
    let cam = pose_of_rvec_tvec(found);
    let pose = w2c.inverse().compose(&cam);
    Ok(RegistrationResult {
        pose,
        residual_px: mean_residual_px(problem, &pose),
        iterations: 0,
        converged: true,
    })
}
