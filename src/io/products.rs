//! Every product the tool writes (and reads back), each image with its sidecar (built by [`Sidecar`]): DRRs (float TIFF +
//! sidecar + PNG preview), depth maps, silhouette masks, difference images and heatmaps. File names follow
//! the output path as `spinedrr render` documents them: `OUT.tiff`, `OUT.json`, `OUT.png`,
//! `OUT_depth.tiff`, `OUT_mask.png`, `OUT_mask_<object>.png`, `OUT_mask_<structure>.png`.

use std::path::{Path, PathBuf};

use serde::Serialize;
use serde_json::json;

use super::{
    ImageF32, Sidecar, kind, read_tiff_f32, sidecar_path, units, write_heatmap_png, write_mask_png,
    write_preview_png, write_tiff_f32,
};
use crate::geometry::{Perturbation, View};
use crate::{Error, Result};

/// What the pixels of a DRR file hold.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DrrValues {
    /// The line integral `L = ∫μ dl` itself.
    LineIntegral,
    /// The transmitted intensity `I = I0 · exp(−L)` (Beer–Lambert), a radiograph's look.
    Intensity { i0: f64 },
}

impl DrrValues {
    /// Intensity with `Some(i0)` (a positive number), else the line integral.
    pub fn new(intensity_i0: Option<f64>) -> Result<Self> {
        match intensity_i0 {
            None => Ok(DrrValues::LineIntegral),
            Some(i0) if i0.is_finite() && i0 > 0.0 => Ok(DrrValues::Intensity { i0 }),
            Some(i0) => Err(Error::invalid(
                "I0",
                format!("{i0} must be a positive number"),
            )),
        }
    }

    /// The sidecar's `units` of these values.
    pub fn units(&self) -> &'static str {
        match self {
            DrrValues::LineIntegral => units::LINE_INTEGRAL,
            DrrValues::Intensity { .. } => units::INTENSITY,
        }
    }

    /// These values of a line-integral image (per pixel `I0 · exp(−L)` for intensity, in f64).
    pub fn apply(&self, line_integral: &ImageF32) -> ImageF32 {
        match *self {
            DrrValues::LineIntegral => line_integral.clone(),
            DrrValues::Intensity { i0 } => ImageF32 {
                data: line_integral
                    .data
                    .iter()
                    .map(|&l| (i0 * (-f64::from(l)).exp()) as f32)
                    .collect(),
                ..*line_integral
            },
        }
    }
}

/// `OUT_<suffix>.<ext>` beside `OUT`.
pub fn sibling(out: &Path, suffix: &str, ext: &str) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    out.with_file_name(format!("{stem}_{suffix}.{ext}"))
}

/// Writes a DRR of `view` (reference geometry) rendered under `perturbation`: `out` (float TIFF of
/// `values` of the line integral), its sidecar (kind `drr`, the producer's `details`, and `I0` for an
/// intensity image) and `out` with extension `.png` (an 8-bit preview of the line integral).
pub fn write_drr(
    out: &Path,
    line_integral: &ImageF32,
    values: DrrValues,
    view: &View,
    perturbation: &Perturbation,
    details: &impl Serialize,
) -> Result<()> {
    let mut sidecar =
        Sidecar::new(kind::DRR, values.units(), view, perturbation)?.with_details(details)?;
    if let DrrValues::Intensity { i0 } = values {
        sidecar = sidecar.with_details(&json!({ "I0": i0 }))?;
    }
    write_tiff_f32(out, &values.apply(line_integral))?;
    sidecar.write(&sidecar_path(out))?;
    write_preview_png(&out.with_extension("png"), line_integral, false)
}

/// Reads an image written with its sidecar (a DRR, or any float TIFF beside a `name.json`), checking
/// that the two agree on the size.
pub fn read_with_sidecar(path: &Path) -> Result<(ImageF32, Sidecar)> {
    let img = read_tiff_f32(path)?;
    let sc_path = sidecar_path(path);
    let sc = Sidecar::read(&sc_path)?;
    if (sc.width, sc.height) != (img.width, img.height) {
        return Err(Error::format(
            &sc_path,
            format!(
                "sidecar says {}×{}, image is {}×{}",
                sc.width, sc.height, img.width, img.height
            ),
        ));
    }
    Ok((img, sc))
}

