//! `[tracking]`: the relative (tracking) error experiment — the target registered at two true poses
//! (the motion below) with the same wrong geometry, for the focal cells `df_px` and the physical cells
//! of `[perturbations.physical]`; see [`crate::registration::tracking`].

use serde::{Deserialize, Serialize};

use super::{Family, RegistrationMethod, StudyConfig};
use crate::geometry::Perturbation;
use crate::{Error, Result};

/// Largest motion accepted: far beyond any motion tracked between two images of one vertebra.
const MAX_MOTION_MM: f64 = 200.0;
const MAX_MOTION_DEG: f64 = 90.0;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackingSection {
    /// Methods (solver and observed views).
    pub methods: Vec<RegistrationMethod>,
    /// Focal offsets Δf (px) of the intrinsic cells (family `focal`).
    pub df_px: Vec<f64>,
    /// The target's motion between the two poses: a translation (mm, world axes) after a rotation
    /// (axis-angle vector, degrees, world axes) about the centroid of its landmarks.
    pub translation_mm: [f64; 3],
    pub rotation_deg: [f64; 3],
}

impl Default for TrackingSection {
    /// Jain et al.'s question at the size the issue names: 10 mm along the patient's left–right axis
    /// and 5° about the superior axis; the paper's focal offsets 100 and 500 px; one view each and both.
    fn default() -> Self {
        TrackingSection {
            methods: vec![
                RegistrationMethod::DirectAp,
                RegistrationMethod::DirectLat,
                RegistrationMethod::DirectApLat,
            ],
            df_px: vec![100.0, 500.0],
            translation_mm: [10.0, 0.0, 0.0],
            rotation_deg: [0.0, 0.0, 5.0],
        }
    }
}

/// One tracking cell: a target, a method and one perturbation of the assumed geometry.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackingCell {
    pub target: String,
    pub method: RegistrationMethod,
    pub family: Family,
    pub perturbation: Perturbation,
}

impl TrackingCell {
    /// File-name-safe id.
    pub fn id(&self) -> String {
        let spec = self.perturbation.to_string().replace(['=', ','], "");
        format!(
            "track_{}_{}_{}_{spec}",
            self.target,
            self.method.name().replace('+', "_"),
            self.family
        )
    }

    pub fn describe(&self) -> String {
        format!(
            "tracking of '{}' by {} under {} (family {})",
            self.target, self.method, self.perturbation, self.family
        )
    }
}

impl TrackingSection {
    /// The perturbations of the cells: each Δf alone, then the physical cells of `physical`.
    pub fn perturbations(&self, cfg: &StudyConfig) -> Vec<(Family, Perturbation)> {
        let mut out: Vec<(Family, Perturbation)> = self
            .df_px
            .iter()
            .map(|&d| (Family::Focal, Perturbation::focal(d)))
            .collect();
        out.extend(
            cfg.perturbations
                .physical
                .cells()
                .unwrap_or_default()
                .into_iter()
                .map(|p| (Family::Physical, p)),
        );
        out
    }

    /// Checks the section's values, naming the key.
    pub fn validate(&self) -> Result<()> {
        super::validate::finite_list("tracking.df_px", &self.df_px)?;
        super::validate::unique("tracking.methods", &self.methods, |m| m.name())?;
        super::validate::unique("tracking.df_px", &self.df_px, |d| d.to_string())?;
        if self.methods.is_empty() {
            return Err(Error::invalid("tracking.methods", "lists no method"));
        }
        for (key, v, limit) in [
            (
                "tracking.translation_mm",
                self.translation_mm,
                MAX_MOTION_MM,
            ),
            ("tracking.rotation_deg", self.rotation_deg, MAX_MOTION_DEG),
        ] {
            let n = glam::DVec3::from(v).length();
            if !(v.iter().all(|x| x.is_finite()) && n <= limit) {
                return Err(Error::invalid(
                    key,
                    format!("{v:?} must be finite with a length of at most {limit}"),
                ));
            }
        }
        if self.translation_mm == [0.0; 3] && self.rotation_deg == [0.0; 3] {
            return Err(Error::invalid(
                "tracking.translation_mm / tracking.rotation_deg",
                "the motion is zero: there is nothing to track",
            ));
        }
        Ok(())
    }
}
