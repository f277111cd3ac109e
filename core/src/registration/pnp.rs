//! The independent reference: OpenCV `solvePnP` (ITERATIVE, SQPNP) and `projectPoints`.
//!
//! OpenCV estimates the model → camera transform; the model → world pose is `T_view⁻¹ ∘ T_cam`.
//! OpenCV's pinhole model has no skew term, so views with skew are refused rather than silently
//! mis-modelled.

use glam::{DVec2, DVec3};
use opencv::core::{Mat, Point2d, Point3d, Vector};
use opencv::prelude::*;

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

/// Maps an OpenCV error to [`Error::External`].
pub(crate) fn cv_err(e: opencv::Error) -> Error {
    Error::External {
        library: "OpenCV",
        message: e.to_string(),
    }
}

fn camera_matrix(view: &View) -> Result<Mat> {
    let k = &view.intrinsics;
    if k.skew != 0.0 {
        return Err(Error::invalid(
            format!("view '{}' K[0][1]", view.name),
            "OpenCV's pinhole model has no skew; the opencv method needs skew = 0",
        ));
    }
    Mat::from_slice_2d(&k.matrix_rows()).map_err(cv_err)
}

fn vec3_mat(v: DVec3) -> Result<Mat> {
    Mat::from_slice_2d(&[[v.x], [v.y], [v.z]]).map_err(cv_err)
}

fn mat_vec3(m: &Mat) -> Result<DVec3> {
    let mut out = [0.0; 3];
    for (i, o) in out.iter_mut().enumerate() {
        *o = *m.at::<f64>(i as i32).map_err(cv_err)?;
    }
    Ok(DVec3::from(out))
}

/// OpenCV `projectPoints` of world points through `view` (no distortion): the cross-check of
/// [`View::project`].
pub fn opencv_project_points(view: &View, world: &[DVec3]) -> Result<Vec<DVec2>> {
    let k = camera_matrix(view)?;
    let pts: Vector<Point3d> = world.iter().map(|p| Point3d::new(p.x, p.y, p.z)).collect();
    let rvec = vec3_mat(rotation_log(view.world_to_camera.rotation))?;
    let tvec = vec3_mat(view.world_to_camera.translation)?;
    let mut out: Vector<Point2d> = Vector::new();
    opencv::calib3d::project_points_def(&pts, &rvec, &tvec, &k, &Mat::default(), &mut out)
        .map_err(cv_err)?;
    Ok(out.iter().map(|p| DVec2::new(p.x, p.y)).collect())
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
    let obj: Vector<Point3d> = ov
        .observed
        .iter()
        .map(|&(i, _)| {
            let p = problem.model_points[i];
            Point3d::new(p.x, p.y, p.z)
        })
        .collect();
    let img: Vector<Point2d> = ov
        .observed
        .iter()
        .map(|&(_, x)| Point2d::new(x.x, x.y))
        .collect();
    let w2c = ov.view.world_to_camera;
    let (guess, flags) = match (solver, init) {
        (PnpSolver::Iterative, Some(t)) => {
            (Some(w2c.compose(t)), opencv::calib3d::SOLVEPNP_ITERATIVE)
        }
        (PnpSolver::Iterative, None) => (None, opencv::calib3d::SOLVEPNP_ITERATIVE),
        (PnpSolver::Sqpnp, _) => (None, opencv::calib3d::SOLVEPNP_SQPNP),
    };
    let g = guess.unwrap_or(RigidTransform::IDENTITY);
    let mut rvec = vec3_mat(rotation_log(g.rotation))?;
    let mut tvec = vec3_mat(g.translation)?;
    let ok = opencv::calib3d::solve_pnp(
        &obj,
        &img,
        &k,
        &Mat::default(),
        &mut rvec,
        &mut tvec,
        guess.is_some(),
        flags,
    )
    .map_err(cv_err)?;
    if !ok {
        return Err(Error::External {
            library: "OpenCV",
            message: "solvePnP found no solution".into(),
        });
    }
    let cam = RigidTransform::new(rotation_exp(mat_vec3(&rvec)?), mat_vec3(&tvec)?);
    let pose = w2c.inverse().compose(&cam);
    Ok(RegistrationResult {
        pose,
        residual_px: mean_residual_px(problem, &pose),
        iterations: 0,
        converged: true,
    })
}
