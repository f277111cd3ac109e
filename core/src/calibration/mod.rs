//! Calibration in the loop: a simulated C-arm calibration whose errors feed the projection-domain
//! analysis.
//!
//! * [`phantom`]: calibration phantoms — a planar BB plate imaged in several tilted poses, a 3-D BB
//!   helix seen in one image per view, or a user's BB centres from JSON — and their placements.
//! * [`acquisition`]: BB image positions through the true geometry (`View::project`, or the blob
//!   centroid of rendered BB spheres) plus seeded Gaussian detection noise.
//! * Estimation: a plate by Zhang's method — our closed form ([`zhang`]) refined by OpenCV
//!   `calibrateCamera` ([`opencv`], skew fixed at 0); a 3-D phantom by our
//!   normalised DLT ([`dlt`]) decomposed by RQ, then Levenberg–Marquardt of one K (with skew) and the
//!   poses on the reprojection error ([`bundle`]). OpenCV is the independent reference of the latter.
//! * [`trial`]: one Monte-Carlo calibration — the estimated K, each view's estimated extrinsics, the
//!   reprojection RMS and the 3-D error of held-out BBs triangulated from the views.
//!
//! Stage: after `registration` (it triangulates and registers with it), before `study`.

pub mod acquisition;
pub mod bundle;
pub mod dlt;
pub mod opencv;
pub mod output;
pub mod phantom;
pub mod trial;
pub mod zhang;

use glam::DVec3;

pub use acquisition::{CalibrationImage, Detection};
pub use bundle::{Geometry, Skew};
pub use phantom::{CalibrationPhantom, PhantomKind, Placement};
pub use trial::{CalibrationSetup, SetupOptions, TrialResult, run_trial};

use crate::Result;

/// Which estimator produced a calibration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Estimator {
    /// OpenCV `calibrateCamera` from Zhang's closed form (planar BBs; skew fixed at 0).
    Zhang,
    /// Our normalised DLT + RQ, then LM of one K (skew free) and the poses.
    DltLm,
}

/// A calibration: K, each image's phantom → camera pose, and the RMS reprojection error per coordinate.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    pub geometry: Geometry,
    pub rms_px: f64,
    pub estimator: Estimator,
}

/// Calibrates from `images` of `bbs` on a `width × height` detector: Zhang's method for a planar
/// phantom, DLT + LM (skew free) for a 3-D one.
pub fn calibrate(
    kind: PhantomKind,
    images: &[CalibrationImage],
    bbs: &[DVec3],
    width: u32,
    height: u32,
) -> Result<Calibration> {
    match kind {
        PhantomKind::Planar => {
            // Zhang's closed form, refined by our own LM of K (skew 0, as OpenCV's model has it) and
            // the poses, starts OpenCV's refinement: from there OpenCV converges in a few
            // iterations instead of ~10 from the closed form (each costs it ~0.7 ms on 5 × 100 BBs),
            // and its result is the calibration. Without a usable closed form OpenCV starts itself.
            // Our LM sees the pixels OpenCV sees (f32), so both share one optimum.
            let f32_images = opencv::f32_pixels(images);
            let guess = zhang::initial_geometry(images, bbs, width, height, 0.0)
                .and_then(|g| bundle::refine(&g, &f32_images, bbs, Skew::Fixed, 50).ok())
                .map(|r| r.geometry.k)
                .or_else(|| zhang::closed_form(images, bbs, width, height));
            let (geometry, _) =
                opencv::calibrate_camera(images, bbs, width, height, guess.as_ref())?;
            let rms_px = bundle::rms(&geometry, images, bbs);
            Ok(Calibration {
                geometry,
                rms_px,
                estimator: Estimator::Zhang,
            })
        }
        PhantomKind::Volumetric => {
            let init = dlt_init(images, bbs, width, height)?;
            let r = bundle::refine(&init, images, bbs, Skew::Free, 100)?;
            Ok(Calibration {
                geometry: r.geometry,
                rms_px: r.rms_px,
                estimator: Estimator::DltLm,
            })
        }
    }
}

/// Per image a DLT decomposed by RQ; the shared K starts at the mean of the images' K.
pub fn dlt_init(
    images: &[CalibrationImage],
    bbs: &[DVec3],
    width: u32,
    height: u32,
) -> Result<Geometry> {
    let mut ks = Vec::new();
    let mut poses = Vec::new();
    for im in images {
        let world: Vec<DVec3> = im.observed.iter().map(|&(i, _)| bbs[i]).collect();
        let px: Vec<glam::DVec2> = im.observed.iter().map(|&(_, x)| x).collect();
        let p = dlt::dlt(&world, &px)?;
        let (k, pose) = dlt::decompose(&p, width, height)?;
        ks.push(k);
        poses.push(pose);
    }
    let n = ks.len().max(1) as f64;
    let mean = |f: fn(&crate::geometry::Intrinsics) -> f64| ks.iter().map(f).sum::<f64>() / n;
    let k = crate::geometry::Intrinsics {
        fx: mean(|k| k.fx),
        fy: mean(|k| k.fy),
        skew: mean(|k| k.skew),
        cx: mean(|k| k.cx),
        cy: mean(|k| k.cy),
        width,
        height,
    };
    Ok(Geometry { k, poses })
}
