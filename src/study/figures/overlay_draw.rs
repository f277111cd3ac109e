//! Drawing of the landmark overlays ([`super::overlay`]): per view a pane with the reference DRR under
//! the plot, the landmarks' marks, their numbers placed so they do not overlap, the levels tagged at the
//! left (a segment), a scale bar; under the panes one band with what the marks mean and the key of
//! numbers to landmark names. Every text is [`FONT`] px or more, so the composed figure (two panes,
//! shown [`super::super::report_html`]-wide at 1000 px) keeps its text at least 12 px high.

use plotters::coord::{ReverseCoordTranslate, Shift};
use plotters::prelude::*;

use image::RgbImage;

use super::canvas::{Figure, Raster};
use super::chart::plot_err;
use super::labels::{PixelBox, place_labels};
use super::overlay_key::{
    FONT, MEAS_COLOUR, Mark, PRED_COLOUR, REF_COLOUR, band_height, band_rows, corner, draw_band,
    draw_label, label_size,
};
use super::overlay_points::{Point, Window, resized, tip, window};
use super::scale_bar::ScaleBar;
use crate::Result;
use crate::io::ImageF32;

/// One view's pane (px): title, plot and axes.
const PANE: (u32, u32) = (760, 720);
const TITLE_FONT: u32 = 24;
/// One overlay: the reference DRR of a target in a view under its landmarks.
pub(super) struct Overlay {
    pub title: String,
    pub pts: Vec<Point>,
    pub g: f64,
    pub drr: Option<ImageF32>,
}

/// Overlays side by side at one scale (one: a single overlay figure; AP and LAT: the paper's landmark
/// figure), with the legend and the key of landmark numbers under them.
pub(super) struct OverlayRow {
    pub overlays: Vec<Overlay>,
    /// Landmark names by number (1-based).
    pub key: Vec<String>,
    /// The detector's u pixel spacing (mm), for the scale bar.
    pub mm_per_px: Option<f64>,
}

impl OverlayRow {
    fn width(&self) -> u32 {
        PANE.0 * self.overlays.len().max(1) as u32
    }

    /// The band's rows at this figure's width.
    fn band(&self) -> Vec<Vec<(Mark, String)>> {
        let g = self.overlays.first().map_or(1.0, |o| o.g);
        let levels = self
            .overlays
            .iter()
            .flat_map(|o| &o.pts)
            .any(|p| p.level.is_some());
        band_rows(g, &self.key, levels, self.width())
    }

    /// Each overlay's detector window at the plot `aspect` (width / height), all of the largest one's
    /// size: the views are drawn at one scale.
    fn windows(&self, aspect: f64) -> Vec<Window> {
        let own: Vec<Window> = self
            .overlays
            .iter()
            .map(|o| window(&o.pts, o.g, aspect))
            .collect();
        let w = own.iter().map(|((u0, u1), _)| u1 - u0).fold(0.0, f64::max);
        own.into_iter()
            .map(|win| resized(win, w, w / aspect))
            .collect()
    }
}

