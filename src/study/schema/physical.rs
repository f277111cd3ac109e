//! `physical.csv`: the projection metrics of the physical geometry errors (family `physical`), one row
//! per (target, view, cell), beside the assumed camera each error amounts to.

use serde::{Deserialize, Serialize};

use super::num;

/// One physical cell of one target in one view (table `physical.csv`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhysicalRow {
    pub target: String,
    pub view: String,
    /// The physical key (`det_dz_mm`, …) and its value (mm or degrees, as the key's suffix says).
    pub key: String,
    #[serde(with = "num")]
    pub value: f64,
    /// The assumed camera's intrinsics (px), as the QR of the moved detector gives them.
    #[serde(with = "num")]
    pub fx_px: f64,
    #[serde(with = "num")]
    pub fy_px: f64,
    #[serde(with = "num")]
    pub skew_px: f64,
    #[serde(with = "num")]
    pub cx_px: f64,
    #[serde(with = "num")]
    pub cy_px: f64,
    /// How far the assumed camera centre (the source) moved (mm) and its axes turned (degrees).
    #[serde(with = "num")]
    pub camera_moved_mm: f64,
    #[serde(with = "num")]
    pub camera_turned_deg: f64,
    /// The reference or the perturbed silhouette touches the detector's edge.
    pub cut_by_edge: bool,
    #[serde(with = "num")]
    pub dice: f64,
    #[serde(with = "num")]
    pub iou: f64,
    #[serde(with = "num")]
    pub chamfer_mean_px: f64,
    #[serde(with = "num")]
    pub hd95_px: f64,
    /// NCC over the anatomy's region (as in `projection.csv`).
    #[serde(with = "num")]
    pub ncc: f64,
    /// Landmarks whose reference projection lies on the detector, and their shift between the true and
    /// the assumed camera (exact projections), in px and in mm at the detector (px × pixel pitch).
    pub landmarks: usize,
    #[serde(with = "num")]
    pub landmark_shift_mean_px: f64,
    #[serde(with = "num")]
    pub landmark_shift_max_px: f64,
    #[serde(with = "num")]
    pub landmark_shift_mean_mm: f64,
}

/// One landmark-registration trial under a physical cell (table `registration_physical.csv`): the
/// landmarks observed through the true cameras (plus the registration's noise), solved with the
/// cameras the assumed geometry amounts to, errors against the true pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RegistrationPhysicalRow {
    pub target: String,
    pub method: crate::study::config::RegistrationMethod,
    /// The physical key (`det_dz_mm`, …) and its value (mm or degrees, as the key's suffix says).
    pub key: String,
    #[serde(with = "num")]
    pub value: f64,
    pub trial: usize,
    #[serde(with = "num")]
    pub rot_err_deg: f64,
    #[serde(with = "num")]
    pub trans_err_mm: f64,
    /// Mean target registration error over the target's landmarks (mm).
    #[serde(with = "num")]
    pub tre_mm: f64,
    /// The largest error (mm) at the target's clinical points (planned pedicle-screw entry, isthmus
    /// and tip; NaN without any).
    #[serde(with = "num")]
    pub pedicle_err_max_mm: f64,
    #[serde(with = "num")]
    pub residual_px: f64,
    pub iterations: usize,
    pub converged: bool,
}

/// One calibration trial of a C-arm displaced by a physical error, seen through one protocol in one
/// view (table `calibration_physical.csv`): the phantom is imaged and calibrated on the displaced
/// C-arm, the anatomy is imaged by it too, and is projected and registered with the calibration's
/// geometry — protocol `full`: the estimated K and poses; `intrinsic`: the estimated K with the
/// **nominal** poses (a tracker or mechanical model that does not know of the error). Beside them the
/// same measures for the nominal geometry used uncalibrated.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationPhysicalRow {
    pub phantom: String,
    #[serde(with = "num")]
    pub noise_px: f64,
    /// The physical key and its value (mm or degrees).
    pub key: String,
    #[serde(with = "num")]
    pub value: f64,
    pub trial: usize,
    pub protocol: crate::study::config::Protocol,
    pub view: String,
    /// The calibration's phantom reprojection RMS (px).
    #[serde(with = "num")]
    pub reprojection_rms_px: f64,
    /// Shift of the target's landmarks between the displaced C-arm's projection and the protocol's (px).
    #[serde(with = "num")]
    pub landmark_shift_mean_px: f64,
    #[serde(with = "num")]
    pub landmark_shift_max_px: f64,
    /// Landmark registration (direct, every view) with the protocol's geometry: errors and mTRE over
    /// the target's surface points.
    #[serde(with = "num")]
    pub reg_rot_err_deg: f64,
    #[serde(with = "num")]
    pub reg_trans_err_mm: f64,
    #[serde(with = "num")]
    pub reg_mtre_mm: f64,
    /// The same with the nominal geometry, uncalibrated: the physical error's own effect.
    #[serde(with = "num")]
    pub uncalibrated_shift_max_px: f64,
    #[serde(with = "num")]
    pub uncalibrated_mtre_mm: f64,
}
