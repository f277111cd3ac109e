//! Calibration in the loop on a C-arm displaced by a physical error (`[calibration.physical]`, table
//! `calibration_physical.csv`): the C-arm's focal spot or detector differs from its nominal geometry by
//! one key; the phantom is imaged and calibrated on that displaced C-arm, and the anatomy is imaged by it
//! too. Per trial and protocol the anatomy is projected and registered with the calibration's geometry:
//! `full` — the estimated K and poses, which can absorb the whole error; `intrinsic` — the estimated K
//! with the **nominal** poses (a tracker or a mechanical model that does not know of the error), which
//! absorbs only what the error does to K. Beside each, the nominal geometry used uncalibrated: the error's
//! own effect. A trial draws the same detection noise as the nominal C-arm's trial of the same index.

use super::Context;
use super::calibration::{
    calibration_target, registration, shift_mean_max, study_carm, target_landmarks,
};
use super::calibration_intensity::surface_targets;
use crate::analysis::landmark_shifts;
use crate::calibration::{CalibrationSetup, run_trial};
use crate::geometry::{CArm, Perturbation, View};
use crate::study::config::{CalibrationCell, CalibrationSection, Protocol, physical_cell_key};
use crate::study::schema::{CalibrationPhysicalRow, UnitRows};
use crate::study::timings::Phase;
use crate::study::units::derive_seed;
use crate::{Error, Result};

/// Runs trials `cell.first..cell.first + cell.count` of one (phantom, σ) on the C-arm displaced by `q`.
pub fn run(ctx: &Context, cell: &CalibrationCell, q: &Perturbation) -> Result<UnitRows> {
    let c = &ctx.cfg.calibration;
    let (key, value) = physical_cell_key(q).ok_or_else(|| {
        Error::invalid(
            "calibration.physical",
            format!("{q} is not one physical key alone"),
        )
    })?;
    let nominal = study_carm(ctx)?;
    let displaced = CArm {
        views: nominal
            .views
            .iter()
            .map(|v| v.perturbed(q))
            .collect::<Result<Vec<View>>>()?,
    };
    let phantom = CalibrationSection::phantom(&cell.phantom)?;
    let setup = CalibrationSetup::new(&displaced, &phantom, c.setup_options()).map_err(|e| {
        Error::invalid(
            "calibration.phantoms",
            format!("'{}' on the C-arm displaced by {q}: {e}", cell.phantom),
        )
    })?;
    let t = calibration_target(ctx)?;
    let landmarks = target_landmarks(t);
    let targets = surface_targets(t);
    // The nominal geometry used uncalibrated on the displaced C-arm: per view its largest landmark
    // shift, and the registration with it (the same for every trial).
    let uncalibrated_shift: Vec<f64> = displaced
        .views
        .iter()
        .zip(&nominal.views)
        .map(|(truth, nom)| shift_mean_max(&landmark_shifts(truth, nom, &landmarks)).1)
        .collect();
    let uncalibrated = registration(&displaced, &nominal.views, &landmarks, &targets).2;
    let mut rows = UnitRows::default();
    for trial in cell.first..cell.first + cell.count {
        let seed = derive_seed(ctx.cfg.seed, &cell.seed_key(), trial as u64);
        let r = ctx.timings.time(Phase::Calibration, 1, || {
            run_trial(&setup, cell.noise_px, seed)
        })?;
        for &protocol in &c.protocols {
            let views: Vec<View> = match protocol {
                Protocol::Full => r.views.clone(),
                // The estimated K with the nominal poses.
                Protocol::Intrinsic => nominal
                    .views
                    .iter()
                    .map(|v| View {
                        intrinsics: r.k(),
                        ..v.clone()
                    })
                    .collect(),
            };
            let reg = ctx.timings.time(Phase::Registration, 1, || {
                registration(&displaced, &views, &landmarks, &targets)
            });
            for ((truth, used), &uncalibrated_shift) in
                displaced.views.iter().zip(&views).zip(&uncalibrated_shift)
            {
                let (mean, max) = shift_mean_max(&landmark_shifts(truth, used, &landmarks));
                rows.calibration_physical.push(CalibrationPhysicalRow {
                    phantom: cell.phantom.clone(),
                    noise_px: cell.noise_px,
                    key: key.to_string(),
                    value,
                    trial,
                    protocol,
                    view: truth.name.clone(),
                    reprojection_rms_px: r.calibration.rms_px,
                    landmark_shift_mean_px: mean,
                    landmark_shift_max_px: max,
                    reg_rot_err_deg: reg.0,
                    reg_trans_err_mm: reg.1,
                    reg_mtre_mm: reg.2,
                    uncalibrated_shift_max_px: uncalibrated_shift,
                    uncalibrated_mtre_mm: uncalibrated,
                });
            }
        }
    }
    Ok(rows)
}
