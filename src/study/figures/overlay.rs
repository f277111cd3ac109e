//! Landmark overlay figures, as the paper shows them: the reference DRR of a target in a view with each
//! landmark's reference position and its measured position under the largest focal Δf, the displacement
//! magnified into an arrow, the homography prediction H·x at the arrow's scale, and non-overlapping
//! labels.

use std::path::Path;

use plotters::coord::{ReverseCoordTranslate, Shift};
use plotters::prelude::*;

use image::RgbImage;

use super::canvas::{Figure, Raster, write_figure};
use super::chart::plot_err;
use super::labels::{PixelBox, place_labels};
use crate::Result;
use crate::io::{ImageF32, read_tiff_f32};
use crate::study::experiments::reference_image_path;
use crate::study::schema::{Family, LandmarkRow};

/// Candidate magnifications of the displacement arrows, largest first.
const GAINS: [f64; 6] = [50.0, 20.0, 10.0, 5.0, 2.0, 1.0];
const SIZE: (u32, u32) = (1000, 900);
const LABEL_FONT: u32 = 14;
/// The legend box (px): four entries of 20 px.
const LEGEND_SIZE: (u32, u32) = (230, 92);

/// One landmark in an overlay: name, reference, measured and predicted positions (px).
struct Point {
    name: String,
    reference: (f64, f64),
    measured: (f64, f64),
    predicted: (f64, f64),
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
}

