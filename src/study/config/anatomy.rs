//! `[anatomy]`: what the study images — the built-in phantom's levels, mesh files, CTs with label maps,
//! and folders of CT cases.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::dataset::DatasetConfig;
use crate::anatomy::ct::Alignment;
use crate::anatomy::labels::LabelConvention;
use crate::render::volume::VolumeMethod;
use crate::{Error, Result};

/// `[anatomy]`: the built-in phantom levels and the marker spheres used to measure landmarks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AnatomyConfig {
    /// Levels studied one by one, e.g. `["L1", "L2"]`.
    pub levels: Vec<String>,
    /// Also study the levels together as one segment.
    pub segment: bool,
    /// Marching-cubes grid of the phantom (mm).
    pub voxel_mm: f64,
    /// Radius of the landmark marker spheres (mm).
    pub marker_radius_mm: f64,
    /// The user's own anatomy: closed meshes with landmarks, each studied as one target.
    pub meshes: Vec<MeshTarget>,
    /// CT volumes with a vertebra segmentation: each listed level studied as one target.
    pub ct: Vec<CtTarget>,
    /// Datasets of CT cases (`[[anatomy.dataset]]`): each readable case becomes CT targets as a
    /// `[[anatomy.ct]]` entry does (see `study::cohort`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub dataset: Vec<DatasetConfig>,
}

/// `[[anatomy.meshes]]`: one target made of closed surface files (STL/OBJ/PLY, world mm) and a landmarks
/// JSON file (the format `spinedrr phantom` writes).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshTarget {
    pub name: String,
    pub files: Vec<PathBuf>,
    pub landmarks: PathBuf,
    /// Attenuation of every surface (mm⁻¹); default: cortical bone.
    #[serde(default = "default_mu")]
    pub mu_per_mm: f64,
}

/// `[[anatomy.ct]]`: a CT (NIfTI, HU) with a label map on its grid. Each level becomes target
/// `<name>-<level>` (and `<name>-segment` when `segment`): silhouettes and markers from the label's surface,
/// image metrics and heatmaps from the CT volume DRR (Siddon) masked to the label.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CtTarget {
    pub name: String,
    pub ct: PathBuf,
    pub seg: PathBuf,
    /// Label convention of `seg`: `totalseg` or `verse`.
    #[serde(default, with = "super::kinds::label_convention")]
    pub labels: LabelConvention,
    /// Levels (`L1`, `T12`, `vertebrae_L3`) or raw label ids (`"31"`).
    pub levels: Vec<String>,
    /// Landmarks file (one set per level, CT world mm): our JSON, Slicer `.mrk.json`, or VerSe centroids
    /// (voxels of the `seg` grid); default: automatic landmarks of each label surface.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub landmarks: Option<PathBuf>,
    /// Also study the levels together as target `<name>-segment`.
    #[serde(default)]
    pub segment: bool,
    /// How each level is oriented at the world origin: `none` (moved to its body centre only, the
    /// scanner's axes kept) or `anatomical` (also rotated into its automatic-landmark frame, so AP and
    /// LAT are a tilted vertebra's true AP and LAT).
    #[serde(default, with = "super::kinds::alignment")]
    pub align: Alignment,
    /// Taubin λ|μ smoothing iterations of each label's surface (0: the exact 0.5-isosurface of the
    /// voxels). Thick slices (2–3 mm) leave stair steps that automatic landmarks cannot read; about 10
    /// smooths them without shrinking the surface.
    #[serde(default)]
    pub smooth_iterations: usize,
    /// Ray integrator of the CT volume DRR: `siddon` (exact for the piecewise-constant voxels; thick
    /// slices show as steps) or `trilinear` (the interpolated μ field, sampled at ≤ half the smallest
    /// spacing: smooth across thick slices).
    #[serde(default, with = "super::kinds::volume_method")]
    pub method: VolumeMethod,
}

impl CtTarget {
    /// Each level's target name (`<name>-L1`, or `<name>-id31` for a raw id) and its label id.
    pub fn level_targets(&self) -> Result<Vec<(String, u16)>> {
        let conv = self.labels;
        let mut out: Vec<(String, u16)> = Vec::new();
        for spec in &self.levels {
            let id = conv.resolve(spec).map_err(|e| {
                Error::invalid(
                    "anatomy.ct.levels",
                    format!("target '{}': {spec:?}: {e}", self.name),
                )
            })?;
            let tag = match spec.trim().parse::<u16>() {
                Ok(_) => format!("id{id}"),
                Err(_) => conv
                    .level(id)
                    .map_or_else(|| format!("id{id}"), |l| l.to_string()),
            };
            if out.iter().any(|(_, i)| *i == id) {
                return Err(Error::invalid(
                    "anatomy.ct.levels",
                    format!(
                        "target '{}': {spec:?} (label {id}) is listed twice",
                        self.name
                    ),
                ));
            }
            out.push((format!("{}-{tag}", self.name), id));
        }
        Ok(out)
    }

    /// The segment's target name.
    pub fn segment_target(&self) -> String {
        format!("{}-segment", self.name)
    }
}

fn default_mu() -> f64 {
    crate::anatomy::tissue_mu(crate::anatomy::Tissue::Cortical)
}

impl Default for AnatomyConfig {
    fn default() -> Self {
        AnatomyConfig {
            levels: ["L1", "L2", "L3", "L4", "L5"].map(String::from).to_vec(),
            segment: true,
            voxel_mm: 0.8,
            marker_radius_mm: 2.0,
            meshes: Vec::new(),
            ct: Vec::new(),
            dataset: Vec::new(),
        }
    }
}
