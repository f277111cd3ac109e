//! One Monte-Carlo calibration of a C-arm: the phantom imaged in its placements with detection noise,
//! calibrated; the views' estimated geometry; its reconstruction-domain figures (reprojection RMS on the
//! calibration BBs, 3-D error of held-out BBs triangulated from the views).
//!
//! * Estimated extrinsics of a view: for a 3-D phantom (placed in the world frame) the pose its image
//!   estimates; for a plate, the world → camera transform that best reprojects all the BBs of the view's
//!   plate placements (known world positions) with the estimated K (LM over SE(3), started from the
//!   first placement's estimated pose).
//! * Held-out BBs: a 3-D phantom withholds every `holdout_every`-th BB from the fit; a plate is checked
//!   on the BBs of the default helix at the world origin (a 3-D check phantom), as a vendor validates a
//!   plate calibration. Both are detected with the same noise in every view and triangulated with the
//!   estimated geometry.

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

use super::acquisition::{
    CalibrationImage, Detection, check_on_detector, check_sigma, ideal_images, with_noise,
};
use super::phantom::{CalibrationPhantom, PhantomKind, Placement, placements};
use super::{Calibration, calibrate};
use crate::geometry::{CArm, Intrinsics, RigidTransform, View};
use crate::registration::{
    ObservedView, RegistrationOptions, RegistrationProblem, SplitMix64, register_direct,
    triangulate,
};
use crate::{Error, Result};

/// How a calibration is set up.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SetupOptions {
    /// Plate tilt (deg) of every pose.
    pub tilt_deg: f64,
    /// Plate poses per view.
    pub poses_per_view: usize,
    pub detection: Detection,
    /// A 3-D phantom withholds every n-th BB (n ≥ 2) for the held-out check.
    pub holdout_every: usize,
}

impl Default for SetupOptions {
    fn default() -> Self {
        SetupOptions {
            tilt_deg: 30.0,
            poses_per_view: 5,
            detection: Detection::Projected,
            holdout_every: 5,
        }
    }
}

/// The fixed part of a Monte-Carlo calibration: true geometry, phantom, placements, the noise-free
/// detections of the calibration BBs and of the held-out BBs.
#[derive(Debug, Clone)]
pub struct CalibrationSetup {
    pub carm: CArm,
    pub phantom: CalibrationPhantom,
    pub placements: Vec<Placement>,
    /// Phantom BBs used by the fit.
    pub fit_bbs: Vec<usize>,
    /// Noise-free detections of the fit BBs, one image per placement.
    pub ideal: Vec<CalibrationImage>,
    /// Held-out BBs (world mm).
    pub heldout_world: Vec<DVec3>,
    /// Their noise-free image positions, per view of `carm` (view order).
    pub heldout_ideal: Vec<Vec<DVec2>>,
    pub options: SetupOptions,
}

