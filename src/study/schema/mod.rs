//! The study's tables, typed: one serde row type per table. A row's fields are its columns (names
//! with units, in order); the `csv` crate writes them with headers from the field names and quotes a
//! cell only when it must (a landmark name with a comma or a quote). Unit result files hold the same
//! rows as JSON. Adding a metric column is one field here plus its computation in `experiments`.
//!
//! f64 cells are written with `{}` Display and read back exactly (see [`num`]).

mod calibration;
pub mod cohort;
mod intensity;
pub mod num;
mod physical;
mod screws;
mod tables;

use serde::{Deserialize, Serialize};

pub use super::config::Family;
use super::config::RegistrationMethod;

pub use calibration::{
    CalibrationAmbiguityRow, CalibrationRow, CalibrationToleranceRow, TOLERANCE_THRESHOLDS_PX,
};
pub use intensity::{IntensityBinRow, IntensityRow, IntensitySummaryRow, OPTIMUM_RESTART_MM};
pub use physical::{CalibrationPhysicalRow, PhysicalRow, RegistrationPhysicalRow};
pub use screws::{ScrewNavigationRow, ScrewRow};
pub use tables::{
    SOLVER_SPREAD, StudyTables, TableRow, ci95_half_width, mean_sd, read_rows, write_rows,
};

/// Whole-object silhouette, contour and image-similarity metrics (table `projection.csv`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProjectionRow {
    pub target: String,
    pub view: String,
    pub family: Family,
    #[serde(with = "num")]
    pub df_px: f64,
    #[serde(with = "num")]
    pub dcx_px: f64,
    #[serde(with = "num")]
    pub dcy_px: f64,
    #[serde(with = "num")]
    pub skew_px: f64,
    #[serde(with = "num")]
    pub sy: f64,
    /// The reference or the perturbed silhouette touches the detector's edge: the overlap, contour and
    /// image metrics of this row are of a cut silhouette, and the report leaves it out of pooled numbers.
    pub cut_by_edge: bool,
    #[serde(with = "num")]
    pub dice: f64,
    #[serde(with = "num")]
    pub iou: f64,
    #[serde(with = "num")]
    pub chamfer_mean_px: f64,
    #[serde(with = "num")]
    pub hausdorff_px: f64,
    #[serde(with = "num")]
    pub hd95_px: f64,
    #[serde(with = "num")]
    pub edge_distance_mean_px: f64,
    /// The image similarities over the anatomy's region: the union of the two silhouettes dilated by
    /// `region_margin_px` (`region_px` pixels), so the empty detector does not dominate them.
    #[serde(with = "num")]
    pub ncc: f64,
    #[serde(with = "num")]
    pub ssim: f64,
    #[serde(with = "num")]
    pub mutual_information_nats: f64,
    #[serde(with = "num")]
    pub gradient_correlation: f64,
    pub region_margin_px: usize,
    pub region_px: usize,
    /// The same similarities over the whole detector (background included).
    #[serde(with = "num")]
    pub ncc_detector: f64,
    #[serde(with = "num")]
    pub ssim_detector: f64,
    #[serde(with = "num")]
    pub mutual_information_nats_detector: f64,
    #[serde(with = "num")]
    pub gradient_correlation_detector: f64,
    /// Mean |a − b| of the two images over the whole detector: unitless line integrals (or
    /// intensities), not per mm.
    #[serde(with = "num")]
    pub mean_abs_diff: f64,
}

/// Dice/IoU of one anatomical structure (table `structures.csv`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StructureRow {
    pub target: String,
    pub view: String,
    pub family: Family,
    #[serde(with = "num")]
    pub df_px: f64,
    #[serde(with = "num")]
    pub dcx_px: f64,
    #[serde(with = "num")]
    pub dcy_px: f64,
    pub structure: String,
    #[serde(with = "num")]
    pub dice: f64,
    #[serde(with = "num")]
    pub iou: f64,
}

/// One landmark measured from marker images, with the homography prediction (table `landmarks.csv`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LandmarkRow {
    pub target: String,
    pub view: String,
    pub family: Family,
    #[serde(with = "num")]
    pub df_px: f64,
    #[serde(with = "num")]
    pub dcx_px: f64,
    #[serde(with = "num")]
    pub dcy_px: f64,
    pub landmark: String,
    #[serde(with = "num")]
    pub ref_u_px: f64,
    #[serde(with = "num")]
    pub ref_v_px: f64,
    #[serde(with = "num")]
    pub meas_u_px: f64,
    #[serde(with = "num")]
    pub meas_v_px: f64,
    #[serde(with = "num")]
    pub shift_px: f64,
    #[serde(with = "num")]
    pub pred_u_px: f64,
    #[serde(with = "num")]
    pub pred_v_px: f64,
    #[serde(with = "num")]
    pub pred_shift_px: f64,
    /// `‖x_meas − H x_ref‖`.
    #[serde(with = "num")]
    pub pred_error_px: f64,
}

