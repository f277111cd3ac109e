//! The pedicle-screw tables: where each planned screw is drawn on the screen under a perturbed
//! calibration (`screws.csv`, one row per screw, view and perturbation) and where a navigation system
//! that registered the level with that calibration places it in 3-D (`screw_navigation.csv`, one row per
//! screw and perturbation).

use serde::{Deserialize, Serialize};

use super::{Family, num};

/// One screw in one view under one perturbation (table `screws.csv`): the screw's tip, entry point and
/// axis projected through the **assumed** view at the true pose against their true image — an overlay
/// drawn from a tracked pose with the wrong calibration — and the same points drawn by the navigation
/// system after it registered the level with the assumed views (`nav_*`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScrewRow {
    pub target: String,
    /// The screw: its entry point's landmark name without `_pedicle_entry` (`left`, `L2/right`).
    pub screw: String,
    pub view: String,
    pub family: Family,
    pub perturbation: String,
    #[serde(with = "num")]
    pub df_px: f64,
    #[serde(with = "num")]
    pub piercing_px: f64,
    /// The screw's length, entry to tip (mm).
    #[serde(with = "num")]
    pub length_mm: f64,
    /// ‖π_assumed(tip) − π_true(tip)‖ (px of the detector).
    #[serde(with = "num")]
    pub tip_px: f64,
    /// `tip_px` in mm at the tip: divided by the true magnification there (`tip_px · z_tip / f_px`).
    #[serde(with = "num")]
    pub tip_mm: f64,
    #[serde(with = "num")]
    pub entry_px: f64,
    #[serde(with = "num")]
    pub entry_mm: f64,
    /// Angle between the projected axes (entry → tip), assumed against true (degrees); NaN when the
    /// axis projects to under a pixel (a screw seen end-on).
    #[serde(with = "num")]
    pub axis_deg: f64,
    /// The projected length of the true screw (px): an axis angle means little on a short projection.
    #[serde(with = "num")]
    pub projected_length_px: f64,
    /// The tip as the navigation system draws it (registered pose, assumed view) against its true image
    /// (px): the registration absorbs most of the on-screen error.
    #[serde(with = "num")]
    pub nav_tip_px: f64,
}

/// One screw under one perturbation after the landmark registration of its target on all the study's
/// views with the assumed geometry (table `screw_navigation.csv`): where the navigation system believes
/// the planned screw is, against where it is. Noise-free (exact landmarks, started at the truth): the
/// calibration's bias, one row per cell.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScrewNavigationRow {
    pub target: String,
    pub screw: String,
    /// The views registered (`ap+lat`).
    pub views: String,
    pub family: Family,
    pub perturbation: String,
    #[serde(with = "num")]
    pub df_px: f64,
    #[serde(with = "num")]
    pub piercing_px: f64,
    /// ‖T(tip) − tip‖ with T the registered pose (mm).
    #[serde(with = "num")]
    pub tip_mm: f64,
    #[serde(with = "num")]
    pub entry_mm: f64,
    /// Angle between the registered and the true screw axis (degrees).
    #[serde(with = "num")]
    pub axis_deg: f64,
    /// The registration's mean reprojection residual (px): small while the 3-D error is large is the
    /// danger — the overlay looks right.
    #[serde(with = "num")]
    pub residual_px: f64,
    pub converged: bool,
}
