//! Tables of the calibration experiment: one row per (phantom, σ, trial, protocol, view)
//! (`calibration.csv`), the tolerance table (`calibration_tolerance.csv`: the σ and the reprojection RMS
//! at which the 95th percentile of the largest landmark shift reaches 0.5, 1 and 2 px), and the
//! ambiguity table (`calibration_ambiguity.csv`: calibrations with the same phantom RMS, within 5%,
//! whose landmark errors differ most).

use serde::{Deserialize, Serialize};

use super::num;
use crate::analysis::percentile;
use crate::study::config::Protocol;

/// One calibration trial seen through one protocol in one view.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationRow {
    pub phantom: String,
    #[serde(with = "num")]
    pub noise_px: f64,
    pub trial: usize,
    pub protocol: Protocol,
    pub view: String,
    #[serde(with = "num")]
    pub fx: f64,
    #[serde(with = "num")]
    pub fy: f64,
    #[serde(with = "num")]
    pub cx: f64,
    #[serde(with = "num")]
    pub cy: f64,
    #[serde(with = "num")]
    pub skew: f64,
    /// Estimated minus true.
    #[serde(with = "num")]
    pub dfx_px: f64,
    #[serde(with = "num")]
    pub dfy_px: f64,
    #[serde(with = "num")]
    pub dcx_px: f64,
    #[serde(with = "num")]
    pub dcy_px: f64,
    #[serde(with = "num")]
    pub dskew_px: f64,
    /// RMS reprojection error per coordinate on the calibration BBs (px).
    #[serde(with = "num")]
    pub reprojection_rms_px: f64,
    /// Mean 3-D error of the held-out BBs triangulated from every view with the estimated geometry.
    #[serde(with = "num")]
    pub heldout_err_mm: f64,
    /// Landmark shifts ‖x_est − x_true‖ over the target's landmarks (px).
    #[serde(with = "num")]
    pub landmark_shift_mean_px: f64,
    #[serde(with = "num")]
    pub landmark_shift_max_px: f64,
    /// Protocol intrinsic: the largest distance between a landmark's projection with K_est and the
    /// homography law's prediction `H x`, `H = K_est K⁻¹` (NaN for protocol full, where it does not hold).
    #[serde(with = "num")]
    pub homography_residual_max_px: f64,
    /// Silhouette Dice and contour distances (NaN for trials beyond `silhouette_trials`).
    #[serde(with = "num")]
    pub dice: f64,
    #[serde(with = "num")]
    pub chamfer_mean_px: f64,
    #[serde(with = "num")]
    pub hd95_px: f64,
    /// Landmark registration (direct LM, AP + LAT, true landmark projections) with this geometry.
    #[serde(with = "num")]
    pub reg_rot_err_deg: f64,
    #[serde(with = "num")]
    pub reg_trans_err_mm: f64,
    /// The landmark registration's mTRE over the target's surface points (mm).
    #[serde(with = "num")]
    pub reg_mtre_mm: f64,
    /// Intensity-based registration (AP + LAT, NCC, from the true pose, noise-free fixed images of the
    /// target through the true views) with this geometry: mTRE over the target's surface points (mm),
    /// rotation and translation error (NaN for trials beyond `intensity_trials`).
    #[serde(with = "num")]
    pub ireg_mtre_mm: f64,
    #[serde(with = "num")]
    pub ireg_rot_err_deg: f64,
    #[serde(with = "num")]
    pub ireg_trans_err_mm: f64,
}

/// The calibration tolerance: per phantom, protocol, view and threshold, the detection noise at which
/// the 95th percentile (over trials) of the largest landmark shift reaches the threshold, and the mean
/// reprojection RMS a calibration at that noise reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationToleranceRow {
    pub phantom: String,
    pub protocol: Protocol,
    pub view: String,
    #[serde(with = "num")]
    pub threshold_px: f64,
    /// Linear interpolation of p95(σ) through (0, 0) and the σ grid; NaN when even the largest σ
    /// stays below the threshold (`above_grid`).
    #[serde(with = "num")]
    pub max_noise_px: f64,
    #[serde(with = "num")]
    pub max_reprojection_rms_px: f64,
    /// The threshold is not reached within the σ grid: the tolerance is above its largest σ.
    pub above_grid: bool,
}

/// Two calibrations of one (phantom, σ) whose reprojection RMS agrees within 5% but whose largest
/// landmark shift differs by the largest factor found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationAmbiguityRow {
    pub phantom: String,
    #[serde(with = "num")]
    pub noise_px: f64,
    pub protocol: Protocol,
    pub view: String,
    pub trial_a: usize,
    pub trial_b: usize,
    #[serde(with = "num")]
    pub rms_a_px: f64,
    #[serde(with = "num")]
    pub rms_b_px: f64,
    #[serde(with = "num")]
    pub shift_a_px: f64,
    #[serde(with = "num")]
    pub shift_b_px: f64,
    /// `shift_b / shift_a`.
    #[serde(with = "num")]
    pub ratio: f64,
    #[serde(with = "num")]
    pub dfx_a_px: f64,
    #[serde(with = "num")]
    pub dfx_b_px: f64,
}