/// Writes the depth map of the DRR `out` as `OUT_depth.tiff` with its sidecar (kind `depth`, mm).
pub fn write_depth(
    out: &Path,
    depth: &ImageF32,
    view: &View,
    perturbation: &Perturbation,
) -> Result<()> {
    let path = sibling(out, "depth", "tiff");
    write_tiff_f32(&path, depth)?;
    Sidecar::new(kind::DEPTH, units::DEPTH_MM, view, perturbation)?.write(&sidecar_path(&path))
}

/// What a silhouette outlines.
#[derive(Debug, Clone, PartialEq)]
pub enum SilhouetteOf {
    /// Every object of the render together (`OUT_mask.png`).
    AllObjects,
    /// One object, e.g. a vertebra level or a mesh file (`OUT_mask_<object>.png`).
    Object(String),
    /// One anatomical structure over all objects (`OUT_mask_<structure>.png`).
    Structure(&'static str),
}

impl SilhouetteOf {
    /// The file suffix after `OUT_`.
    fn suffix(&self) -> String {
        match self {
            SilhouetteOf::AllObjects => "mask".into(),
            SilhouetteOf::Object(name) => format!("mask_{name}"),
            SilhouetteOf::Structure(name) => format!("mask_{name}"),
        }
    }

    /// The sidecar's `details.silhouette_of`.
    fn describe(&self) -> serde_json::Value {
        match self {
            SilhouetteOf::AllObjects => json!("all objects"),
            SilhouetteOf::Object(name) => json!({ "object": name }),
            SilhouetteOf::Structure(name) => json!({ "structure": name }),
        }
    }
}

/// One silhouette mask of a render: row-major, `true` inside.
#[derive(Debug, Clone, PartialEq)]
pub struct Silhouette {
    pub of: SilhouetteOf,
    pub pixels: Vec<bool>,
}

/// Writes each silhouette of the DRR `out` as an 8-bit PNG beside it (see [`SilhouetteOf`] for the names)
/// with its sidecar (kind `mask`, `details.silhouette_of`).
pub fn write_masks(
    out: &Path,
    silhouettes: &[Silhouette],
    view: &View,
    perturbation: &Perturbation,
) -> Result<()> {
    let base = Sidecar::new(kind::MASK, units::SILHOUETTE, view, perturbation)?;
    for s in silhouettes {
        let path = sibling(out, &s.of.suffix(), "png");
        write_mask_png(&path, base.width, base.height, &s.pixels)?;
        base.clone()
            .with_details(&json!({ "silhouette_of": s.of.describe() }))?
            .write(&sidecar_path(&path))?;
    }
    Ok(())
}

/// Writes `diff = |A − B|` of two DRRs into `dir` as `absdiff.tiff` (kind `abs_difference`) and
/// `heatmap.png` (kind `heatmap`), each with a sidecar derived from `base` (the sidecar of B) plus
/// `details`.
pub fn write_difference(
    dir: &Path,
    diff: &ImageF32,
    base: &Sidecar,
    details: &impl Serialize,
) -> Result<()> {
    let sidecar = base.clone().with_details(details)?;
    let tiff = dir.join("absdiff.tiff");
    write_tiff_f32(&tiff, diff)?;
    sidecar
        .derived(kind::ABS_DIFFERENCE)
        .write(&sidecar_path(&tiff))?;
    write_heatmap_png(&dir.join("heatmap.png"), diff, &sidecar)
}

/// Writes the heatmap PNG of `diff = |A − B|`, the difference of the line-integral DRRs of `view` (A,
/// reference) and of `view` under `perturbation` (B), with its sidecar (kind `heatmap`, `K` of the
/// perturbed view, `K_reference` of `view`, the producer's `details`).
pub fn write_difference_heatmap(
    path: &Path,
    diff: &ImageF32,
    view: &View,
    perturbation: &Perturbation,
    details: &impl Serialize,
) -> Result<()> {
    let sidecar = Sidecar::new(
        kind::HEATMAP,
        units::LINE_INTEGRAL_DIFFERENCE,
        view,
        perturbation,
    )?
    .with_details(details)?;
    write_heatmap_png(path, diff, &sidecar)
}