impl Figure for OverlayRow {
    fn size(&self) -> (u32, u32) {
        (self.width(), PANE.1 + band_height(&self.band()))
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<Vec<Raster>> {
        let (top, _) = root.split_vertically(PANE.1);
        let areas = top.split_evenly((1, self.overlays.len().max(1)));
        let Some(first) = self.overlays.first() else {
            return Ok(Vec::new());
        };
        // Every pane has the same plot size: measure it once, fit each view's window, then give every
        // view the largest window's size so all are drawn at one scale.
        let probe = builder(&areas[0], &first.title)
            .build_cartesian_2d(0.0..1.0, 0.0..1.0)
            .map_err(plot_err)?;
        let (px, py) = probe.plotting_area().get_pixel_range();
        let aspect = f64::from(px.end - px.start) / f64::from(py.end - py.start);
        let mut rasters = Vec::new();
        for ((o, area), win) in self.overlays.iter().zip(&areas).zip(self.windows(aspect)) {
            rasters.push(o.draw_in(root, area, win, self.mm_per_px)?);
        }
        draw_band(root, PANE.1, &self.band())?;
        Ok(rasters)
    }
}

fn builder<'a, 'b, DB: DrawingBackend>(
    root: &'a DrawingArea<DB, Shift>,
    title: &'b str,
) -> ChartBuilder<'a, 'b, DB> {
    let mut b = ChartBuilder::on(root);
    b.caption(title, ("sans-serif", TITLE_FONT))
        .margin(14)
        .x_label_area_size(62)
        .y_label_area_size(86);
    b
}

/// Grey level of a line integral: bone bright on a dark background, as on a radiograph.
fn grey(l: f32, scale: f32) -> RGBColor {
    let g = (l.max(0.0) / scale).min(1.0).powf(0.7);
    let g = (40.0 + 200.0 * g) as u8;
    RGBColor(g, g, g)
}

type Chart<'a, DB> = ChartContext<
    'a,
    DB,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

impl Overlay {
    /// Draws the overlay into `area` (part of `root`, the whole figure, on which the pixel-placed
    /// numbers, tags and scale bar are drawn) over the detector window `win`; returns the DRR
    /// background as a raster.
    fn draw_in<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        area: &DrawingArea<DB, Shift>,
        win: Window,
        mm_per_px: Option<f64>,
    ) -> Result<Raster> {
        let ((u0, u1), (v0, v1)) = win;
        // v grows downward on the detector: the y axis runs from v1 (bottom) to v0 (top).
        let mut chart = builder(area, &self.title)
            .build_cartesian_2d(u0..u1, v1..v0)
            .map_err(plot_err)?;
        let whole = |v: &f64| format!("{v:.0}");
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("u (px)")
            .y_desc("v (px)")
            .x_label_formatter(&whole)
            .y_label_formatter(&whole)
            .x_labels(6)
            .y_labels(6)
            .label_style(("sans-serif", FONT))
            .axis_desc_style(("sans-serif", FONT))
            .draw()
            .map_err(plot_err)?;
        let raster = background(&chart, self.drr.as_ref());
        let (px, py) = chart.plotting_area().get_pixel_range();
        let bar = ScaleBar::for_span(u1 - u0, mm_per_px);
        let bar_box = bar.draw(
            root,
            (px.end - 8, py.end - 8),
            f64::from(px.end - px.start) / (u1 - u0),
            FONT,
        )?;
        marks_and_numbers(root, &mut chart, &self.pts, self.g, bar_box)?;
        Ok(raster)
    }
}

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

