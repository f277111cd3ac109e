//! Every product the tool writes (and reads back), each image with its sidecar (built by [`Sidecar`]): DRRs (float TIFF +
//! sidecar + PNG preview), depth maps, silhouette masks, difference images and heatmaps. File names follow
//! the output path as `spinedrr render` documents them: `OUT.tiff`, `OUT.json`, `OUT.png`,
//! `OUT_depth.tiff`, `OUT_mask.png`, `OUT_mask_<object>.png`, `OUT_mask_<structure>.png`.

use std::path::{Path, PathBuf};

use serde::Serialize;
use serde_json::json;

use super::output_set::{Staging, file_names, folder_of};
use super::xray::XrayModel;
use super::{
    ImageF32, Sidecar, check_output_set, kind, remove_stale_temporaries, sidecar_path, units,
    write_heatmap_png, write_mask_png, write_preview_png, write_tiff_f32,
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
    /// A radiograph of the X-ray image model ([`XrayModel`]: Poisson counts, blur, optional log).
    Xray(XrayModel),
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
            DrrValues::Xray(m) if m.log => units::XRAY_LOG,
            DrrValues::Xray(_) => units::XRAY_COUNTS,
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
            DrrValues::Xray(m) => m.apply(line_integral),
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

/// The images of one render, written together by [`write_drr_set`].
#[derive(Debug, Clone, Copy)]
pub struct DrrProducts<'a> {
    /// The line integral (written as `values`; the PNG preview always shows the line integral).
    pub line_integral: &'a ImageF32,
    pub values: DrrValues,
    /// Silhouette masks (`OUT_mask*.png`), none when not asked for.
    pub silhouettes: &'a [Silhouette],
    /// The first-hit depth map (`OUT_depth.tiff`), when asked for.
    pub depth: Option<&'a ImageF32>,
}

/// Every file [`write_drr_set`] writes for `out` (the main sidecar last).
pub fn drr_set_paths(out: &Path, silhouettes: &[Silhouette], depth: bool) -> Vec<PathBuf> {
    let mut paths = Vec::new();
    for s in silhouettes {
        let png = sibling(out, &s.of.suffix(), "png");
        paths.push(sidecar_path(&png));
        paths.push(png);
    }
    if depth {
        let tiff = sibling(out, "depth", "tiff");
        paths.push(sidecar_path(&tiff));
        paths.push(tiff);
    }
    paths.push(out.to_path_buf());
    paths.push(out.with_extension("png"));
    paths.push(sidecar_path(out));
    paths
}

/// The kind of the record at `path` in the DRR set of `out` (its sidecar `drr`, the depth map's `depth`,
/// a mask's `mask`; `None` for an image): an existing spinedrr record of another kind there is refused
/// ([`super::check_output_set`]).
pub fn drr_set_kind(out: &Path, path: &Path) -> Option<&'static str> {
    if path.extension()? != "json" {
        None
    } else if path == sidecar_path(out) {
        Some(kind::DRR)
    } else if path == sidecar_path(&sibling(out, "depth", "tiff")) {
        Some(kind::DEPTH)
    } else {
        Some(kind::MASK)
    }
}

