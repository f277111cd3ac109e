//! One reference/perturbed comparison: image similarity, per-structure silhouette metrics and landmark
//! shifts, gathered into a serialisable record (`metrics.json` of `spinedrr compare`).

use std::path::Path;

use serde::Serialize;

use super::{
    ContourDistances, Landmark, LandmarkShift, Region, contour_points, dice_iou, edge_distance,
    gradient_correlation_in, gradient_correlation_whole_and_in, landmark_shifts,
    mutual_information_in, ncc_in, ssim_in, ssim_whole_and_in, subpixel_boundary,
};
use crate::geometry::View;
use crate::io::ImageF32;
use crate::{Error, Result};

/// Histogram bins per axis of the mutual information in [`image_metrics`].
pub const MI_BINS: usize = 64;

/// A named pair of binary silhouettes of the same size.
#[derive(Debug, Clone, PartialEq)]
pub struct MaskPair {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub reference: Vec<bool>,
    pub perturbed: Vec<bool>,
}

impl MaskPair {
    /// Whether either silhouette has a pixel on the detector's border: the detector cuts it, so its
    /// overlap and contour metrics are of the visible part only.
    pub fn touches_edge(&self) -> bool {
        let (w, h) = (self.width as usize, self.height as usize);
        let edge = |m: &[bool]| {
            (0..w).any(|u| m[u] || m[(h - 1) * w + u])
                || (0..h).any(|v| m[v * w] || m[v * w + w - 1])
        };
        w > 0
            && h > 0
            && self.reference.len() == w * h
            && self.perturbed.len() == w * h
            && (edge(&self.reference) || edge(&self.perturbed))
    }
}

/// Similarity of the two DRRs.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ImageMetrics {
    pub ncc: f64,
    pub ssim: f64,
    pub mutual_information_nats: f64,
    pub mutual_information_bins: usize,
    pub gradient_correlation: f64,
    pub mean_abs_diff: f64,
    pub max_abs_diff: f64,
}

/// Overlap and contour distances of one structure's silhouettes (distances in px).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SilhouetteMetrics {
    pub name: String,
    pub dice: f64,
    pub iou: f64,
    pub contour_points_reference: usize,
    pub contour_points_perturbed: usize,
    /// The paper's one-sided sum `Σ_{x ∈ C_gt} min_y ‖x − y‖`.
    pub chamfer_sum_px: f64,
    pub chamfer_mean_px: f64,
    pub hausdorff_px: f64,
    pub hd95_px: f64,
    pub edge_distance_mean_px: f64,
    pub edge_distance_max_px: f64,
    /// Symmetric mean Chamfer and Hausdorff of the sub-pixel boundaries (half-pixel edge crossings).
    pub chamfer_mean_subpixel_px: f64,
    pub hausdorff_subpixel_px: f64,
}

/// Everything `spinedrr compare` measures.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Comparison {
    pub image: ImageMetrics,
    pub silhouettes: Vec<SilhouetteMetrics>,
    pub landmarks: Vec<LandmarkShift>,
}

/// NCC, SSIM, MI ([`MI_BINS`] bins), gradient correlation and the absolute-difference summary.
pub fn image_metrics(reference: &ImageF32, perturbed: &ImageF32) -> Result<ImageMetrics> {
    image_metrics_in(reference, perturbed, None)
}

/// [`image_metrics`] with NCC, SSIM, MI and gradient correlation over `region` (all pixels when
/// `None`); the absolute differences stay over the whole image.
pub fn image_metrics_in(
    reference: &ImageF32,
    perturbed: &ImageF32,
    region: Option<&Region>,
) -> Result<ImageMetrics> {
    let ((n, s), (m, g)) = rayon::join(
        || {
            (
                ncc_in(reference, perturbed, region),
                ssim_in(reference, perturbed, region),
            )
        },
        || {
            (
                mutual_information_in(reference, perturbed, MI_BINS, region),
                gradient_correlation_in(reference, perturbed, region),
            )
        },
    );
    let (mean_abs_diff, max_abs_diff) = abs_diffs(reference, perturbed);
    Ok(ImageMetrics {
        ncc: n?,
        ssim: s?,
        mutual_information_nats: m?,
        mutual_information_bins: MI_BINS,
        gradient_correlation: g?,
        mean_abs_diff,
        max_abs_diff,
    })
}