/// The marks of every landmark (reference circle, measured dot, magnified arrow, predicted cross), the
/// level tags at the plot's left edge, and each landmark's number placed clear of the marks, tags,
/// other numbers and `bar` (the scale bar), with a leader line when it sits apart.
fn marks_and_numbers<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    chart: &mut Chart<DB>,
    pts: &[Point],
    g: f64,
    bar: PixelBox,
) -> Result<()> {
    let spec = chart.as_coord_spec().clone();
    let to_px = |p: (f64, f64)| {
        let (x, y) = spec.translate(&p);
        (f64::from(x), f64::from(y))
    };
    let mut obstacles = vec![bar];
    for p in pts {
        let (a, b) = (to_px(p.reference), to_px(tip(p.reference, p.measured, g)));
        for k in 0..=10 {
            let s = f64::from(k) / 10.0;
            let q = (a.0 + s * (b.0 - a.0), a.1 + s * (b.1 - a.1));
            obstacles.push(PixelBox::around(q, 14.0, 14.0));
        }
        obstacles.push(PixelBox::around(to_px(p.measured), 12.0, 12.0));
        obstacles.push(PixelBox::around(
            to_px(tip(p.reference, p.predicted, g)),
            18.0,
            18.0,
        ));
    }
    for p in pts {
        let arrow = PathElement::new(
            vec![p.reference, tip(p.reference, p.measured, g)],
            MEAS_COLOUR.stroke_width(3),
        );
        chart
            .draw_series(std::iter::once(arrow))
            .map_err(plot_err)?;
        let cross = Cross::new(
            tip(p.reference, p.predicted, g),
            7,
            PRED_COLOUR.stroke_width(3),
        );
        chart
            .draw_series(std::iter::once(cross))
            .map_err(plot_err)?;
        let m = Circle::new(p.measured, 4, MEAS_COLOUR.filled());
        chart.draw_series(std::iter::once(m)).map_err(plot_err)?;
        let r = Circle::new(p.reference, 6, REF_COLOUR.stroke_width(3));
        chart.draw_series(std::iter::once(r)).map_err(plot_err)?;
    }
    let (px, py) = chart.plotting_area().get_pixel_range();
    let bounds = PixelBox {
        x0: f64::from(px.start),
        y0: f64::from(py.start),
        x1: f64::from(px.end),
        y1: f64::from(py.end),
    };
    // Level tags at the left edge, at the height of each level's landmarks.
    for level in super::distinct(pts.iter().filter_map(|p| p.level.as_deref())) {
        let vs: Vec<f64> = pts
            .iter()
            .filter(|p| p.level.as_deref() == Some(level))
            .map(|p| to_px(p.reference).1)
            .collect();
        let y = vs.iter().sum::<f64>() / vs.len() as f64;
        let (w, h) = label_size(level);
        let b = PixelBox {
            x0: bounds.x0 + 6.0,
            y0: y - h / 2.0,
            x1: bounds.x0 + 6.0 + w,
            y1: y + h / 2.0,
        };
        draw_label(root, b, level)?;
        obstacles.push(b);
    }
    let sizes: Vec<(f64, f64)> = pts.iter().map(|p| label_size(&p.key.to_string())).collect();
    let anchors: Vec<(f64, f64)> = pts.iter().map(|p| to_px(p.reference)).collect();
    let boxes = place_labels(&anchors, &sizes, &obstacles, bounds);
    for ((p, b), a) in pts.iter().zip(&boxes).zip(&anchors) {
        let near = (a.0.clamp(b.x0, b.x1), a.1.clamp(b.y0, b.y1));
        if (near.0 - a.0).hypot(near.1 - a.1) > 10.0 {
            root.draw(&PathElement::new(
                vec![corner(a.0, a.1), corner(near.0, near.1)],
                WHITE.mix(0.9).stroke_width(1),
            ))
            .map_err(plot_err)?;
        }
        draw_label(root, *b, &p.key.to_string())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn overlay(points: &[(f64, f64)], shift: f64) -> Overlay {
        Overlay {
            title: String::new(),
            pts: points
                .iter()
                .map(|&r| Point {
                    key: 1,
                    level: None,
                    reference: r,
                    measured: (r.0 + shift, r.1),
                    predicted: (r.0 + shift, r.1),
                })
                .collect(),
            g: 1.0,
            drr: None,
        }
    }

    /// A small AP footprint and a large LAT one get windows of one size (the LAT's), each holding its
    /// own landmarks: equal sizes on the page are equal sizes on the detector.
    #[test]
    fn the_views_share_one_window_size_and_each_holds_its_landmarks() {
        let ap = overlay(&[(480.0, 500.0), (540.0, 520.0)], 2.0);
        let lat = overlay(&[(200.0, 400.0), (700.0, 700.0)], 10.0);
        let own_lat = window(&lat.pts, 1.0, 1.2);
        let row = OverlayRow {
            overlays: vec![ap, lat],
            key: vec!["a".into()],
            mm_per_px: Some(0.3),
        };
        let wins = row.windows(1.2);
        for (win, o) in wins.iter().zip(&row.overlays) {
            let ((u0, u1), (v0, v1)) = *win;
            assert!((u1 - u0 - (own_lat.0.1 - own_lat.0.0)).abs() < 1e-9);
            assert!(((u1 - u0) / (v1 - v0) - 1.2).abs() < 1e-12);
            for p in &o.pts {
                assert!(
                    u0 < p.reference.0
                        && p.measured.0 < u1
                        && v0 < p.reference.1
                        && p.reference.1 < v1
                );
            }
        }
    }

    /// The band holds the legend and one key entry per name, and grows a row when the key is long.
    #[test]
    fn the_key_names_every_number_and_wraps_to_the_figure_width() {
        let names: Vec<String> = (0..10).map(|i| format!("corner_posterior_{i}")).collect();
        let row = |n: usize| OverlayRow {
            overlays: vec![overlay(&[(0.0, 0.0)], 1.0)],
            key: names[..n].to_vec(),
            mm_per_px: None,
        };
        let numbers = |r: &OverlayRow| {
            r.band()
                .iter()
                .flatten()
                .filter(|(m, _)| matches!(m, Mark::Number(_)))
                .count()
        };
        assert_eq!(numbers(&row(10)), 10);
        assert!(band_height(&row(10).band()) > band_height(&row(1).band()));
    }
}
