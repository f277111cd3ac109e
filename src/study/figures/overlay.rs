//! Landmark overlay figures, as the paper shows them: the reference DRR of a target in a view with each
//! landmark's reference position and its measured position under the largest focal Δf, the displacement
//! magnified into an arrow, the homography prediction H·x at the arrow's scale, each landmark numbered
//! (the names in a key below the panes). AP and LAT of a target are drawn at one scale (the same
//! detector window size, a scale bar in mm at the detector). Drawing is in [`super::overlay_draw`].

use std::path::Path;

use super::canvas::write_figure;
use super::overlay_draw::{Overlay, OverlayRow};
use crate::Result;
use crate::io::read_tiff_f32;
use crate::study::experiments::reference_image_path;
use crate::study::schema::{Family, LandmarkRow};

/// Candidate magnifications of the displacement arrows, largest first.
const GAINS: [f64; 6] = [50.0, 20.0, 10.0, 5.0, 2.0, 1.0];

/// One landmark in an overlay: its key number, level (a segment's `L3/center` → `L3`), reference,
/// measured and predicted positions (px).
pub(super) struct Point {
    pub key: usize,
    pub level: Option<String>,
    pub reference: (f64, f64),
    pub measured: (f64, f64),
    pub predicted: (f64, f64),
}

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

/// The arrow magnification: the largest of [`GAINS`] that keeps the longest arrow within a fifth of
/// the landmarks' spread (1 when the shifts are already that large).
pub(super) fn gain(pts: &[Point]) -> f64 {
    let (mut spread, mut longest) = (0.0f64, 0.0f64);
    for p in pts {
        for q in pts {
            spread =
                spread.max((p.reference.0 - q.reference.0).hypot(p.reference.1 - q.reference.1));
        }
        for y in [p.measured, p.predicted] {
            longest = longest.max((y.0 - p.reference.0).hypot(y.1 - p.reference.1));
        }
    }
    let limit = 0.2 * spread.max(50.0);
    GAINS
        .into_iter()
        .find(|g| g * longest <= limit)
        .unwrap_or(1.0)
}

/// `x + g · (y − x)`.
pub(super) fn tip(x: (f64, f64), y: (f64, f64), g: f64) -> (f64, f64) {
    (x.0 + g * (y.0 - x.0), x.1 + g * (y.1 - x.1))
}

/// The detector window shown: every point and arrow tip with a margin, widened to the plot's aspect
/// ratio `aspect` (width / height) so DRR pixels stay square.
pub(super) fn window(pts: &[Point], g: f64, aspect: f64) -> ((f64, f64), (f64, f64)) {
    let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in pts {
        let tips = [
            tip(p.reference, p.measured, g),
            tip(p.reference, p.predicted, g),
        ];
        for (u, v) in [p.reference, p.measured, tips[0], tips[1]] {
            (u0, u1, v0, v1) = (u0.min(u), u1.max(u), v0.min(v), v1.max(v));
        }
    }
    if u0 > u1 {
        (u0, u1, v0, v1) = (0.0, 1.0, 0.0, 1.0);
    }
    let m = 0.25 * (u1 - u0).max(v1 - v0).max(40.0);
    let (mut w, mut h) = (u1 - u0 + 2.0 * m, v1 - v0 + 2.0 * m);
    if w / h < aspect {
        w = h * aspect;
    } else {
        h = w / aspect;
    }
    let (cu, cv) = ((u0 + u1) / 2.0, (v0 + v1) / 2.0);
    ((cu - w / 2.0, cu + w / 2.0), (cv - h / 2.0, cv + h / 2.0))
}

/// `window` re-centred at its own centre with size `w × h` (detector px): the views of one figure
/// share the largest window's size, so they are drawn at one scale.
pub(super) fn resized(
    window: ((f64, f64), (f64, f64)),
    w: f64,
    h: f64,
) -> ((f64, f64), (f64, f64)) {
    let ((u0, u1), (v0, v1)) = window;
    let (cu, cv) = ((u0 + u1) / 2.0, (v0 + v1) / 2.0);
    ((cu - w / 2.0, cu + w / 2.0), (cv - h / 2.0, cv + h / 2.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(u: f64, shift: f64) -> Point {
        Point {
            key: 1,
            level: None,
            reference: (u, 100.0),
            measured: (u + shift, 100.0),
            predicted: (u + shift, 100.0),
        }
    }

    #[test]
    fn arrows_are_magnified_to_a_fifth_of_the_spread_at_most() {
        // Spread 400 px → arrows up to 80 px: a 3-px shift gets ×20 (60 px), a 30-px shift ×2 (60 px),
        // a 100-px shift is drawn at its size.
        for (shift, g) in [(3.0, 20.0), (30.0, 2.0), (100.0, 1.0)] {
            assert_eq!(
                gain(&[point(0.0, shift), point(400.0, 0.0)]),
                g,
                "shift {shift}"
            );
        }
    }

    #[test]
    fn the_window_holds_every_arrow_at_the_plot_aspect() {
        let pts = [point(100.0, 10.0), point(300.0, -5.0)];
        let ((u0, u1), (v0, v1)) = window(&pts, 5.0, 1.5);
        assert!(((u1 - u0) / (v1 - v0) - 1.5).abs() < 1e-12);
        for p in &pts {
            let t = tip(p.reference, p.measured, 5.0);
            assert!(u0 < t.0 && t.0 < u1 && u0 < p.reference.0 && v0 < 100.0 && 100.0 < v1);
        }
    }
}
