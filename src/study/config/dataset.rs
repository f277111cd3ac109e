//! `[[anatomy.dataset]]`: a folder of CT cases in a known layout (what the config says; the cases are
//! found by [`crate::study::cohort`]).
//!
//! Layouts:
//! * `verse` — the VerSe 2019/2020 release (BIDS naming): `rawdata/sub-X/sub-X[_entities]_ct.nii.gz`
//!   with its mask `derivatives/sub-X/sub-X[_entities]_seg-vert_msk.nii.gz` (or both in one
//!   `sub-X/` folder); labels 20–24 = L1–L5. The case is the file stem (`sub-verse004`,
//!   `sub-gl003_dir-ax`).
//! * `totalseg` — one folder per case holding `ct.nii.gz` and the TotalSegmentator label map: the
//!   multilabel `segmentations.nii.gz` (`TotalSegmentator --ml`), or the per-structure files of the
//!   TotalSegmentator dataset, `segmentations/vertebrae_L1.nii.gz` …, merged into one label map
//!   (TotalSegmentator v2 ids) by [`super::prepare`]. The case is the folder name.
//! * `glob` — two patterns relative to the folder with one `{case}` each, e.g. `ct = "{case}/image.nii.gz"`,
//!   `seg = "{case}/labels.nii.gz"`; `labels` names the convention (default `totalseg`).
//!
//! Cases are sorted by id; `include` keeps only the listed ids, `exclude` drops ids.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::anatomy::labels::LabelConvention;
use crate::{Error, Result};

/// A dataset's file layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    Verse,
    Totalseg,
    Glob,
}

/// `[[anatomy.dataset]]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetConfig {
    /// Prefix of its targets: case `C` level `L1` is target `<name>-<C>-L1`.
    pub name: String,
    /// The dataset's root folder (relative paths: relative to the config file).
    pub folder: PathBuf,
    pub layout: Layout,
    /// `glob` layout: the CT pattern, with one `{case}`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ct: Option<String>,
    /// `glob` layout: the label-map pattern, with one `{case}`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seg: Option<String>,
    /// `glob` layout: the label convention (`totalseg` or `verse`; default `totalseg`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub labels: Option<String>,
    /// Levels studied in every case (`L1`, …).
    pub levels: Vec<String>,
    /// Only these case ids (default: every case found).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub include: Vec<String>,
    /// Case ids left out.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub exclude: Vec<String>,
    /// A case that cannot be read stops the study before any work (default: it is reported, skipped
    /// and listed in the report's *cases left out* table).
    #[serde(default)]
    pub strict: bool,
    /// Also study each case's levels together (`<name>-<C>-segment`).
    #[serde(default)]
    pub segment: bool,
    /// Taubin smoothing of every case's label surfaces, as `[[anatomy.ct]]`'s `smooth_iterations`
    /// (about 10 for thick slices, whose stair steps automatic landmarks cannot read).
    #[serde(default)]
    pub smooth_iterations: usize,
}

impl DatasetConfig {
    /// The label convention of the dataset's label maps.
    pub fn convention(&self) -> Result<LabelConvention> {
        match self.layout {
            Layout::Verse => Ok(LabelConvention::Verse),
            Layout::Totalseg => Ok(LabelConvention::TotalSegmentator),
            Layout::Glob => match &self.labels {
                None => Ok(LabelConvention::TotalSegmentator),
                Some(s) => s.parse().map_err(|e: Error| {
                    Error::invalid("anatomy.dataset.labels", format!("'{}': {e}", self.name))
                }),
            },
        }
    }

    /// Static checks (names, patterns, levels, lists); the folder is read by [`Self::discover`].
    pub fn check(&self) -> Result<()> {
        let key = |k: &str| format!("anatomy.dataset.{k}");
        let ok_name = !self.name.is_empty()
            && self
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-');
        if !ok_name {
            return Err(Error::invalid(
                key("name"),
                format!("'{}' must be non-empty, letters/digits/'-' only", self.name),
            ));
        }
        if self.levels.is_empty() {
            return Err(Error::invalid(
                key("levels"),
                format!("dataset '{}' lists no levels", self.name),
            ));
        }
        let conv = self.convention()?;
        for l in &self.levels {
            conv.resolve(l).map_err(|e| {
                Error::invalid(
                    key("levels"),
                    format!("dataset '{}': {l:?}: {e}", self.name),
                )
            })?;
        }
        let glob = self.layout == Layout::Glob;
        for (k, v) in [("ct", &self.ct), ("seg", &self.seg)] {
            match (glob, v) {
                (true, None) => {
                    return Err(Error::invalid(
                        key(k),
                        format!(
                            "dataset '{}' (layout glob) needs `{k}`, a pattern with one {{case}}",
                            self.name
                        ),
                    ));
                }
                (true, Some(p)) if p.matches("{case}").count() != 1 => {
                    return Err(Error::invalid(
                        key(k),
                        format!("{p:?} must hold {{case}} exactly once"),
                    ));
                }
                (false, Some(_)) => {
                    return Err(Error::invalid(
                        key(k),
                        format!(
                            "dataset '{}': `{k}` is for layout = \"glob\" only",
                            self.name
                        ),
                    ));
                }
                _ => {}
            }
        }
        if let (Some(ct), Some(seg)) = (&self.ct, &self.seg)
            && ct == seg
        {
            return Err(Error::invalid(
                key("seg"),
                format!(
                    "dataset '{}': {seg:?} is the CT pattern too; the label map must be another file",
                    self.name
                ),
            ));
        }
        if !glob && self.labels.is_some() {
            return Err(Error::invalid(
                key("labels"),
                format!(
                    "dataset '{}': the {:?} layout fixes its labels; `labels` is for layout = \"glob\"",
                    self.name, self.layout
                ),
            ));
        }
        Ok(())
    }
}