/// Mean and maximum |a − b| over every pixel.
fn abs_diffs(reference: &ImageF32, perturbed: &ImageF32) -> (f64, f64) {
    let (sum, max) = reference
        .data
        .iter()
        .zip(&perturbed.data)
        .map(|(a, b)| f64::from((a - b).abs()))
        .fold((0.0, 0.0f64), |(s, m), d| (s + d, m.max(d)));
    (sum / reference.data.len().max(1) as f64, max)
}

/// [`image_metrics`] over the whole image and over `region` (NCC, SSIM, MI, gradient correlation; the
/// absolute differences are the whole image's in both), SSIM and gradient correlation from one pass.
pub fn image_metrics_whole_and_in(
    reference: &ImageF32,
    perturbed: &ImageF32,
    region: &Region,
) -> Result<(ImageMetrics, ImageMetrics)> {
    let ((s, g), (n, m)) = rayon::join(
        || {
            rayon::join(
                || ssim_whole_and_in(reference, perturbed, region),
                || gradient_correlation_whole_and_in(reference, perturbed, region),
            )
        },
        || {
            let pair = |r: Option<&Region>| {
                Ok::<_, Error>((
                    ncc_in(reference, perturbed, r)?,
                    mutual_information_in(reference, perturbed, MI_BINS, r)?,
                ))
            };
            (pair(None), pair(Some(region)))
        },
    );
    let ((s_all, s_in), (g_all, g_in), (n_all, m_all), (n_in, m_in)) = (s?, g?, n?, m?);
    let (mean_abs_diff, max_abs_diff) = abs_diffs(reference, perturbed);
    let metrics = |ncc, ssim, mi, gc| ImageMetrics {
        ncc,
        ssim,
        mutual_information_nats: mi,
        mutual_information_bins: MI_BINS,
        gradient_correlation: gc,
        mean_abs_diff,
        max_abs_diff,
    };
    Ok((
        metrics(n_all, s_all, m_all, g_all),
        metrics(n_in, s_in, m_in, g_in),
    ))
}

/// Dice, IoU, contour distances (OpenCV contours) and the edge-based distance of one mask pair.
pub fn silhouette_metrics(pair: &MaskPair) -> Result<SilhouetteMetrics> {
    let field = |e: Error| Error::invalid(format!("mask '{}'", pair.name), e.to_string());
    let (w, h) = (pair.width, pair.height);
    let (dice, iou) = dice_iou(&pair.reference, &pair.perturbed).map_err(field)?;
    let ca = contour_points(&pair.reference, w, h).map_err(field)?;
    let cb = contour_points(&pair.perturbed, w, h).map_err(field)?;
    let d = ContourDistances::between(&ca, &cb).map_err(field)?;
    let (edge_mean, edge_max) =
        edge_distance(&pair.reference, &pair.perturbed, w, h).map_err(field)?;
    let sa = subpixel_boundary(&pair.reference, w, h).map_err(field)?;
    let sb = subpixel_boundary(&pair.perturbed, w, h).map_err(field)?;
    let ds = ContourDistances::between(&sa, &sb).map_err(field)?;
    Ok(SilhouetteMetrics {
        name: pair.name.clone(),
        dice,
        iou,
        contour_points_reference: ca.len(),
        contour_points_perturbed: cb.len(),
        chamfer_sum_px: d.chamfer_sum(),
        chamfer_mean_px: d.chamfer_mean(),
        hausdorff_px: d.hausdorff(),
        hd95_px: d.hd95(),
        edge_distance_mean_px: edge_mean,
        edge_distance_max_px: edge_max,
        chamfer_mean_subpixel_px: ds.chamfer_mean(),
        hausdorff_subpixel_px: ds.hausdorff(),
    })
}