/// One overlay per target and view (of the focal rows of `rows`), on the reference DRR under `out`,
/// and per target the views side by side at one arrow magnification (`landmarks_<target>.png`).
pub fn landmark_overlays(
    out: &Path,
    rows: &[LandmarkRow],
    figs: &Path,
) -> Result<Vec<OverlayFigure>> {
    let focal: Vec<&LandmarkRow> = rows.iter().filter(|r| r.family == Family::Focal).collect();
    let mut made = Vec::new();
    for target in super::distinct(focal.iter().map(|r| r.target.as_str())) {
        let of_target: Vec<&LandmarkRow> = focal
            .iter()
            .copied()
            .filter(|r| r.target == target)
            .collect();
        let df_max = of_target
            .iter()
            .map(|r| r.df_px)
            .fold(f64::NEG_INFINITY, f64::max);
        let views = super::distinct(of_target.iter().map(|r| r.view.to_string()));
        let mut row = Vec::new();
        for view in &views {
            let pts = points(&of_target, view, df_max);
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
            let single = OverlayRow(vec![o]);
            write_figure(&file, &single)?;
            row.extend(single.0);
        }
        // One magnification for every view, so AP and LAT arrows compare by length.
        let g = row.iter().map(|o| o.g).fold(f64::INFINITY, f64::min);
        let landmarks = row.iter().map(|o| o.pts.len()).max().unwrap_or(0);
        for (o, view) in row.iter_mut().zip(&views) {
            o.g = g;
            o.title = overlay_title(target, view, df_max, g, o.drr.is_some());
        }
        let file = format!("landmarks_{target}.png");
        write_figure(&figs.join(&file), &OverlayRow(row))?;
        made.push(OverlayFigure {
            target: target.to_string(),
            file,
            views,
            df_px: df_max,
            gain: g,
            landmarks,
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
        "{target} {}: landmarks at focal Δf {df} px (arrows ×{g}){missing}",
        view.to_uppercase()
    )
}

/// The landmarks of one view at `df` whose reference, measured and predicted positions are all known.
fn points(rows: &[&LandmarkRow], view: &str, df: f64) -> Vec<Point> {
    rows.iter()
        .filter(|r| r.view == view && r.df_px == df)
        .map(|r| Point {
            name: r.landmark.clone(),
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
fn gain(pts: &[Point]) -> f64 {
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
fn tip(x: (f64, f64), y: (f64, f64), g: f64) -> (f64, f64) {
    (x.0 + g * (y.0 - x.0), x.1 + g * (y.1 - x.1))
}

/// The detector window shown: every point and arrow tip with a margin, widened to the plot's aspect
/// ratio `aspect` (width / height) so DRR pixels stay square.
fn window(pts: &[Point], g: f64, aspect: f64) -> ((f64, f64), (f64, f64)) {
    let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in pts {
        for (u, v) in [p.reference, p.measured, tip(p.reference, p.measured, g)] {
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

fn builder<'a, 'b, DB: DrawingBackend>(
    root: &'a DrawingArea<DB, Shift>,
    title: &'b str,
) -> ChartBuilder<'a, 'b, DB> {
    let mut b = ChartBuilder::on(root);
    b.caption(title, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(50)
        .y_label_area_size(70);
    b
}

/// Grey level of a line integral: bone bright on a dark background, as on a radiograph.
fn grey(l: f32, scale: f32) -> RGBColor {
    let g = (l.max(0.0) / scale).min(1.0).powf(0.7);
    let g = (40.0 + 200.0 * g) as u8;
    RGBColor(g, g, g)
}

/// One overlay: the reference DRR of a target in a view under its landmarks.
pub(super) struct Overlay {
    pub title: String,
    pts: Vec<Point>,
    g: f64,
    drr: Option<ImageF32>,
}

impl Overlay {
    /// Draws the overlay into `area` (part of `root`, the whole figure, on which the pixel-placed
    /// labels and legend are drawn); returns the DRR background as a raster.
    fn draw_in<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        area: &DrawingArea<DB, Shift>,
    ) -> Result<Raster> {
        let (title, pts, g) = (self.title.as_str(), &self.pts, self.g);
        // The plot's pixel size does not depend on the data ranges: measure it, then fit the window.
        let probe = builder(area, title)
            .build_cartesian_2d(0.0..1.0, 0.0..1.0)
            .map_err(plot_err)?;
        let (px, py) = probe.plotting_area().get_pixel_range();
        let aspect = f64::from(px.end - px.start) / f64::from(py.end - py.start);
        let ((u0, u1), (v0, v1)) = window(pts, g, aspect);
        // v grows downward on the detector: the y axis runs from v1 (bottom) to v0 (top).
        let mut chart = builder(area, title)
            .build_cartesian_2d(u0..u1, v1..v0)
            .map_err(plot_err)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("u (px)")
            .y_desc("v (px)")
            .label_style(("sans-serif", 16))
            .draw()
            .map_err(plot_err)?;
        let raster = background(&chart, self.drr.as_ref());
        markers_and_labels(root, &mut chart, pts, g)?;
        legend(root, (px.start, py.start), g)?;
        Ok(raster)
    }
}

/// Overlays side by side (one: a single overlay figure; AP and LAT: the paper's landmark figure).
pub(super) struct OverlayRow(pub Vec<Overlay>);

impl Figure for OverlayRow {
    fn size(&self) -> (u32, u32) {
        (SIZE.0 * self.0.len().max(1) as u32, SIZE.1)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<Vec<Raster>> {
        let areas = root.split_evenly((1, self.0.len().max(1)));
        let mut rasters = Vec::new();
        for (o, area) in self.0.iter().zip(&areas) {
            rasters.push(o.draw_in(root, area)?);
        }
        Ok(rasters)
    }
}

type Chart<'a, DB> = ChartContext<
    'a,
    DB,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// The reference DRR under the plot area (nearest pixel), or a flat grey without one.
fn background<DB: DrawingBackend>(chart: &Chart<DB>, drr: Option<&ImageF32>) -> Raster {
    let (px, py) = chart.plotting_area().get_pixel_range();
    let scale = drr.map_or(1.0, |d| d.max()).max(f32::MIN_POSITIVE);
    let (w, h) = (
        (px.end - px.start).max(1) as u32,
        (py.end - py.start).max(1) as u32,
    );
    let mut image = RgbImage::new(w, h);
    for (dx, dy, p) in image.enumerate_pixels_mut() {
        let (x, y) = (px.start + dx as i32, py.start + dy as i32);
        let colour = match (drr, chart.as_coord_spec().reverse_translate((x, y))) {
            (Some(d), Some((u, v))) => {
                let (iu, iv) = (u.round(), v.round());
                if iu >= 0.0 && iv >= 0.0 && iu < f64::from(d.width) && iv < f64::from(d.height) {
                    grey(d.get(iu as u32, iv as u32), scale)
                } else {
                    RGBColor(20, 20, 20)
                }
            }
            _ => RGBColor(90, 90, 90),
        };
        *p = image::Rgb([colour.0, colour.1, colour.2]);
    }
    Raster {
        x: px.start,
        y: py.start,
        image,
    }
}

const REF_COLOUR: RGBColor = RGBColor(0, 220, 90);
const MEAS_COLOUR: RGBColor = RGBColor(255, 60, 40);
const PRED_COLOUR: RGBColor = RGBColor(80, 170, 255);

fn markers_and_labels<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    chart: &mut Chart<DB>,
    pts: &[Point],
    g: f64,
) -> Result<()> {
    let spec = chart.as_coord_spec().clone();
    let to_px = |p: (f64, f64)| {
        let (x, y) = spec.translate(&p);
        (f64::from(x), f64::from(y))
    };
    let mut obstacles = Vec::new();
    for p in pts {
        let (a, b) = (to_px(p.reference), to_px(tip(p.reference, p.measured, g)));
        for k in 0..=10 {
            let s = f64::from(k) / 10.0;
            let q = (a.0 + s * (b.0 - a.0), a.1 + s * (b.1 - a.1));
            obstacles.push(PixelBox::around(q, 12.0, 12.0));
        }
        obstacles.push(PixelBox::around(to_px(p.measured), 12.0, 12.0));
        obstacles.push(PixelBox::around(
            to_px(tip(p.reference, p.predicted, g)),
            14.0,
            14.0,
        ));
    }
    for p in pts {
        let arrow = PathElement::new(
            vec![p.reference, tip(p.reference, p.measured, g)],
            MEAS_COLOUR.stroke_width(2),
        );
        chart
            .draw_series(std::iter::once(arrow))
            .map_err(plot_err)?;
        let cross = Cross::new(
            tip(p.reference, p.predicted, g),
            6,
            PRED_COLOUR.stroke_width(2),
        );
        chart
            .draw_series(std::iter::once(cross))
            .map_err(plot_err)?;
        let m = Circle::new(p.measured, 3, MEAS_COLOUR.filled());
        chart.draw_series(std::iter::once(m)).map_err(plot_err)?;
        let r = Circle::new(p.reference, 5, REF_COLOUR.stroke_width(2));
        chart.draw_series(std::iter::once(r)).map_err(plot_err)?;
    }
    let font = ("sans-serif", LABEL_FONT).into_font().color(&BLACK);
    let mut sizes = Vec::new();
    for p in pts {
        let (w, h) = root.estimate_text_size(&p.name, &font).map_err(plot_err)?;
        sizes.push((f64::from(w) + 6.0, f64::from(h) + 4.0));
    }
    let (px, py) = chart.plotting_area().get_pixel_range();
    let bounds = PixelBox {
        x0: f64::from(px.start),
        y0: f64::from(py.start),
        x1: f64::from(px.end),
        y1: f64::from(py.end),
    };
    // The legend sits in the plot's top-left corner (see [`legend`]).
    obstacles.push(PixelBox {
        x0: bounds.x0,
        y0: bounds.y0,
        x1: bounds.x0 + f64::from(8 + LEGEND_SIZE.0),
        y1: bounds.y0 + f64::from(8 + LEGEND_SIZE.1),
    });
    let anchors: Vec<(f64, f64)> = pts.iter().map(|p| to_px(p.reference)).collect();
    let boxes = place_labels(&anchors, &sizes, &obstacles, bounds);
    for ((p, b), a) in pts.iter().zip(&boxes).zip(&anchors) {
        let corner = |x: f64, y: f64| (x.round() as i32, y.round() as i32);
        // A leader line from the label's nearest edge point to its landmark when it sits apart.
        let near = (a.0.clamp(b.x0, b.x1), a.1.clamp(b.y0, b.y1));
        if (near.0 - a.0).hypot(near.1 - a.1) > 10.0 {
            root.draw(&PathElement::new(
                vec![corner(a.0, a.1), corner(near.0, near.1)],
                WHITE.mix(0.8).stroke_width(1),
            ))
            .map_err(plot_err)?;
        }
        root.draw(&Rectangle::new(
            [corner(b.x0, b.y0), corner(b.x1, b.y1)],
            WHITE.mix(0.85).filled(),
        ))
        .map_err(plot_err)?;
        root.draw(&Text::new(
            p.name.clone(),
            corner(b.x0 + 3.0, b.y0 + 2.0),
            font.clone(),
        ))
        .map_err(plot_err)?;
    }
    Ok(())
}

/// What the marks mean, in a box at the plot's top-left corner.
fn legend<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    (x, y): (i32, i32),
    g: f64,
) -> Result<()> {
    let entries = [
        ("reference position".to_string(), REF_COLOUR),
        ("measured, perturbed K".to_string(), MEAS_COLOUR),
        (format!("measured shift ×{g} (arrow)"), MEAS_COLOUR),
        (format!("H·x predicted (×{g})"), PRED_COLOUR),
    ];
    let (x, y) = (x + 8, y + 8);
    root.draw(&Rectangle::new(
        [(x, y), (x + LEGEND_SIZE.0 as i32, y + LEGEND_SIZE.1 as i32)],
        WHITE.mix(0.85).filled(),
    ))
    .map_err(plot_err)?;
    for (i, (label, colour)) in entries.iter().enumerate() {
        let cy = y + 16 + 20 * i as i32;
        let c = (x + 16, cy);
        match i {
            0 => root.draw(&Circle::new(c, 5, colour.stroke_width(2))),
            1 => root.draw(&Circle::new(c, 3, colour.filled())),
            2 => root.draw(&PathElement::new(
                vec![(x + 6, cy), (x + 26, cy)],
                colour.stroke_width(2),
            )),
            _ => root.draw(&Cross::new(c, 6, colour.stroke_width(2))),
        }
        .map_err(plot_err)?;
        let style = ("sans-serif", LABEL_FONT).into_font().color(&BLACK);
        root.draw(&Text::new(label.clone(), (x + 34, cy - 8), style))
            .map_err(plot_err)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(u: f64, shift: f64) -> Point {
        Point {
            name: String::new(),
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
