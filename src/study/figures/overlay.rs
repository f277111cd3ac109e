//! Landmark overlay figures, as the paper shows them: the reference DRR of a target in a view with each
//! landmark's reference position and its measured position under the largest focal Δf, the displacement
//! magnified into an arrow, the homography prediction H·x at the arrow's scale, each landmark numbered
//! (the names in a key below the panes). AP and LAT of a target are drawn at one scale (the same
//! detector window size, a scale bar in mm at the detector). Drawing is in [`super::overlay_draw`].

use std::path::Path;

use super::canvas::write_figure;
use super::overlay_draw::{Overlay, OverlayRow};
use super::overlay_points::{Point, gain};
use crate::Result;
use crate::io::read_tiff_f32;
use crate::study::experiments::reference_image_path;
use crate::study::schema::{Family, LandmarkRow};

/// What [`landmark_overlays`] drew for one target: the AP-beside-LAT figure and its conditions.
pub struct OverlayFigure {
    pub target: String,
    /// The composed figure's file name (views side by side).
    pub file: String,
    pub views: Vec<String>,
    pub df_px: f64,
    /// Arrow magnification.
    pub gain: f64,
    pub landmarks: usize,
    /// The scale bar's unit: mm at the detector (`true`) or detector px.
    pub scale_in_mm: bool,
}

/// `L3/center` → (`Some("L3")`, `center`); `center` → (`None`, `center`).
fn split_level(name: &str) -> (Option<&str>, &str) {
    match name.split_once('/') {
        Some((level, base)) => (Some(level), base),
        None => (None, name),
    }
}

/// The key of a target's landmarks: their names without the level, in order of first appearance (one
/// number per name, the same on every level and in every view).
pub(super) fn key_names(rows: &[&LandmarkRow]) -> Vec<String> {
    super::distinct(rows.iter().map(|r| split_level(&r.landmark).1))
        .into_iter()
        .map(str::to_string)
        .collect()
}

/// One overlay per target and view (of the focal rows of `rows`), on the reference DRR under `out`,
/// and per target the views side by side at one arrow magnification and one scale
/// (`landmarks_<target>.png`). `mm_per_px`: the detector's u pixel spacing, for the scale bar.
pub fn landmark_overlays(
    out: &Path,
    rows: &[LandmarkRow],
    figs: &Path,
    mm_per_px: Option<f64>,
) -> Result<Vec<OverlayFigure>> {
    let focal: Vec<&LandmarkRow> = rows.iter().filter(|r| r.family == Family::Focal).collect();
    let mut made = Vec::new();
    for target in super::distinct(focal.iter().map(|r| r.target.as_str())) {
        let of_target: Vec<&LandmarkRow> = focal
            .iter()
            .copied()
            .filter(|r| r.target == target)
            .collect();
        let key = key_names(&of_target);
        let df_max = of_target
            .iter()
            .map(|r| r.df_px)
            .fold(f64::NEG_INFINITY, f64::max);
        let views = super::distinct(of_target.iter().map(|r| r.view.to_string()));
        let mut row = Vec::new();
        for view in &views {
            let pts = points(&of_target, view, df_max, &key);
            let image_path = reference_image_path(out, target, view);
            let drr = image_path
                .exists()
                .then(|| read_tiff_f32(&image_path))
                .transpose()?;
            let g = gain(&pts);
            let o = Overlay {
                title: overlay_title(target, view, df_max, g, drr.is_some()),
                pts,
                g,
                drr,
            };
            let file = figs.join(format!("landmark_overlay_{target}_{view}.png"));
            let single = OverlayRow {
                overlays: vec![o],
                key: key.clone(),
                mm_per_px,
            };
            write_figure(&file, &single)?;
            row.extend(single.overlays);
        }
        // One magnification for every view, so AP and LAT arrows compare by length.
        let g = row.iter().map(|o| o.g).fold(f64::INFINITY, f64::min);
        let landmarks = row.iter().map(|o| o.pts.len()).max().unwrap_or(0);
        for (o, view) in row.iter_mut().zip(&views) {
            o.g = g;
            o.title = overlay_title(target, view, df_max, g, o.drr.is_some());
        }
        let file = format!("landmarks_{target}.png");
        let composed = OverlayRow {
            overlays: row,
            key,
            mm_per_px,
        };
        write_figure(&figs.join(&file), &composed)?;
        made.push(OverlayFigure {
            target: target.to_string(),
            file,
            views,
            df_px: df_max,
            gain: g,
            landmarks,
            scale_in_mm: mm_per_px.is_some(),
        });
    }
    Ok(made)
}

fn overlay_title(target: &str, view: &str, df: f64, g: f64, has_drr: bool) -> String {
    let missing = if has_drr {
        ""
    } else {
        " (no reference DRR found)"
    };
    format!(
        "{target} {}: focal Δf {df} px, arrows ×{g}{missing}",
        view.to_uppercase()
    )
}

/// The landmarks of one view at `df` whose reference, measured and predicted positions are all known.
fn points(rows: &[&LandmarkRow], view: &str, df: f64, key: &[String]) -> Vec<Point> {
    rows.iter()
        .filter(|r| r.view == view && r.df_px == df)
        .map(|r| {
            let (level, base) = split_level(&r.landmark);
            (
                r,
                level.map(str::to_string),
                key.iter().position(|k| k == base),
            )
        })
        .map(|(r, level, k)| Point {
            key: k.map_or(0, |k| k + 1),
            level,
            reference: (r.ref_u_px, r.ref_v_px),
            measured: (r.meas_u_px, r.meas_v_px),
            predicted: (r.pred_u_px, r.pred_v_px),
        })
        .filter(|p| {
            [p.reference, p.measured, p.predicted]
                .iter()
                .all(|q| q.0.is_finite() && q.1.is_finite())
        })
        .collect()
}