impl CalibrationSetup {
    /// Places the phantom, checks every BB lands on the detector, and measures the noise-free
    /// detections.
    pub fn new(carm: &CArm, phantom: &CalibrationPhantom, options: SetupOptions) -> Result<Self> {
        let k0 = carm.views[0].intrinsics;
        if carm.views.iter().any(|v| v.intrinsics != k0) {
            return Err(Error::invalid(
                "geometry",
                "the calibration estimates one K: every view must share the detector's intrinsics",
            ));
        }
        let placements = placements(carm, phantom, options.tilt_deg, options.poses_per_view)?;
        let all: Vec<usize> = (0..phantom.bbs_mm.len()).collect();
        let (fit_bbs, heldout_world) = match phantom.kind {
            PhantomKind::Planar => (all, CalibrationPhantom::default_helix().points()),
            PhantomKind::Volumetric => {
                let n = options.holdout_every;
                if n < 2 {
                    return Err(Error::invalid(
                        "holdout_every",
                        format!("must be at least 2, got {n}"),
                    ));
                }
                let pts = phantom.points();
                let fit: Vec<usize> = all.iter().copied().filter(|i| i % n != n - 1).collect();
                let held = all
                    .iter()
                    .filter(|i| *i % n == n - 1)
                    .map(|&i| pts[i])
                    .collect();
                (fit, held)
            }
        };
        let ideal = ideal_images(carm, phantom, &placements, &fit_bbs, options.detection)?;
        let heldout_ideal = carm
            .views
            .iter()
            .map(|v| {
                heldout_world
                    .iter()
                    .enumerate()
                    .map(|(i, p)| check_on_detector(v, *p, &format!("held-out BB {i}")))
                    .collect::<Result<Vec<_>>>()
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(CalibrationSetup {
            carm: carm.clone(),
            phantom: phantom.clone(),
            placements,
            fit_bbs,
            ideal,
            heldout_world,
            heldout_ideal,
            options,
        })
    }

    /// Number of unknowns of this calibration (for the residual-count check and the RMS noise floor).
    pub fn unknowns(&self) -> usize {
        let skew = match self.phantom.kind {
            PhantomKind::Planar => super::Skew::Fixed,
            PhantomKind::Volumetric => super::Skew::Free,
        };
        super::bundle::unknowns(skew, self.ideal.len())
    }

    /// Number of residuals.
    pub fn residuals(&self) -> usize {
        super::bundle::residual_count(&self.ideal)
    }

    /// The expected RMS of a least-squares fit at noise σ: `σ √(1 − p/n)`.
    pub fn rms_floor(&self, sigma_px: f64) -> f64 {
        sigma_px * (1.0 - self.unknowns() as f64 / self.residuals() as f64).sqrt()
    }
}

/// One calibration's outcome.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialResult {
    pub calibration: Calibration,
    /// The estimated views: `K_est` with each view's estimated extrinsics (names as in the C-arm).
    pub views: Vec<View>,
    /// The same views with `K_est` and the true extrinsics (protocol a).
    pub intrinsic_only: Vec<View>,
    /// Mean 3-D distance (mm) of the held-out BBs triangulated with the estimated views from their truth.
    pub heldout_err_mm: f64,
}

impl TrialResult {
    pub fn k(&self) -> Intrinsics {
        self.calibration.geometry.k
    }
}

/// Runs one calibration at noise `sigma_px` with seed `seed`.
pub fn run_trial(setup: &CalibrationSetup, sigma_px: f64, seed: u64) -> Result<TrialResult> {
    check_sigma(sigma_px)?;
    let images = with_noise(&setup.ideal, sigma_px, seed);
    let k0 = setup.carm.views[0].intrinsics;
    let bbs = setup.phantom.points();
    let calibration = calibrate(setup.phantom.kind, &images, &bbs, k0.width, k0.height)?;
    let k = calibration.geometry.k;
    let mut views = Vec::with_capacity(setup.carm.views.len());
    for v in &setup.carm.views {
        let w2c = estimated_extrinsics(setup, &images, &calibration, &v.name, &bbs)?;
        views.push(View::new(v.name.clone(), k, w2c));
    }
    let intrinsic_only = setup
        .carm
        .views
        .iter()
        .map(|v| View::new(v.name.clone(), k, v.world_to_camera))
        .collect();
    // Held-out BBs: their own noise stream (a different seed family from the calibration images).
    let mut rng = SplitMix64::new(seed ^ 0x05ee_d0f4_e1d0_u64);
    let noisy: Vec<Vec<DVec2>> = setup
        .heldout_ideal
        .iter()
        .map(|xs| {
            xs.iter()
                .map(|x| *x + DVec2::new(rng.normal(), rng.normal()) * sigma_px)
                .collect()
        })
        .collect();
    let heldout_err_mm = if views.len() >= 2 {
        let mut sum = 0.0;
        for (i, truth) in setup.heldout_world.iter().enumerate() {
            let obs: Vec<(&View, DVec2)> =
                views.iter().zip(&noisy).map(|(v, xs)| (v, xs[i])).collect();
            sum += (triangulate(&obs)? - *truth).length();
        }
        sum / setup.heldout_world.len().max(1) as f64
    } else {
        f64::NAN
    };
    Ok(TrialResult {
        calibration,
        views,
        intrinsic_only,
        heldout_err_mm,
    })
}

/// The estimated world → camera transform of view `name`.
fn estimated_extrinsics(
    setup: &CalibrationSetup,
    images: &[CalibrationImage],
    cal: &Calibration,
    name: &str,
    bbs: &[DVec3],
) -> Result<RigidTransform> {
    let idx: Vec<usize> = (0..images.len())
        .filter(|&j| images[j].view == name)
        .collect();
    let first = *idx
        .first()
        .ok_or_else(|| Error::Internal(format!("no calibration image of view '{name}'")))?;
    let start = cal.geometry.poses[first].compose(&images[first].phantom_to_world.inverse());
    if setup.phantom.kind == PhantomKind::Volumetric && idx.len() == 1 {
        return Ok(start);
    }
    // All BBs of the view's placements in world coordinates, registered with the estimated K.
    let mut model_points = Vec::new();
    let mut observed = Vec::new();
    for &j in &idx {
        for &(i, x) in &images[j].observed {
            observed.push((model_points.len(), x));
            model_points.push(images[j].phantom_to_world.apply(bbs[i]));
        }
    }
    let problem = RegistrationProblem {
        names: (0..model_points.len()).map(|i| format!("bb{i}")).collect(),
        model_points,
        views: vec![ObservedView {
            view: View::new(name, cal.geometry.k, RigidTransform::IDENTITY),
            observed,
        }],
    };
    let opts = RegistrationOptions {
        init: Some(start),
        ..RegistrationOptions::default()
    };
    Ok(register_direct(&problem, &start, &opts)?.pose)
}
