//! The calibration experiment: per (phantom, σ) Monte-Carlo calibrations of the study's C-arm
//! ([`crate::calibration`]), each seen through the protocols — (a) `K_est` with the true extrinsics, (b)
//! the full estimated geometry — on the study's calibration target.
//!
//! Per trial and protocol: the landmark shifts (exact projections of the target's 3-D landmarks through
//! the true and the estimated view, `View::project`), the homography law's residual (protocol a), and a
//! landmark registration (direct LM over AP + LAT from the true landmark projections, with the estimated
//! geometry). Per view and for the first `silhouette_trials` trials: the target's silhouette rendered
//! with the estimated geometry against the true one (Dice, mean Chamfer, HD95).

use glam::{DVec2, DVec3};

use super::calibration_intensity::{IntensityBench, IntensityError, surface_targets};
use super::{Context, Target};
use crate::analysis::{Landmark, LandmarkShift, MaskPair, landmark_shifts, silhouette_metrics};
use crate::calibration::{CalibrationSetup, TrialResult, run_trial};
use crate::geometry::{CArm, RigidTransform, View};
use crate::registration::intensity::mtre_mm;
use crate::registration::{
    Method, ObservedView, RegistrationOptions, RegistrationProblem, pose_errors, register,
};
use crate::render::{ThicknessDrr, ThicknessOptions};
use crate::study::config::{CalibrationCell, CalibrationSection, Protocol};
use crate::study::schema::{CalibrationRow, UnitRows};
use crate::study::timings::Phase;
use crate::study::units::derive_seed;
use crate::{Error, Result};

/// The target the calibration experiment measures: `calibration.target`, else the study's first.
pub fn calibration_target(ctx: &Context) -> Result<&Target> {
    match &ctx.cfg.calibration.target {
        Some(name) => ctx.target(name),
        None => ctx
            .targets
            .first()
            .ok_or_else(|| Error::invalid("calibration.target", "the study has no target")),
    }
}

/// The calibration target's landmarks as the analysis takes them.
pub(super) fn target_landmarks(t: &Target) -> Vec<Landmark> {
    t.landmarks
        .iter()
        .map(|(name, p)| Landmark {
            name: name.clone(),
            position: *p,
        })
        .collect()
}

/// The mean and the largest of the landmark shifts `s` (px; 0 without any).
pub(super) fn shift_mean_max(s: &[LandmarkShift]) -> (f64, f64) {
    let n = s.len().max(1) as f64;
    (
        s.iter().map(|x| x.shift_px).sum::<f64>() / n,
        s.iter().map(|x| x.shift_px).fold(0.0, f64::max),
    )
}

/// The study's views (those of `geometry.views`) as a C-arm.
pub(super) fn study_carm(ctx: &Context) -> Result<CArm> {
    let views = ctx
        .cfg
        .geometry
        .views
        .iter()
        .map(|v| ctx.carm.view(v).cloned())
        .collect::<Result<Vec<View>>>()?;
    Ok(CArm { views })
}

/// Runs trials `cell.first..cell.first + cell.count` of one (phantom, σ).
pub fn run(ctx: &Context, cell: &CalibrationCell) -> Result<UnitRows> {
    let c = &ctx.cfg.calibration;
    let carm = study_carm(ctx)?;
    let phantom = CalibrationSection::phantom(&cell.phantom)?;
    let setup = CalibrationSetup::new(&carm, &phantom, c.setup_options())
        .map_err(|e| Error::invalid("calibration.phantoms", format!("'{}': {e}", cell.phantom)))?;
    let t = calibration_target(ctx)?;
    let landmarks = target_landmarks(t);
    let needs_silhouettes = cell.first < c.silhouette_trials;
    let targets = surface_targets(t);
    let mut intensity = if cell.first < c.intensity_trials {
        Some(ctx.timings.time(Phase::Scene, 1, || {
            IntensityBench::new(t, &carm, targets.clone())
        })?)
    } else {
        None
    };
    let references = if needs_silhouettes {
        carm.views
            .iter()
            .map(|v| render(ctx, t, v))
            .collect::<Result<Vec<_>>>()?
    } else {
        Vec::new()
    };
    let mut rows = UnitRows::default();
    for trial in cell.first..cell.first + cell.count {
        let seed = derive_seed(ctx.cfg.seed, &cell.seed_key(), trial as u64);
        let r = ctx.timings.time(Phase::Calibration, 1, || {
            run_trial(&setup, cell.noise_px, seed)
        })?;
        for &protocol in &c.protocols {
            let views = match protocol {
                Protocol::Intrinsic => &r.intrinsic_only,
                Protocol::Full => &r.views,
            };
            let reg = ctx.timings.time(Phase::Registration, 1, || {
                registration(&carm, views, &landmarks, &targets)
            });
            let ireg = match intensity.as_mut() {
                Some(bench) if trial < c.intensity_trials => {
                    ctx.timings
                        .time(Phase::Registration, 1, || bench.register(views))
                }
                _ => (f64::NAN, f64::NAN, f64::NAN),
            };
            for (truth, est) in carm.views.iter().zip(views) {
                let shifts = landmark_shifts(truth, est, &landmarks);
                let (shift_mean, shift_max) = shift_mean_max(&shifts);
                let homography = match protocol {
                    Protocol::Intrinsic => shifts
                        .iter()
                        .map(|s| {
                            (DVec2::from(s.perturbed_px) - DVec2::from(s.predicted_px)).length()
                        })
                        .fold(0.0, f64::max),
                    Protocol::Full => f64::NAN,
                };
                let (dice, chamfer, hd95) = if trial < c.silhouette_trials {
                    let i = carm
                        .views
                        .iter()
                        .position(|v| v.name == truth.name)
                        .unwrap_or(0);
                    silhouettes(ctx, t, est, &references[i])?
                } else {
                    (f64::NAN, f64::NAN, f64::NAN)
                };
                rows.calibration.push(row(
                    cell,
                    trial,
                    protocol,
                    truth,
                    &r,
                    RowMetrics {
                        shift_mean,
                        shift_max,
                        homography,
                        dice,
                        chamfer,
                        hd95,
                        reg,
                        ireg,
                    },
                ));
            }
        }
    }
    Ok(rows)
}