/// The union of several mask pairs (the whole vertebra from its structures), named `name`.
pub fn union_masks(pairs: &[MaskPair], name: &str) -> Result<MaskPair> {
    let first = pairs
        .first()
        .ok_or_else(|| Error::invalid("masks", "no mask pairs"))?;
    let mut out = MaskPair {
        name: name.into(),
        ..first.clone()
    };
    for p in &pairs[1..] {
        if (p.width, p.height) != (out.width, out.height) {
            return Err(Error::invalid(
                format!("mask '{}'", p.name),
                "size differs from the others",
            ));
        }
        out.reference
            .iter_mut()
            .zip(&p.reference)
            .for_each(|(a, b)| *a |= b);
        out.perturbed
            .iter_mut()
            .zip(&p.perturbed)
            .for_each(|(a, b)| *a |= b);
    }
    Ok(out)
}

/// Runs every metric. With more than one mask pair and none called `vertebra`, a `vertebra` entry (the
/// union) is added. Landmarks need both views.
pub fn compare(
    reference: &ImageF32,
    perturbed: &ImageF32,
    masks: &[MaskPair],
    landmarks: &[Landmark],
    views: Option<(&View, &View)>,
) -> Result<Comparison> {
    let image = image_metrics(reference, perturbed)?;
    let mut pairs = masks.to_vec();
    if pairs.len() > 1 && !pairs.iter().any(|p| p.name == "vertebra") {
        pairs.push(union_masks(masks, "vertebra")?);
    }
    let silhouettes = pairs
        .iter()
        .map(silhouette_metrics)
        .collect::<Result<Vec<_>>>()?;
    let landmarks = match views {
        Some((r, p)) => {
            in_front_of_both(r, p, landmarks)?;
            landmark_shifts(r, p, landmarks)
        }
        None if landmarks.is_empty() => Vec::new(),
        None => {
            return Err(Error::invalid(
                "landmarks",
                "landmark shifts need both images' views",
            ));
        }
    };
    Ok(Comparison {
        image,
        silhouettes,
        landmarks,
    })
}

/// Refuses a landmark at or behind either view's source (camera depth ≤ 0): it has no projection, and
/// the pinhole formula would put it on the detector mirrored. The error names the landmark, the view
/// and the depth — usually a file in another frame or unit.
fn in_front_of_both(reference: &View, perturbed: &View, landmarks: &[Landmark]) -> Result<()> {
    for l in landmarks {
        for (which, v) in [("reference", reference), ("perturbed", perturbed)] {
            let depth = v.depth(l.position);
            // Positions are finite (the readers refuse others), so the depth is too.
            if depth <= 0.0 {
                return Err(Error::invalid(
                    "landmarks",
                    format!(
                        "landmark '{}' at ({:.1}, {:.1}, {:.1}) mm is {} the {which} view '{}''s source \
                         (depth {depth:.1} mm along its central ray): it cannot be projected; check the \
                         landmark file's frame and units (world mm, RAS+ unless it says otherwise)",
                        l.name,
                        l.position.x,
                        l.position.y,
                        l.position.z,
                        if depth == 0.0 { "level with" } else { "behind" },
                        v.name
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Reads an 8-bit mask PNG (any non-zero grey value is inside). Returns `(width, height, mask)`.
pub fn read_mask_png(path: &Path) -> Result<(u32, u32, Vec<bool>)> {
    let img = image::open(path)
        .map_err(|e| Error::format(path, format!("not a readable PNG mask: {e}")))?
        .into_luma8();
    let (w, h) = img.dimensions();
    Ok((w, h, img.into_raw().into_iter().map(|v| v > 0).collect()))
}
