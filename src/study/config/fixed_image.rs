//! What the intensity registration's fixed images are made of: today's monochromatic line integral
//! (`mono`), or a radiograph as a C-arm makes it — a tube spectrum through the phantom's materials onto a
//! CsI detector, without implants (`spectral`) and with two titanium pedicle screws per level
//! (`spectral+screws`), so a change is attributed to the spectrum or to the metal —
//! `[intensity_registration] images` and `[intensity_registration.spectral]`. The moving DRR is always
//! the monochromatic one of the level alone, as registration systems compute it.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::spectral::{SpectralModel, model_from_specs};
use crate::{Error, Result};

/// The image model of a cell's fixed images.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum FixedImage {
    /// `μ·L` summed over the meshes (the moving DRR's own model).
    #[serde(rename = "mono")]
    Mono,
    /// `−ln(I/I0)` of the spectral model of `[intensity_registration.spectral]`, no implants.
    #[serde(rename = "spectral")]
    Spectral,
    /// The same with two titanium pedicle screws per level of the fixed image, along the phantom's
    /// pedicle axes.
    #[serde(rename = "spectral+screws")]
    SpectralScrews,
}

impl FixedImage {
    /// The table spelling.
    pub fn name(self) -> &'static str {
        match self {
            FixedImage::Mono => "mono",
            FixedImage::Spectral => "spectral",
            FixedImage::SpectralScrews => "spectral+screws",
        }
    }

    /// File-name-safe spelling (unit ids).
    pub fn id(self) -> &'static str {
        match self {
            FixedImage::Mono => "mono",
            FixedImage::Spectral => "spectral",
            FixedImage::SpectralScrews => "spectral_screws",
        }
    }

    /// Whether the image is the spectral model's (with or without screws).
    pub fn is_spectral(self) -> bool {
        self != FixedImage::Mono
    }

    /// The images of a section written before the key existed: monochromatic only.
    pub fn mono_only() -> Vec<FixedImage> {
        vec![FixedImage::Mono]
    }
}

impl std::fmt::Display for FixedImage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// `[intensity_registration.spectral]`: the spectral fixed images' tube, filtration and detector, in the
/// spellings of `spinedrr render --spectrum/--filter/--detector`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SpectralImageSection {
    /// A tube potential in kV (TASMIP, 30–140), `mono:E` (keV) or a spectrum file (relative to the config).
    pub spectrum: String,
    /// Added filtration, `al:2.5,cu:0.1` (mm), or empty.
    pub filter: String,
    /// `csi:0.6` (MATERIAL:MM of scintillator) or `ideal` (every photon absorbed).
    pub detector: String,
}

impl Default for SpectralImageSection {
    /// A lumbar fluoroscopy technique: 80 kV with 2.5 mm Al, a 600 µm CsI detector.
    fn default() -> Self {
        SpectralImageSection {
            spectrum: "80".into(),
            filter: "al:2.5".into(),
            detector: "csi:0.6".into(),
        }
    }
}

impl SpectralImageSection {
    /// The spectral model (validated; errors name the key).
    pub fn model(&self) -> Result<SpectralModel> {
        model_from_specs(&self.spectrum, &self.filter, &self.detector).map_err(|e| {
            Error::invalid(
                "intensity_registration.spectral",
                format!(
                    "spectrum '{}', filter '{}', detector '{}': {e}",
                    self.spectrum, self.filter, self.detector
                ),
            )
        })
    }

    /// The spectrum in words for the report: `80 kV (TASMIP), 2.5 mm Al, 600 µm CsI`.
    pub fn describe(&self) -> String {
        let tube = if self.spectrum.trim().parse::<f64>().is_ok() {
            format!("{} kV (TASMIP)", self.spectrum.trim())
        } else {
            self.spectrum.clone()
        };
        let filter = if self.filter.trim().is_empty() {
            "no added filtration".to_string()
        } else {
            format!("filter {}", self.filter)
        };
        format!("{tube}, {filter}, detector {}", self.detector)
    }

    /// A spectrum file named relative to the config's folder `dir` is found there.
    pub fn resolve_paths(&mut self, dir: &Path) {
        let s = self.spectrum.trim();
        if s.parse::<f64>().is_ok() || s.starts_with("mono:") {
            return;
        }
        let p = PathBuf::from(s);
        if p.is_relative() {
            self.spectrum = dir.join(p).to_string_lossy().into_owned();
        }
    }
}