/// One registration trial (table `registration.csv`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RegistrationRow {
    pub target: String,
    pub method: RegistrationMethod,
    #[serde(with = "num")]
    pub df_px: f64,
    #[serde(with = "num")]
    pub piercing_px: f64,
    pub trial: usize,
    #[serde(with = "num")]
    pub rot_err_deg: f64,
    #[serde(with = "num")]
    pub trans_err_mm: f64,
    #[serde(with = "num")]
    pub residual_px: f64,
    pub iterations: usize,
    pub converged: bool,
}

/// Mean, sample standard deviation and 95 % confidence half-width over the trials of one registration
/// cell (table `registration_summary.csv`) over the trials that converged to finite errors; the others
/// (a solve that errored, hit its cap or stopped at a pose that cannot be the anatomy) are counted in
/// `failed` and left out of `n` and the statistics. `deterministic`: every error's spread is below [`SOLVER_SPREAD`]
/// (trials that differ only in their starting pose, without observation noise, converge to one
/// answer); such a cell is one value, and the report prints it as one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RegistrationSummaryRow {
    pub target: String,
    pub method: RegistrationMethod,
    #[serde(with = "num")]
    pub df_px: f64,
    #[serde(with = "num")]
    pub piercing_px: f64,
    pub trials: usize,
    pub failed: usize,
    /// Trials that converged to finite errors (`trials − failed`): the n of the statistics.
    pub n: usize,
    pub deterministic: bool,
    #[serde(with = "num")]
    pub rot_err_deg_mean: f64,
    #[serde(with = "num")]
    pub rot_err_deg_sd: f64,
    /// Half-width of the 95 % confidence interval of the mean (Student t, n − 1 degrees of freedom;
    /// NaN for n < 2).
    #[serde(with = "num")]
    pub rot_err_deg_ci95: f64,
    #[serde(with = "num")]
    pub trans_err_mm_mean: f64,
    #[serde(with = "num")]
    pub trans_err_mm_sd: f64,
    /// Half-width of the 95 % confidence interval of the mean (Student t, n − 1 degrees of freedom;
    /// NaN for n < 2).
    #[serde(with = "num")]
    pub trans_err_mm_ci95: f64,
    #[serde(with = "num")]
    pub residual_px_mean: f64,
    #[serde(with = "num")]
    pub residual_px_sd: f64,
    /// Half-width of the 95 % confidence interval of the mean (Student t, n − 1 degrees of freedom;
    /// NaN for n < 2).
    #[serde(with = "num")]
    pub residual_px_ci95: f64,
}

/// Everything one unit produced (the content of its `units/<id>.json`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct UnitRows {
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub projection: Vec<ProjectionRow>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub structures: Vec<StructureRow>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub landmarks: Vec<LandmarkRow>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub registration: Vec<RegistrationRow>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub calibration: Vec<CalibrationRow>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub intensity: Vec<IntensityRow>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub physical: Vec<PhysicalRow>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub tracking: Vec<TrackingRow>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub registration_physical: Vec<RegistrationPhysicalRow>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub calibration_physical: Vec<CalibrationPhysicalRow>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub screws: Vec<ScrewRow>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub screw_navigation: Vec<ScrewNavigationRow>,
}

/// One tracking cell (table `tracking.csv`): the absolute errors at the two poses and the error of
/// the relative pose `T₁⁻¹ T₂` (see [`crate::registration::tracking`]). Noise-free: one row per cell.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrackingRow {
    pub target: String,
    pub method: RegistrationMethod,
    pub family: Family,
    /// The assumed geometry's perturbation (canonical spec).
    pub perturbation: String,
    /// The motion between the poses: translation length (mm) and rotation angle (degrees).
    #[serde(with = "num")]
    pub motion_mm: f64,
    #[serde(with = "num")]
    pub motion_deg: f64,
    /// Pose 1: rotation and translation error and mean target registration error over the landmarks.
    #[serde(with = "num")]
    pub abs_rot_err_deg: f64,
    #[serde(with = "num")]
    pub abs_trans_err_mm: f64,
    #[serde(with = "num")]
    pub abs_tre_mm: f64,
    /// Pose 2's mean target registration error.
    #[serde(with = "num")]
    pub abs_tre_2_mm: f64,
    /// The relative pose's rotation and translation error and its mean TRE over the landmarks.
    #[serde(with = "num")]
    pub rel_rot_err_deg: f64,
    #[serde(with = "num")]
    pub rel_trans_err_mm: f64,
    #[serde(with = "num")]
    pub rel_tre_mm: f64,
    /// The largest error (mm) at the target's clinical points (planned pedicle-screw entry, isthmus and
    /// tip; NaN without any): absolute at pose 1, and of the relative pose.
    #[serde(with = "num")]
    pub pedicle_abs_err_max_mm: f64,
    #[serde(with = "num")]
    pub pedicle_rel_err_max_mm: f64,
    #[serde(with = "num")]
    pub residual_px: f64,
    pub converged: bool,
}
