//! `figures/index.json`: every figure the study drew, with the report section it belongs to and its
//! caption (what it shows, under which conditions), so the report lists figures without re-deriving
//! them.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::io::write_atomic_bytes;
use crate::{Error, Result};

/// The manifest's file name inside `figures/`.
pub const MANIFEST: &str = "index.json";

/// The report section a figure belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Section {
    Setup,
    Projection,
    Landmarks,
    Registration,
    Calibration,
    Intensity,
    Screws,
    /// The spread across a cohort's cases (`[[anatomy.dataset]]`).
    Cohort,
}

/// One figure: `file` (a PNG in `figures/`, with its SVG beside it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FigureEntry {
    pub section: Section,
    pub file: String,
    pub title: String,
    pub caption: String,
    /// Shown in the report body (a composed, paper-style figure); otherwise listed as a link.
    pub primary: bool,
}

/// Writes the manifest of `entries` into `figs`.
pub fn write(figs: &Path, entries: &[FigureEntry]) -> Result<()> {
    let json =
        serde_json::to_vec_pretty(entries).map_err(|e| Error::encode("figures/index.json", e))?;
    write_atomic_bytes(&figs.join(MANIFEST), &json)
}

/// The manifest in `figs` (empty when the study drew none).
pub fn read(figs: &Path) -> Result<Vec<FigureEntry>> {
    let path = figs.join(MANIFEST);
    if !path.exists() {
        return Ok(Vec::new());
    }
    let bytes = std::fs::read(&path).map_err(|e| Error::io(&path, e))?;
    serde_json::from_slice(&bytes).map_err(|e| Error::format(&path, e.to_string()))
}