/// The thresholds of the tolerance table (px).
pub const TOLERANCE_THRESHOLDS_PX: [f64; 3] = [0.5, 1.0, 2.0];

/// Largest relative difference of two reprojection RMS values that counts as "equal".
pub const AMBIGUITY_RMS_TOLERANCE: f64 = 0.05;

/// Values in order of first appearance.
fn distinct<T: PartialEq + Clone>(values: impl IntoIterator<Item = T>) -> Vec<T> {
    let mut v: Vec<T> = Vec::new();
    for x in values {
        if !v.contains(&x) {
            v.push(x);
        }
    }
    v
}

/// The (phantom, protocol, view) groups of `rows`, in order of first appearance.
fn groups(rows: &[CalibrationRow]) -> Vec<(String, Protocol, String)> {
    distinct(
        rows.iter()
            .map(|r| (r.phantom.clone(), r.protocol, r.view.clone())),
    )
}

/// The tolerance table of `rows`.
pub fn tolerance(rows: &[CalibrationRow]) -> Vec<CalibrationToleranceRow> {
    let mut out = Vec::new();
    for (phantom, protocol, view) in groups(rows) {
        let of =
            |r: &&CalibrationRow| r.phantom == phantom && r.protocol == protocol && r.view == view;
        let mut sigmas: Vec<f64> = distinct(rows.iter().filter(of).map(|r| r.noise_px));
        sigmas.sort_by(f64::total_cmp);
        // (σ, p95 of the largest shift, mean RMS), starting at the exact noise-free point.
        let mut curve = vec![(0.0, 0.0, 0.0)];
        for &s in &sigmas {
            let cell: Vec<&CalibrationRow> =
                rows.iter().filter(of).filter(|r| r.noise_px == s).collect();
            let shifts: Vec<f64> = cell
                .iter()
                .map(|r| r.landmark_shift_max_px)
                .filter(|x| x.is_finite())
                .collect();
            let rms = cell.iter().map(|r| r.reprojection_rms_px).sum::<f64>() / cell.len() as f64;
            if s > 0.0 && !shifts.is_empty() {
                curve.push((s, percentile(&shifts, 95.0), rms));
            }
        }
        for &threshold_px in &TOLERANCE_THRESHOLDS_PX {
            let crossing = curve.windows(2).find(|w| w[1].1 >= threshold_px).map(|w| {
                let (a, b) = (w[0], w[1]);
                let t = ((threshold_px - a.1) / (b.1 - a.1)).clamp(0.0, 1.0);
                (a.0 + t * (b.0 - a.0), a.2 + t * (b.2 - a.2))
            });
            out.push(CalibrationToleranceRow {
                phantom: phantom.clone(),
                protocol,
                view: view.clone(),
                threshold_px,
                max_noise_px: crossing.map_or(f64::NAN, |c| c.0),
                max_reprojection_rms_px: crossing.map_or(f64::NAN, |c| c.1),
                above_grid: crossing.is_none(),
            });
        }
    }
    out
}

/// The ambiguity table of `rows`: per (phantom, σ > 0, protocol, view) the pair of trials with
/// reprojection RMS equal within [`AMBIGUITY_RMS_TOLERANCE`] and the largest ratio of their largest
/// landmark shifts.
pub fn ambiguity(rows: &[CalibrationRow]) -> Vec<CalibrationAmbiguityRow> {
    let mut out = Vec::new();
    let cells = distinct(rows.iter().map(|r| {
        (
            r.phantom.clone(),
            r.noise_px.to_bits(),
            r.protocol,
            r.view.clone(),
        )
    }));
    for (phantom, bits, protocol, view) in cells {
        let noise_px = f64::from_bits(bits);
        if noise_px <= 0.0 {
            continue;
        }
        let cell: Vec<&CalibrationRow> = rows
            .iter()
            .filter(|r| {
                r.phantom == phantom
                    && r.noise_px.to_bits() == bits
                    && r.protocol == protocol
                    && r.view == view
                    && r.landmark_shift_max_px > 0.0
                    && r.reprojection_rms_px.is_finite()
            })
            .collect();
        let mut best: Option<(f64, &CalibrationRow, &CalibrationRow)> = None;
        for a in &cell {
            for b in &cell {
                let equal = (a.reprojection_rms_px - b.reprojection_rms_px).abs()
                    <= AMBIGUITY_RMS_TOLERANCE * a.reprojection_rms_px.min(b.reprojection_rms_px);
                let ratio = b.landmark_shift_max_px / a.landmark_shift_max_px;
                if equal && ratio.is_finite() && best.is_none_or(|(r, _, _)| ratio > r) {
                    best = Some((ratio, a, b));
                }
            }
        }
        if let Some((ratio, a, b)) = best {
            out.push(CalibrationAmbiguityRow {
                phantom: phantom.clone(),
                noise_px,
                protocol,
                view: view.clone(),
                trial_a: a.trial,
                trial_b: b.trial,
                rms_a_px: a.reprojection_rms_px,
                rms_b_px: b.reprojection_rms_px,
                shift_a_px: a.landmark_shift_max_px,
                shift_b_px: b.landmark_shift_max_px,
                ratio,
                dfx_a_px: a.dfx_px,
                dfx_b_px: b.dfx_px,
            });
        }
    }
    out
}
