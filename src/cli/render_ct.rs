//! CT volume DRR options of `spinedrr render` (`--ct`, `--seg`, `--label`, …) and their runner.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use spinedrr::anatomy::ct::{VoxelMask, read_ct, read_labels};
use spinedrr::anatomy::labels::LabelConvention;
use spinedrr::geometry::{Perturbation, View};
use spinedrr::io::{Sidecar, sidecar_path, write_preview_png, write_tiff_f32};
use spinedrr::render::volume::{MU_WATER_70KEV, VolumeMethod, VolumeRenderOptions, VolumeRenderer};

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
    #[arg(long, default_value_t = MU_WATER_70KEV)]
    pub mu_water: f64,
    /// Trilinear step (mm), capped at half the smallest voxel spacing.
    #[arg(long)]
    pub step_mm: Option<f64>,
}

/// Renders the CT DRR of `view` under `perturbation` to `out` (float32 TIFF), with its JSON sidecar
/// and an 8-bit PNG preview beside it.
pub fn run_ct(
    a: &CtArgs,
    view: &View,
    perturbation: &Perturbation,
    out: &Path,
) -> anyhow::Result<()> {
    let Some(ct_path) = &a.ct else {
        bail!("--ct is required for a CT render");
    };
    let method: VolumeMethod = a.method.parse()?;
    let convention: LabelConvention = a.labels.parse()?;
    let ct = read_ct(ct_path).with_context(|| format!("reading CT {}", ct_path.display()))?;
    let mut mask = None;
    if let (Some(seg_path), Some(spec)) = (&a.seg, &a.label) {
        let id = convention.resolve(spec)?;
        let seg = read_labels(seg_path)
            .with_context(|| format!("reading segmentation {}", seg_path.display()))?;
        if !ct.same_grid(&seg) {
            bail!(
                "segmentation {} is not on the CT's grid (dims {:?} vs {:?}, or a different affine)",
                seg_path.display(),
                seg.dims,
                ct.dims
            );
        }
        let m = VoxelMask::from_labels(&seg, &[id])
            .with_context(|| format!("label {spec} (id {id}) in {}", seg_path.display()))?;
        mask = Some(m);
    }
    if let Some(hu) = a.bone_hu {
        let bone = VoxelMask::from_threshold(&ct, hu)?;
        mask = Some(match mask {
            Some(m) => intersect(&ct, &m, &bone)?,
            None => bone,
        });
    }
    let opts = VolumeRenderOptions {
        method,
        mu_water: a.mu_water,
        step_mm: a.step_mm,
    };
    let renderer = VolumeRenderer::new(&ct, &opts, mask.as_ref())?;
    let img = renderer.render(&view.perturbed(perturbation)?);
    write_tiff_f32(out, &img).with_context(|| format!("writing {}", out.display()))?;
    let mut side = Sidecar::new("drr", "line integral of mu (unitless)", view, perturbation)?;
    let details = serde_json::json!({
        "renderer": "ct-volume", "method": method.to_string(), "mu_water_per_mm": a.mu_water,
        "step_mm": renderer.step_mm(), "ct": ct_path.display().to_string(),
        "seg": a.seg.as_ref().map(|p| p.display().to_string()), "label": a.label,
        "labels": convention.to_string(), "bone_hu": a.bone_hu,
    });
    if let serde_json::Value::Object(map) = details {
        side.details = map;
    }
    side.write(&sidecar_path(out))?;
    write_preview_png(&out.with_extension("png"), &img, false)?;
    Ok(())
}

fn intersect(
    ct: &spinedrr::anatomy::ct::CtVolume,
    a: &VoxelMask,
    b: &VoxelMask,
) -> anyhow::Result<VoxelMask> {
    let keep = a.keep.iter().zip(&b.keep).map(|(x, y)| *x && *y).collect();
    VoxelMask::from_keep(ct, keep).context("no voxel of the label reaches the --bone-hu threshold")
}