/// Writes the output set of a DRR of `view` (reference geometry) rendered under `perturbation`: the
/// masks and the depth map (each with its sidecar), `out` (float TIFF of the values), `OUT.png` (an 8-bit
/// preview of the line integral) and, last, `OUT.json` (kind `drr`, the producer's `details`, `I0` for an
/// intensity image, and `companions`: the other files of the set).
///
/// Every path is checked first ([`check_output_set`]): when one cannot be written, nothing is. Then
/// temporaries of killed runs are removed and the set is written aside and committed
/// ([`super::output_set::Staging`]): a run that fails while writing leaves the previous set whole, and a
/// set without `OUT.json` is one a run did not finish committing.
pub fn write_drr_set(
    out: &Path,
    products: &DrrProducts,
    view: &View,
    perturbation: &Perturbation,
    details: &impl Serialize,
) -> Result<()> {
    let values = products.values;
    let mut sidecar =
        Sidecar::new(kind::DRR, values.units(), view, perturbation)?.with_details(details)?;
    match values {
        DrrValues::Intensity { i0 } => sidecar = sidecar.with_details(&json!({ "I0": i0 }))?,
        DrrValues::Xray(m) => sidecar = sidecar.with_details(&json!({ "xray_model": m }))?,
        DrrValues::LineIntegral => {}
    }
    let paths = drr_set_paths(out, products.silhouettes, products.depth.is_some());
    check_output_set(&paths, |p| drr_set_kind(out, p))?;
    let folder = folder_of(out);
    remove_stale_temporaries(folder);
    let stem = out.file_name().unwrap_or_default().to_string_lossy();
    let stage = Staging::new(folder, &stem)?;
    let staged = stage.path(out);
    write_masks(&staged, products.silhouettes, view, perturbation)?;
    if let Some(depth) = products.depth {
        write_depth(&staged, depth, view, perturbation)?;
    }
    write_tiff_f32(&staged, &values.apply(products.line_integral))?;
    write_preview_png(&staged.with_extension("png"), products.line_integral, false)?;
    sidecar.companions = file_names(&paths[..paths.len() - 1]);
    sidecar.write(&sidecar_path(&staged))?;
    stage.commit(&paths)
}

/// [`write_drr_set`] of a DRR alone (its TIFF, preview and sidecar).
pub fn write_drr(
    out: &Path,
    line_integral: &ImageF32,
    values: DrrValues,
    view: &View,
    perturbation: &Perturbation,
    details: &impl Serialize,
) -> Result<()> {
    let products = DrrProducts {
        line_integral,
        values,
        silhouettes: &[],
        depth: None,
    };
    write_drr_set(out, &products, view, perturbation, details)
}

/// Reads a DRR written with its sidecar: one page of float samples ([`super::image::read_drr_tiff`])
/// beside its `name.json`, checking that the two agree on the size.
pub fn read_with_sidecar(path: &Path) -> Result<(ImageF32, Sidecar)> {
    let img = super::image::read_drr_tiff(path)?;
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

/// Every file of `spinedrr compare`'s output set in `dir`: [`write_difference`]'s four, then the marker
/// `metrics.json`.
pub fn difference_set_paths(dir: &Path) -> Vec<PathBuf> {
    [
        "absdiff.tiff",
        "absdiff.json",
        "heatmap.png",
        "heatmap.json",
        "metrics.json",
    ]
    .map(|f| dir.join(f))
    .to_vec()
}

/// The kind of the record at `path` in `compare`'s output set (`absdiff.json`, `heatmap.json`,
/// `metrics.json`).
pub fn difference_set_kind(path: &Path) -> Option<&'static str> {
    match path.file_name()?.to_str()? {
        "absdiff.json" => Some(kind::ABS_DIFFERENCE),
        "heatmap.json" => Some(kind::HEATMAP),
        "metrics.json" => Some(kind::METRICS),
        _ => None,
    }
}

/// Writes [`write_difference`]'s images and then `marker` (the set's record, e.g. `metrics.json`, a JSON
/// object given `companions`: the other files) under the protocol of [`write_drr_set`]: every path checked
/// first, stale temporaries and the previous marker removed, the marker last.
pub fn write_difference_set(
    dir: &Path,
    diff: &ImageF32,
    base: &Sidecar,
    details: &impl Serialize,
    marker: serde_json::Map<String, serde_json::Value>,
) -> Result<()> {
    let paths = difference_set_paths(dir);
    check_output_set(&paths, difference_set_kind)?;
    remove_stale_temporaries(dir);
    let (marker_path, companions) = paths
        .split_last()
        .ok_or_else(|| Error::Internal("a difference set without a marker".into()))?;
    let stage = Staging::new(dir, "difference")?;
    write_difference(stage.dir(), diff, base, details)?;
    let mut marker = marker;
    marker.insert("companions".into(), json!(file_names(companions)));
    // Through a JSON value: its keys come out sorted.
    super::write_json(&stage.path(marker_path), &serde_json::Value::Object(marker))?;
    stage.commit(&paths)
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
