//! OpenCV's calibration: `calibrateCamera` (Zhang's method for a plate; with `CALIB_USE_INTRINSIC_GUESS`
//! for 3-D BBs) and `decomposeProjectionMatrix`, the independent references of our DLT + LM.
//!
//! Free parameters: fx, fy, cx, cy and each image's pose. Fixed: the skew (OpenCV's pinhole model has
//! none — K[0][1] is 0 in every result, although our K may carry a skew), and all lens distortion
//! (`CALIB_FIX_K1..K6`, `CALIB_ZERO_TANGENT_DIST`: a flat-panel detector has none). OpenCV converts the
//! points to `f32` internally, which is why phantoms hold `f32`-exact BB centres.

use glam::{DVec2, DVec3};

use super::acquisition::CalibrationImage;
use super::bundle::Geometry;
use crate::geometry::{Intrinsics, RigidTransform, rotation_log};
use crate::registration::pose_of_rvec_tvec;
use crate::{Error, Result};

/// OpenCV's LM stops when the parameter step is below this fraction of the parameters (relative L2
/// norm): 1e-12 of fx = 4500 px is 5e-9 px. (Its default, DBL_EPSILON, is never reached by a converged
/// solve, which then runs to the iteration cap.)
const CONVERGED_REL_STEP: f64 = 1e-12;

/// The iteration cap of OpenCV's LM.
const MAX_ITERATIONS: u32 = 100;

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
    let points: Vec<Vec<([f32; 3], [f32; 2])>> = images
        .iter()
        .map(|im| {
            im.observed
                .iter()
                .map(|&(i, x)| (bbs[i].as_vec3().to_array(), x.as_vec2().to_array()))
                .collect()
        })
        .collect();
    let guess = guess.map(|g| [[g.fx, 0.0, g.cx], [0.0, g.fy, g.cy], [0.0, 0.0, 1.0]]);
    let cal = spinedrr_cv::calibrate_camera(
        &points,
        width,
        height,
        guess,
        MAX_ITERATIONS,
        CONVERGED_REL_STEP,
    )
    .map_err(Error::opencv)?;
    let k = cal.k;
    let intrinsics = Intrinsics {
        fx: k[0][0],
        fy: k[1][1],
        skew: 0.0,
        cx: k[0][2],
        cy: k[1][2],
        width,
        height,
    };
    intrinsics
        .validate()
        .map_err(|e| Error::Numerical(format!("OpenCV calibrateCamera: {e}")))?;
    let poses = cal.poses.iter().map(|&rt| pose_of_rvec_tvec(rt)).collect();
    Ok((
        Geometry {
            k: intrinsics,
            poses,
        },
        cal.rms,
    ))
}

/// K (row-major, K[2][2] = 1), R (row-major) and the camera centre (world).
pub type Decomposition = ([[f64; 3]; 3], [[f64; 3]; 3], DVec3);

/// OpenCV `decomposeProjectionMatrix` of `p` (row-major 3×4): K (normalised to K[2][2] = 1), the rotation
/// and the camera centre (world).
pub fn decompose_projection_matrix(p: &[[f64; 4]; 3]) -> Result<Decomposition> {
    let (k, r, c) = spinedrr_cv::decompose_projection_matrix(p).map_err(Error::opencv)?;
    let s = k[2][2];
    let km = k.map(|row| row.map(|x| x / s));
    let centre = DVec3::new(c[0], c[1], c[2]) / c[3];
    Ok((km, r, centre))
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