struct RowMetrics {
    shift_mean: f64,
    shift_max: f64,
    homography: f64,
    dice: f64,
    chamfer: f64,
    hd95: f64,
    /// Landmark registration: (rotation error deg, translation error mm, mTRE mm).
    reg: (f64, f64, f64),
    /// Intensity registration: (mTRE mm, rotation error deg, translation error mm).
    ireg: IntensityError,
}

fn row(
    cell: &CalibrationCell,
    trial: usize,
    protocol: Protocol,
    truth: &View,
    r: &TrialResult,
    m: RowMetrics,
) -> CalibrationRow {
    let (k, k0) = (r.k(), truth.intrinsics);
    CalibrationRow {
        phantom: cell.phantom.clone(),
        noise_px: cell.noise_px,
        trial,
        protocol,
        view: truth.name.clone(),
        fx: k.fx,
        fy: k.fy,
        cx: k.cx,
        cy: k.cy,
        skew: k.skew,
        dfx_px: k.fx - k0.fx,
        dfy_px: k.fy - k0.fy,
        dcx_px: k.cx - k0.cx,
        dcy_px: k.cy - k0.cy,
        dskew_px: k.skew - k0.skew,
        reprojection_rms_px: r.calibration.rms_px,
        heldout_err_mm: r.heldout_err_mm,
        landmark_shift_mean_px: m.shift_mean,
        landmark_shift_max_px: m.shift_max,
        homography_residual_max_px: m.homography,
        dice: m.dice,
        chamfer_mean_px: m.chamfer,
        hd95_px: m.hd95,
        reg_rot_err_deg: m.reg.0,
        reg_trans_err_mm: m.reg.1,
        reg_mtre_mm: m.reg.2,
        ireg_mtre_mm: m.ireg.0,
        ireg_rot_err_deg: m.ireg.1,
        ireg_trans_err_mm: m.ireg.2,
    }
}

/// Registers the target's landmarks (seen exactly through the true views) with `views`: direct LM over
/// every view from the Kabsch start; (rotation error deg, translation error mm, mTRE mm over `targets`)
/// of the pose, whose truth is the identity. NaN when the solve fails.
pub(super) fn registration(
    carm: &CArm,
    views: &[View],
    landmarks: &[Landmark],
    targets: &[DVec3],
) -> (f64, f64, f64) {
    let problem = RegistrationProblem {
        names: landmarks.iter().map(|l| l.name.clone()).collect(),
        model_points: landmarks.iter().map(|l| l.position).collect(),
        views: carm
            .views
            .iter()
            .zip(views)
            .map(|(truth, est)| ObservedView {
                view: est.clone(),
                observed: landmarks
                    .iter()
                    .enumerate()
                    .map(|(i, l)| (i, truth.project(l.position)))
                    .collect(),
            })
            .collect(),
    };
    match register(&problem, Method::Direct, &RegistrationOptions::default()) {
        Ok(r) => {
            let e = pose_errors(&r.pose, &RigidTransform::IDENTITY);
            (
                e.rot_err_deg,
                e.trans_err_mm,
                mtre_mm(&r.pose, &RigidTransform::IDENTITY, targets),
            )
        }
        Err(_) => (f64::NAN, f64::NAN, f64::NAN),
    }
}

fn render(ctx: &Context, t: &Target, view: &View) -> Result<ThicknessDrr> {
    ctx.timings.time(Phase::RenderTarget, 1, || {
        t.renderer.render(view, &ThicknessOptions::with_masks())
    })
}

/// (Dice, mean Chamfer, HD95) of the target's silhouette in `est` against `reference`. A calibration
/// poor enough to move the whole target off the detector leaves no silhouette: Dice 0 (nothing
/// overlaps) and no contour distance (NaN); with no reference silhouette nothing is measured (NaN).
fn silhouettes(
    ctx: &Context,
    t: &Target,
    est: &View,
    reference: &ThicknessDrr,
) -> Result<(f64, f64, f64)> {
    let b = render(ctx, t, est)?;
    let k = est.intrinsics;
    let pair = MaskPair {
        name: t.name.clone(),
        width: k.width,
        height: k.height,
        reference: reference.masks()?.union(),
        perturbed: b.masks()?.union(),
    };
    match (
        pair.reference.iter().any(|&x| x),
        pair.perturbed.iter().any(|&x| x),
    ) {
        (false, _) => return Ok((f64::NAN, f64::NAN, f64::NAN)),
        (true, false) => return Ok((0.0, f64::NAN, f64::NAN)),
        (true, true) => {}
    }
    let s = ctx
        .timings
        .time(Phase::Metrics, 1, || silhouette_metrics(&pair))?;
    Ok((s.dice, s.chamfer_mean_px, s.hd95_px))
}
