//! `[calibration]`: the calibration-in-the-loop experiment — which phantoms, detection noise levels,
//! trials and protocols; and its work cells (one per phantom, σ and chunk of trials).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::PhysicalGrid;
use crate::calibration::{CalibrationPhantom, SetupOptions};
use crate::geometry::Perturbation;
use crate::{Error, Result};

/// Largest number of calibration trials per (phantom, σ).
pub const MAX_CALIBRATION_TRIALS: usize = 100_000;

/// A protocol: which geometry the anatomy is projected with after a calibration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Protocol {
    /// (a) `K_est` with the true extrinsics (the paper's intrinsic-only protocol).
    Intrinsic,
    /// (b) the full estimated geometry `K_est [R_est | t_est]`.
    Full,
}

impl Protocol {
    pub fn name(self) -> &'static str {
        match self {
            Protocol::Intrinsic => "intrinsic",
            Protocol::Full => "full",
        }
    }
}

impl std::fmt::Display for Protocol {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// `[calibration]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CalibrationSection {
    /// `plate`, `helix`, or paths of phantom JSON files (`{"bbs_mm": [[x, y, z], ...]}`).
    pub phantoms: Vec<String>,
    /// Detection noise σ values (px, at the study's detector binning).
    pub noise_px: Vec<f64>,
    /// Monte-Carlo calibrations per (phantom, σ).
    pub trials: usize,
    /// Trials per work unit (the resume granularity).
    pub trials_per_unit: usize,
    pub protocols: Vec<Protocol>,
    /// The target whose landmarks and silhouette are measured (default: the study's first target).
    pub target: Option<String>,
    /// Dice and contour distances (a render per view and protocol) for the first this many trials of
    /// each (phantom, σ); the landmark metrics and registration run for every trial.
    pub silhouette_trials: usize,
    /// An intensity-based registration (AP + LAT, NCC, from the true pose) with the estimated geometry
    /// for the first this many trials of each (phantom, σ) and protocol (0 = none).
    pub intensity_trials: usize,
    /// Plate tilt (deg) and poses per view.
    pub tilt_deg: f64,
    pub poses_per_view: usize,
    /// `[calibration.physical]`: the C-arm whose calibration is simulated differs from its nominal
    /// geometry by a physical error (each value of each key alone, the keys of
    /// `[perturbations.physical]`), table `calibration_physical.csv`. A section without this table
    /// has none.
    #[serde(default = "PhysicalGrid::none")]
    pub physical: PhysicalGrid,
}

impl Default for CalibrationSection {
    fn default() -> Self {
        CalibrationSection {
            // The default study's small grid: two noise levels spanning a good and a poor calibration,
            // 10 calibrations each, every reported column over all 10 (the silhouettes too), no
            // intensity registration (`make calibration` runs the full grid).
            phantoms: vec!["plate".into(), "helix".into()],
            noise_px: vec![0.1, 1.0],
            trials: 10,
            trials_per_unit: 10,
            protocols: vec![Protocol::Intrinsic, Protocol::Full],
            target: None,
            silhouette_trials: 10,
            intensity_trials: 0,
            tilt_deg: 30.0,
            poses_per_view: 5,
            // A displaced focal spot (the camera centre moves), a detector farther from the source (K
            // alone changes) and a rolled detector (the camera turns): what a calibration of K alone
            // can and cannot absorb.
            physical: PhysicalGrid {
                src_dx_mm: vec![4.0],
                det_dz_mm: vec![10.0],
                det_roll_deg: vec![2.0],
                ..PhysicalGrid::none()
            },
        }
    }
}

/// One work cell: trials `first..first + count` of one (phantom, σ), on the nominal C-arm or on one
/// displaced by a physical error.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationCell {
    pub phantom: String,
    pub noise_px: f64,
    pub first: usize,
    pub count: usize,
    /// The physical error of the calibrated C-arm against its nominal geometry (None: the nominal).
    pub physical: Option<Perturbation>,
}

impl CalibrationCell {
    /// File-name-safe id.
    pub fn id(&self) -> String {
        let p: String = self
            .phantom
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        match &self.physical {
            Some(q) => format!(
                "cal_{p}_s{}_{}_t{}",
                self.noise_px,
                q.to_string().replace(['=', ','], ""),
                self.first
            ),
            None => format!("cal_{p}_s{}_t{}", self.noise_px, self.first),
        }
    }

