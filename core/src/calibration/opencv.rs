//! OpenCV's calibration: `calibrateCamera` (Zhang's method for a plate; with `CALIB_USE_INTRINSIC_GUESS`
//! for 3-D BBs) and `decomposeProjectionMatrix`, the independent references of our DLT + LM.
//!
//! Free parameters: fx, fy, cx, cy and each image's pose. Fixed: the skew (OpenCV's pinhole model has
//! none — K[0][1] is 0 in every result, although our K may carry a skew), and all lens distortion
//! (`CALIB_FIX_K1..K6`, `CALIB_ZERO_TANGENT_DIST`: a flat-panel detector has none). OpenCV converts the
//! points to `f32` internally, which is why phantoms hold `f32`-exact BB centres.

use glam::{DVec2, DVec3};
use opencv::core::{Mat, Point2f, Point3f, Size, TermCriteria, Vector};
use opencv::prelude::*;

use super::acquisition::CalibrationImage;
use super::bundle::Geometry;
use crate::geometry::{Intrinsics, RigidTransform, rotation_exp, rotation_log};
use crate::{Error, Result};

fn cv(e: opencv::Error) -> Error {
    Error::from(e)
}

/// OpenCV's LM stops when the parameter step is below this fraction of the parameters (relative L2
/// norm): 1e-12 of fx = 4500 px is 5e-9 px. (Its default, DBL_EPSILON, is never reached by a converged
/// solve, which then runs to the iteration cap.)
const CONVERGED_REL_STEP: f64 = 1e-12;

/// The distortion-free flags.
fn flags() -> i32 {
    use opencv::calib3d::*;
    CALIB_FIX_K1
        | CALIB_FIX_K2
        | CALIB_FIX_K3
        | CALIB_FIX_K4
        | CALIB_FIX_K5
        | CALIB_FIX_K6
        | CALIB_ZERO_TANGENT_DIST
}

fn mat_vec3(m: &Mat) -> Result<DVec3> {
    let mut out = [0.0; 3];
    for (i, o) in out.iter_mut().enumerate() {
        *o = *m.at::<f64>(i as i32).map_err(cv)?;
    }
    Ok(DVec3::from(out))
}

/// OpenCV `calibrateCamera` on the images. Without `guess` the object points must be planar (z = 0):
/// Zhang's closed form starts the optimisation; with `guess` (`CALIB_USE_INTRINSIC_GUESS`, its skew
/// dropped) any BB layout is accepted. Returns K (skew 0), the phantom → camera poses and OpenCV's RMS.
pub fn calibrate_camera(
    images: &[CalibrationImage],
    bbs: &[DVec3],
    width: u32,
    height: u32,
    guess: Option<&Intrinsics>,
) -> Result<(Geometry, f64)> {
    let obj: Vector<Vector<Point3f>> = images
        .iter()
        .map(|im| {
            im.observed
                .iter()
                .map(|&(i, _)| {
                    let p = bbs[i];
                    Point3f::new(p.x as f32, p.y as f32, p.z as f32)
                })
                .collect()
        })
        .collect();
    let img: Vector<Vector<Point2f>> = images
        .iter()
        .map(|im| {
            im.observed
                .iter()
                .map(|&(_, x)| Point2f::new(x.x as f32, x.y as f32))
                .collect()
        })
        .collect();
    let size = Size::new(width as i32, height as i32);
    let mut flags = flags();
    let mut k = match guess {
        Some(g) => {
            flags |= opencv::calib3d::CALIB_USE_INTRINSIC_GUESS;
            Mat::from_slice_2d(&[[g.fx, 0.0, g.cx], [0.0, g.fy, g.cy], [0.0, 0.0, 1.0]])
                .map_err(cv)?
        }
        None => Mat::from_slice_2d(&[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0f64]])
            .map_err(cv)?,
    };
    let mut dist = Mat::from_slice(&[0.0f64; 5])
        .map_err(cv)?
        .try_clone()
        .map_err(cv)?;
    let mut rvecs: Vector<Mat> = Vector::new();
    let mut tvecs: Vector<Mat> = Vector::new();
    let criteria = TermCriteria::new(
        opencv::core::TermCriteria_COUNT + opencv::core::TermCriteria_EPS,
        100,
        CONVERGED_REL_STEP,
    )
    .map_err(cv)?;
    let rms = opencv::calib3d::calibrate_camera(
        &obj, &img, size, &mut k, &mut dist, &mut rvecs, &mut tvecs, flags, criteria,
    )
    .map_err(cv)?;
    let at = |r: i32, c: i32| -> Result<f64> { Ok(*k.at_2d::<f64>(r, c).map_err(cv)?) };
    let intrinsics = Intrinsics {
        fx: at(0, 0)?,
        fy: at(1, 1)?,
        skew: 0.0,
        cx: at(0, 2)?,
        cy: at(1, 2)?,
        width,
        height,
    };
    intrinsics
        .validate()
        .map_err(|e| Error::Numerical(format!("OpenCV calibrateCamera: {e}")))?;
    let mut poses = Vec::with_capacity(images.len());
    for (r, t) in rvecs.iter().zip(tvecs.iter()) {
        poses.push(RigidTransform::new(
            rotation_exp(mat_vec3(&r)?),
            mat_vec3(&t)?,
        ));
    }
    Ok((
        Geometry {
            k: intrinsics,
            poses,
        },
        rms,
    ))
}

/// K (row-major, K[2][2] = 1), R (row-major) and the camera centre (world).
pub type Decomposition = ([[f64; 3]; 3], [[f64; 3]; 3], DVec3);

/// OpenCV `decomposeProjectionMatrix` of `p` (row-major 3×4): K (normalised to K[2][2] = 1), the rotation
/// and the camera centre (world).
pub fn decompose_projection_matrix(p: &[[f64; 4]; 3]) -> Result<Decomposition> {
    let pm = Mat::from_slice_2d(p).map_err(cv)?;
    let (mut k, mut r, mut c) = (Mat::default(), Mat::default(), Mat::default());
    opencv::calib3d::decompose_projection_matrix_def(&pm, &mut k, &mut r, &mut c).map_err(cv)?;
    let get = |m: &Mat, i: i32, j: i32| -> Result<f64> { Ok(*m.at_2d::<f64>(i, j).map_err(cv)?) };
    let mut km = [[0.0; 3]; 3];
    let mut rm = [[0.0; 3]; 3];
    let s = get(&k, 2, 2)?;
    for i in 0..3 {
        for j in 0..3 {
            km[i][j] = get(&k, i as i32, j as i32)? / s;
            rm[i][j] = get(&r, i as i32, j as i32)?;
        }
    }
    let w = get(&c, 3, 0)?;
    let centre = DVec3::new(get(&c, 0, 0)? / w, get(&c, 1, 0)? / w, get(&c, 2, 0)? / w);
    Ok((km, rm, centre))
}

/// The axis-angle vector of a pose's rotation (OpenCV's `rvec`).
pub fn rvec(pose: &RigidTransform) -> DVec3 {
    rotation_log(pose.rotation)
}

/// Rounds pixels to `f32`, the precision OpenCV calibrates with (so both solvers see the same data).
pub fn f32_pixels(images: &[CalibrationImage]) -> Vec<CalibrationImage> {
    images
        .iter()
        .map(|im| CalibrationImage {
            observed: im
                .observed
                .iter()
                .map(|&(i, x)| (i, DVec2::new(f64::from(x.x as f32), f64::from(x.y as f32))))
                .collect(),
            ..im.clone()
        })
        .collect()
}
