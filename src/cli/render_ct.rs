//! CT volume DRR options of `spinedrr render` (`--ct`, `--seg`, `--label`, …) and their runner.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use spinedrr::anatomy::MU_WATER_PER_MM;
use spinedrr::anatomy::ct::{read_ct, read_labels};
use spinedrr::anatomy::labels::LabelConvention;
use spinedrr::geometry::{Perturbation, View};
use spinedrr::io::{DrrValues, write_drr};
use spinedrr::render::volume::{
    VolumeDetails, VolumeMethod, VolumeRenderOptions, VolumeRenderer, select_voxels,
};

/// Flags of a CT volume DRR.
#[derive(clap::Args, Debug, Clone)]
pub struct CtArgs {
    /// CT volume (NIfTI-1 `.nii` / `.nii.gz`, Hounsfield units) to render instead of meshes.
    #[arg(long, value_name = "CT.nii.gz")]
    pub ct: Option<PathBuf>,
    /// Segmentation on the CT's grid; with `--label`, only that label's voxels are rendered.
    #[arg(long, requires = "label")]
    pub seg: Option<PathBuf>,
    /// Label to render: a level name (`L1`, `T12`) in the `--labels` convention, or a raw integer id.
    #[arg(long, requires = "seg")]
    pub label: Option<String>,
    /// Label convention of `--seg`: totalseg (TotalSegmentator v2) or verse.
    #[arg(long, default_value = "totalseg")]
    pub labels: String,
    /// Render only voxels at or above this HU (e.g. 150 for bone).
    #[arg(long)]
    pub bone_hu: Option<f32>,
    /// Ray integrator: siddon (exact voxel traversal) or trilinear.
    #[arg(long, default_value = "siddon")]
    pub method: String,
    /// μ of water (mm⁻¹) in μ(HU) = μ_water · max(0, 1 + HU/1000).
    #[arg(long, default_value_t = MU_WATER_PER_MM)]
    pub mu_water: f64,
    /// Trilinear step (mm), capped at half the smallest voxel spacing.
    #[arg(long)]
    pub step_mm: Option<f64>,
}

/// Renders the CT DRR of `view` under `perturbation` to `out` (float32 TIFF of `values`), with its JSON
/// sidecar and an 8-bit PNG preview beside it.
pub fn run_ct(
    a: &CtArgs,
    view: &View,
    perturbation: &Perturbation,
    values: DrrValues,
    out: &Path,
) -> anyhow::Result<()> {
    let Some(ct_path) = &a.ct else {
        bail!("--ct is required for a CT render");
    };
    let method: VolumeMethod = a.method.parse()?;
    let convention: LabelConvention = a.labels.parse()?;
    let ct = read_ct(ct_path).with_context(|| format!("reading CT {}", ct_path.display()))?;
    let label = match (&a.seg, &a.label) {
        (Some(seg_path), Some(spec)) => {
            let id = convention.resolve(spec)?;
            let seg = read_labels(seg_path)
                .with_context(|| format!("reading segmentation {}", seg_path.display()))?;
            Some((seg_path, spec, seg, id))
        }
        _ => None,
    };
    let mask = select_voxels(
        &ct,
        label.as_ref().map(|(_, _, seg, id)| (seg, *id)),
        a.bone_hu,
    )
    .with_context(|| match &label {
        Some((seg_path, spec, _, id)) => {
            format!("label {spec} (id {id}) in {}", seg_path.display())
        }
        None => "--bone-hu".into(),
    })?;
    let opts = VolumeRenderOptions {
        method,
        mu_water: a.mu_water,
        step_mm: a.step_mm,
    };
    let renderer = VolumeRenderer::new(&ct, &opts, mask.as_ref())?;
    let img = renderer.render(&view.perturbed(perturbation)?);
    let inputs = CtInputs {
        ct: ct_path.display().to_string(),
        seg: a.seg.as_ref().map(|p| p.display().to_string()),
        label: a.label.clone(),
        labels: convention.to_string(),
        bone_hu: a.bone_hu,
        render: renderer.details(),
    };
    write_drr(out, &img, values, view, perturbation, &inputs)
        .with_context(|| format!("writing {}", out.display()))
}

/// The CT render's sidecar `details`: the inputs as given, and the renderer's record.
#[derive(serde::Serialize)]
struct CtInputs {
    ct: String,
    seg: Option<String>,
    label: Option<String>,
    labels: String,
    bone_hu: Option<f32>,
    #[serde(flatten)]
    render: VolumeDetails,
}
