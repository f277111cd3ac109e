//! The paper's reported figures (`reference/paper-results.toml`, embedded), typed.

use std::collections::BTreeMap;

use serde::Deserialize;

use crate::{Error, Result};

/// The paper's reported figures, as TOML.
pub const PAPER_RESULTS_TOML: &str = include_str!("../../reference/paper-results.toml");

/// A value at Δf = 100 and 500 px.
#[derive(Debug, Clone, Copy, Deserialize)]
pub struct AtDf {
    pub at_df_100: f64,
    pub at_df_500: f64,
}

impl AtDf {
    /// The value at `df` (100 or 500 px).
    pub fn at(&self, df: f64) -> Option<f64> {
        match df {
            100.0 => Some(self.at_df_100),
            500.0 => Some(self.at_df_500),
            _ => None,
        }
    }
}

/// Silhouette overlap under the paper's perturbation schedule.
#[derive(Debug, Clone, Deserialize)]
pub struct Silhouette {
    pub lat_dice: AtDf,
    pub lat_iou: AtDf,
    pub ap_dice_min: f64,
}

/// Registration error ranges over Δf 100–500 px and piercing 0–50 px: [min, max].
#[derive(Debug, Clone, Deserialize)]
pub struct Registration {
    pub kabsch_rotation_deg: [f64; 2],
    pub kabsch_translation_mm: [f64; 2],
    pub direct_rotation_deg: [f64; 2],
    pub direct_translation_mm: [f64; 2],
    /// How the paper says each of the four errors changes as Δf grows ("rising" for all four).
    pub trend_with_df: String,
}

/// The paper's geometry and perturbation grid.
#[derive(Debug, Clone, Deserialize)]
pub struct PaperGeometry {
    pub focal_length_px: f64,
    pub detector_px: [u32; 2],
    pub focal_perturbation_px: Vec<f64>,
    pub piercing_perturbation_px: Vec<f64>,
}

/// What the paper reports.
#[derive(Debug, Clone, Deserialize)]
pub struct PaperResults {
    pub geometry: PaperGeometry,
    pub silhouette: Silhouette,
    /// Landmark → [AP, LAT] shift (px) under one (unstated) focal perturbation.
    pub landmark_shift_px: BTreeMap<String, [f64; 2]>,
    pub registration: Registration,
}

impl PaperResults {
    /// The embedded figures.
    pub fn embedded() -> Result<PaperResults> {
        toml::from_str(PAPER_RESULTS_TOML)
            .map_err(|e| Error::format("reference/paper-results.toml", e.to_string()))
    }

    /// Mean of the paper's landmark shifts in view `i` (0 = AP, 1 = LAT).
    pub fn mean_landmark_shift(&self, i: usize) -> f64 {
        let v: Vec<f64> = self.landmark_shift_px.values().map(|s| s[i]).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_figures_parse() {
        let p = PaperResults::embedded().unwrap();
        assert_eq!(p.silhouette.lat_dice.at(500.0), Some(0.973));
        assert_eq!(p.landmark_shift_px["spinous_tip"], [1.8, 18.8]);
        assert_eq!(p.registration.kabsch_rotation_deg, [0.05, 0.37]);
        // (2.2 + 3.6 + 3.5 + 2.4 + 1.3 + 1.8) / 6
        assert!((p.mean_landmark_shift(0) - 14.8 / 6.0).abs() < 1e-12);
    }
}