    pub fn describe(&self) -> String {
        let on = self
            .physical
            .map_or(String::new(), |q| format!(" of a C-arm displaced by {q}"));
        format!(
            "calibration{on} with phantom '{}' at σ = {} px, trials {}..{}",
            self.phantom,
            self.noise_px,
            self.first,
            self.first + self.count
        )
    }

    /// The seed key (chunking excluded; the physical error too: a trial on a displaced C-arm draws
    /// the same detection noise as on the nominal one, so the two differ by the error alone).
    pub fn seed_key(&self) -> String {
        format!("cal/{}/{}", self.phantom, self.noise_px)
    }
}

impl CalibrationSection {
    /// The phantom a `phantoms` entry names (`plate`, `helix` or a JSON file).
    pub fn phantom(name: &str) -> Result<CalibrationPhantom> {
        match name {
            "plate" => Ok(CalibrationPhantom::default_plate()),
            "helix" => Ok(CalibrationPhantom::default_helix()),
            file => CalibrationPhantom::from_file(&PathBuf::from(file))
                .map_err(|e| Error::invalid("calibration.phantoms", e.to_string())),
        }
    }

    /// The setup options.
    pub fn setup_options(&self) -> SetupOptions {
        SetupOptions {
            tilt_deg: self.tilt_deg,
            poses_per_view: self.poses_per_view,
            ..SetupOptions::default()
        }
    }

    /// Every cell in table order: the nominal C-arm's (phantom, then σ, then chunk), then each physical
    /// error's (validated before; a grid that fails to parse has none here).
    pub fn cells(&self) -> Vec<CalibrationCell> {
        let mut out = Vec::new();
        let errors: Vec<Option<Perturbation>> = std::iter::once(None)
            .chain(
                self.physical
                    .cells()
                    .unwrap_or_default()
                    .into_iter()
                    .map(Some),
            )
            .collect();
        for physical in errors {
            for p in &self.phantoms {
                for &s in &self.noise_px {
                    for first in (0..self.trials).step_by(self.trials_per_unit.max(1)) {
                        out.push(CalibrationCell {
                            phantom: p.clone(),
                            noise_px: s,
                            first,
                            count: self.trials_per_unit.min(self.trials - first),
                            physical,
                        });
                    }
                }
            }
        }
        out
    }

    /// Checks every key (phantom files are read and checked here too).
    pub fn validate(&self) -> Result<()> {
        if self.phantoms.is_empty() {
            return Err(Error::invalid(
                "calibration.phantoms",
                "must list at least one phantom",
            ));
        }
        for (i, p) in self.phantoms.iter().enumerate() {
            if self.phantoms[..i].contains(p) {
                return Err(Error::invalid(
                    "calibration.phantoms",
                    format!("'{p}' is listed twice"),
                ));
            }
            Self::phantom(p)?;
        }
        if self.noise_px.is_empty() {
            return Err(Error::invalid(
                "calibration.noise_px",
                "must list at least one σ",
            ));
        }
        for &s in &self.noise_px {
            if !(s.is_finite() && s >= 0.0) {
                return Err(Error::invalid(
                    "calibration.noise_px",
                    format!("σ must be a finite number ≥ 0 px, got {s}"),
                ));
            }
        }
        if self.trials == 0 || self.trials > MAX_CALIBRATION_TRIALS {
            return Err(Error::invalid(
                "calibration.trials",
                format!(
                    "must be between 1 and {MAX_CALIBRATION_TRIALS}, got {}",
                    self.trials
                ),
            ));
        }
        if self.trials_per_unit == 0 {
            return Err(Error::invalid(
                "calibration.trials_per_unit",
                "must be at least 1",
            ));
        }
        if self.protocols.is_empty() {
            return Err(Error::invalid(
                "calibration.protocols",
                "must list at least one of \"intrinsic\", \"full\"",
            ));
        }
        if !(self.tilt_deg.is_finite() && self.tilt_deg > 0.0 && self.tilt_deg < 80.0) {
            return Err(Error::invalid(
                "calibration.tilt_deg",
                format!("must be in (0, 80) degrees, got {}", self.tilt_deg),
            ));
        }
        self.physical.cells_of("calibration.physical")?;
        let max = crate::calibration::phantom::MAX_POSES_PER_VIEW;
        if !(2..=max).contains(&self.poses_per_view) {
            return Err(Error::invalid(
                "calibration.poses_per_view",
                format!("{}: must be between 2 and {max}", self.poses_per_view),
            ));
        }
        Ok(())
    }
}
