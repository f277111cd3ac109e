//! Line charts and multi-panel figures (plotters, embedded DejaVu Sans) with labelled axes, legends
//! placed where the lines cross them least, optional spread bands and reference marks (the paper's
//! values), written as PNG and SVG through [`super::canvas`].

use std::path::Path;
use std::sync::OnceLock;

use plotters::prelude::*;

use crate::io::write_atomic_bytes;
use crate::{Error, Result};

const FONT: &[u8] = include_bytes!("../../../assets/DejaVuSans.ttf");
pub(super) const SIZE: (u32, u32) = (900, 600);

/// One labelled line of a chart, with an optional ± spread per point (drawn as whiskers) or a band.
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    /// Empty, or one value per point.
    pub spread: Vec<f64>,
    /// Empty, or one (low, high) per point: a shaded band around the line (e.g. min–max over levels).
    pub band: Vec<(f64, f64)>,
    /// The palette colour (`None`: the series' index), so several series can share one (a target's).
    pub colour: Option<usize>,
    /// Drawn dashed (e.g. the LAT view beside a solid AP).
    pub dashed: bool,
    /// The least value the quantity can take (0 for an error or a distance): whiskers stop there.
    pub floor: f64,
}

impl Series {
    /// A plain line.
    pub fn line(label: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        Series {
            label: label.into(),
            points,
            spread: Vec::new(),
            band: Vec::new(),
            colour: None,
            dashed: false,
            floor: f64::NEG_INFINITY,
        }
    }

    /// The whisker (low, high) of point `i`: its value ± spread, the low end at [`Series::floor`] at
    /// least; `None` without a finite positive spread.
    pub fn whisker(&self, i: usize) -> Option<(f64, f64)> {
        let (x, y) = *self.points.get(i)?;
        let e = *self.spread.get(i)?;
        (x.is_finite() && y.is_finite() && e.is_finite() && e > 0.0)
            .then(|| ((y - e).max(self.floor), y + e))
    }

    /// The same series in palette colour `colour`, dashed or solid.
    pub fn styled(self, colour: usize, dashed: bool) -> Series {
        Series {
            colour: Some(colour),
            dashed,
            ..self
        }
    }
}

/// A reference mark drawn over a panel (the paper's reported values), in the colour of series `colour`.
#[derive(Debug, Clone, PartialEq)]
pub enum Mark {
    /// A star at (x, y).
    Point { x: f64, y: f64, colour: usize },
    /// A shaded horizontal band `lo ≤ y ≤ hi` across the panel.
    Band { lo: f64, hi: f64 },
    /// A dashed horizontal line at y.
    Level { y: f64, colour: usize },
    /// Nothing drawn: the y axis spans at least `lo..hi` (a rate's 0–100 %).
    Extent { lo: f64, hi: f64 },
}

pub(super) fn plot_err(e: impl std::fmt::Display) -> Error {
    Error::External {
        library: "plotters",
        message: e.to_string(),
    }
}

pub(super) fn register_font() -> Result<()> {
    static DONE: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    DONE.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
            .map_err(|_| "the embedded font does not parse".to_string())
    })
    .clone()
    .map_err(plot_err)
}

/// Font sizes (px) of one chart.
#[derive(Debug, Clone, Copy)]
pub(super) struct ChartStyle {
    pub caption: u32,
    pub labels: u32,
    /// Legend font size; `None`: no legend in the chart (a figure-wide one is drawn instead).
    pub legend: Option<u32>,
}

pub(super) const SINGLE: ChartStyle = ChartStyle {
    caption: 24,
    labels: 16,
    legend: Some(16),
};

/// Dot radius (px) of series `i` of `n`: 4 for the last, 1 px more per later series, at most 8.
fn radius(i: usize, n: usize) -> i32 {
    4 + n.saturating_sub(i + 1).min(4) as i32
}

/// The unpadded extents `(x0, x1, y0, y1)` of the finite points, their error bars and bands, and the
/// marks; `x0 > x1` when no point is finite.
pub(super) fn extents(series: &[Series], marks: &[Mark]) -> (f64, f64, f64, f64) {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for s in series {
        for (&(x, _), &(lo, hi)) in s.points.iter().zip(&s.band) {
            if x.is_finite() && lo.is_finite() && hi.is_finite() {
                (y0, y1) = (y0.min(lo), y1.max(hi));
            }
        }
        for (i, &(x, y)) in s.points.iter().enumerate() {
            if !(x.is_finite() && y.is_finite()) {
                continue;
            }
            let (lo, hi) = s.whisker(i).unwrap_or((y, y));
            (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(lo), y1.max(hi));
        }
    }
    for m in marks {
        let (lo, hi) = match *m {
            Mark::Point { x, y, .. } => {
                (x0, x1) = (x0.min(x), x1.max(x));
                (y, y)
            }
            Mark::Band { lo, hi } | Mark::Extent { lo, hi } => (lo, hi),
            Mark::Level { y, .. } => (y, y),
        };
        (y0, y1) = (y0.min(lo), y1.max(hi));
    }
    (x0, x1, y0, y1)
}

/// The padded (x, y) ranges of the finite points (and of their error bars).
fn ranges(series: &[Series], marks: &[Mark]) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let (mut x0, mut x1, mut y0, mut y1) = extents(series, marks);
    if x0 > x1 {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    let pad = |a: f64, b: f64| {
        if b - a > 1e-12 {
            (b - a) * 0.05
        } else {
            a.abs().max(1.0) * 0.05
        }
    };
    let (px, py) = (pad(x0, x1), pad(y0, y1));
    ((x0 - px)..(x1 + px), (y0 - py)..(y1 + py))
}

/// A tick label: at most 4 decimals, trailing zeros dropped (`100`, `0.25`, `1.5e-5` as `0`).
fn tick(v: f64) -> String {
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.to_string() }
}

/// The plot corner whose legend box (`box_w × box_h`, fractions of the plot) the lines cross least.
fn legend_corner(
    series: &[Series],
    xr: &std::ops::Range<f64>,
    yr: &std::ops::Range<f64>,
    (box_w, box_h): (f64, f64),
) -> SeriesLabelPosition {
    let (w, h) = (xr.end - xr.start, yr.end - yr.start);
    let mut samples = Vec::new();
    for s in series {
        let pts: Vec<&(f64, f64)> = s
            .points
            .iter()
            .filter(|p| p.0.is_finite() && p.1.is_finite())
            .collect();
        for pair in pts.windows(2) {
            for k in 0..=32 {
                let a = f64::from(k) / 32.0;
                samples.push((
                    (pair[0].0 + a * (pair[1].0 - pair[0].0) - xr.start) / w,
                    (pair[0].1 + a * (pair[1].1 - pair[0].1) - yr.start) / h,
                ));
            }
        }
        samples.extend(
            pts.iter()
                .map(|p| ((p.0 - xr.start) / w, (p.1 - yr.start) / h)),
        );
    }
    let corners = [
        (SeriesLabelPosition::UpperLeft, false, true),
        (SeriesLabelPosition::UpperRight, true, true),
        (SeriesLabelPosition::LowerRight, true, false),
        (SeriesLabelPosition::LowerLeft, false, false),
    ];
    let crossings = |right: bool, upper: bool| {
        samples
            .iter()
            .filter(|(x, y)| {
                (if right {
                    *x >= 1.0 - box_w
                } else {
                    *x <= box_w
                }) && (if upper {
                    *y >= 1.0 - box_h
                } else {
                    *y <= box_h
                })
            })
            .count()
    };
    let mut best = (SeriesLabelPosition::UpperLeft, usize::MAX);
    for (pos, right, upper) in corners {
        let n = crossings(right, upper);
        if n < best.1 {
            best = (pos, n);
        }
    }
    best.0
}

/// The legend box of `series` in `font`-px text as fractions of a plot `plot_px` big (estimated from
/// the label lengths: DejaVu Sans averages ~0.6 em per character).
fn legend_box(series: &[Series], font: u32, plot_px: (f64, f64)) -> (f64, f64) {
    let chars = series
        .iter()
        .map(|s| s.label.chars().count())
        .max()
        .unwrap_or(0);
    let f = f64::from(font);
    let w = chars as f64 * 0.6 * f + 50.0;
    let h = series.len() as f64 * (f + 6.0) + 16.0;
    ((w / plot_px.0).min(1.0), (h / plot_px.1).min(1.0))
}

/// Draws the panel's series (bands, lines, point markers, ± spread whiskers when given) and its marks
/// with axes and a legend on `area`.
pub(super) fn draw_lines<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    p: &Panel,
    x_label: &str,
    y_label: &str,
    style: ChartStyle,
) -> Result<()> {
    let (series, marks) = (&p.series, &p.marks);
    let (xr, yr) = ranges(series, marks);
    let (aw, ah) = area.dim_in_pixel();
    let plot_px = (
        f64::from(aw) - f64::from(4 * style.labels + 50),
        f64::from(ah) - f64::from(2 * style.labels + style.caption + 60),
    );
    let legend_size = legend_box(series, style.legend.unwrap_or(0), plot_px);
    let legend = legend_corner(series, &xr, &yr, legend_size);
    let (x_lo, x_hi) = (xr.start, xr.end);
    let mut chart = ChartBuilder::on(area)
        .caption(&p.title, ("sans-serif", style.caption))
        .margin(15)
        .x_label_area_size(2 * style.labels + 20)
        .y_label_area_size(4 * style.labels + 20)
        .build_cartesian_2d(xr, yr)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .x_labels(6)
        .y_labels(8)
        .x_label_formatter(&|v| tick(*v))
        .y_label_formatter(&|v| tick(*v))
        .label_style(("sans-serif", style.labels))
        .draw()
        .map_err(plot_err)?;
    let reference = RGBColor(120, 120, 120);
    for m in marks {
        if let Mark::Band { lo, hi } = *m {
            let band = Rectangle::new([(x_lo, lo), (x_hi, hi)], reference.mix(0.18).filled());
            chart.draw_series(std::iter::once(band)).map_err(plot_err)?;
        }
    }
    for (i, s) in series.iter().enumerate() {
        let colour = Palette99::pick(s.colour.unwrap_or(i)).to_rgba();
        let band: Vec<(f64, f64)> = s
            .points
            .iter()
            .zip(&s.band)
            .filter(|(p, b)| p.0.is_finite() && b.0.is_finite() && b.1.is_finite())
            .map(|(p, b)| (p.0, b.1))
            .chain(
                s.points
                    .iter()
                    .zip(&s.band)
                    .rev()
                    .filter(|(p, b)| p.0.is_finite() && b.0.is_finite() && b.1.is_finite())
                    .map(|(p, b)| (p.0, b.0)),
            )
            .collect();
        if band.len() >= 4 {
            let poly = Polygon::new(band, colour.mix(0.2).filled());
            chart.draw_series(std::iter::once(poly)).map_err(plot_err)?;
        }
    }
    for (i, s) in series.iter().enumerate() {
        let colour = Palette99::pick(s.colour.unwrap_or(i)).to_rgba();
        let finite = |p: &&(f64, f64)| p.0.is_finite() && p.1.is_finite();
        let pts: Vec<(f64, f64)> = s.points.iter().filter(finite).copied().collect();
        let line = colour.stroke_width(2);
        let anno = if s.dashed {
            chart.draw_series(DashedLineSeries::new(pts.clone(), 9, 6, line))
        } else {
            chart.draw_series(LineSeries::new(pts.clone(), line))
        }
        .map_err(plot_err)?;
        // The legend sample in the line's own style: one stroke, or two dashes.
        let gap = if s.dashed { (9, 14) } else { (24, 24) };
        anno.label(s.label.clone()).legend(move |(x, y)| {
            EmptyElement::at((x, y))
                + PathElement::new(vec![(0, 0), (gap.0, 0)], line)
                + PathElement::new(vec![(gap.1, 0), (24, 0)], line)
        });
        chart
            // Earlier series get larger dots, so a line drawn over an equal one leaves it visible.
            .draw_series(
                pts.iter()
                    .map(|&p| Circle::new(p, radius(i, series.len()), colour.filled())),
            )
            .map_err(plot_err)?;
        let whiskers = (0..s.points.len()).filter_map(|i| {
            let (lo, hi) = s.whisker(i)?;
            let x = s.points[i].0;
            Some(PathElement::new(
                vec![(x, lo), (x, hi)],
                colour.stroke_width(1),
            ))
        });
        chart.draw_series(whiskers).map_err(plot_err)?;
    }
    for m in marks {
        match *m {
            Mark::Point { x, y, colour } => {
                let c = Palette99::pick(colour).to_rgba();
                let star = TriangleMarker::new((x, y), 9, c.filled());
                chart.draw_series(std::iter::once(star)).map_err(plot_err)?;
                let ring = Circle::new((x, y), 9, BLACK.stroke_width(1));
                chart.draw_series(std::iter::once(ring)).map_err(plot_err)?;
            }
            Mark::Level { y, colour } => {
                let c = Palette99::pick(colour).to_rgba();
                let n = 24;
                let dashes = (0..n).step_by(2).map(|k| {
                    let t = |k: i32| x_lo + (x_hi - x_lo) * f64::from(k) / f64::from(n);
                    PathElement::new(vec![(t(k), y), (t(k + 1), y)], c.stroke_width(2))
                });
                chart.draw_series(dashes).map_err(plot_err)?;
            }
            Mark::Band { .. } | Mark::Extent { .. } => {}
        }
    }
    if let Some(size) = style.legend {
        chart
            .configure_series_labels()
            .position(legend)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", size))
            .draw()
            .map_err(plot_err)?;
    }
    Ok(())
}

/// A legend of `labels` (text, colour, dashed) laid out in `cols` columns (row by row, centred in `area`): a coloured line and
/// the label of each series (colours as in [`draw_lines`]).
pub(super) fn legend_grid<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    labels: &[(String, RGBAColor, bool)],
    font: u32,
    cols: usize,
) -> Result<()> {
    let (w, h) = area.dim_in_pixel();
    let cols = cols.clamp(1, labels.len().max(1));
    let rows = labels.len().div_ceil(cols).max(1) as i32;
    let step_x = (w as i32 / cols as i32).min(320);
    let step_y = font as i32 + 8;
    let x0 = (w as i32 - step_x * cols as i32) / 2;
    let y0 = (h as i32 - step_y * rows) / 2 + step_y / 2;
    let anchor = plotters::style::text_anchor::Pos::new(
        plotters::style::text_anchor::HPos::Left,
        plotters::style::text_anchor::VPos::Center,
    );
    for (i, (label, colour, dashed)) in labels.iter().enumerate() {
        let colour = *colour;
        let x = x0 + step_x * (i % cols) as i32 + 10;
        let y = y0 + step_y * (i / cols) as i32;
        // The sample in the line's style: one stroke, or three dashes.
        let dashes: &[(i32, i32)] = if *dashed {
            &[(0, 9), (14, 23), (28, 36)]
        } else {
            &[(0, 36)]
        };
        for &(a, b) in dashes {
            area.draw(&PathElement::new(
                vec![(x + a, y), (x + b, y)],
                colour.stroke_width(3),
            ))
            .map_err(plot_err)?;
        }
        let style = ("sans-serif", font).into_font().color(&BLACK).pos(anchor);
        area.draw(&Text::new(label.clone(), (x + 44, y), style))
            .map_err(plot_err)?;
    }
    Ok(())
}

/// One panel of a multi-panel figure.
pub struct Panel {
    pub title: String,
    pub series: Vec<Series>,
    /// Reference marks (the paper's values) drawn over the series.
    pub marks: Vec<Mark>,
}

pub(super) fn encode_png_sized(path: &Path, buf: Vec<u8>, size: (u32, u32)) -> Result<()> {
    let img = image::RgbImage::from_raw(size.0, size.1, buf)
        .ok_or_else(|| Error::Internal("figure buffer size mismatch".into()))?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| Error::format(path, e.to_string()))?;
    write_atomic_bytes(path, &png)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A whisker is the value ± its spread, stopped at the series' floor (an error is never below 0);
    /// a point without a positive finite spread has none.
    #[test]
    fn whiskers_stop_at_the_floor() {
        let mut s = Series::line("e", vec![(0.0, 0.2), (1.0, 1.0), (2.0, 0.5)]);
        s.spread = vec![0.5, 0.25, 0.0];
        assert_eq!(s.whisker(0), Some((-0.3, 0.7)));
        s.floor = 0.0;
        assert_eq!(s.whisker(0), Some((0.0, 0.7)));
        assert_eq!(s.whisker(1), Some((0.75, 1.25)));
        assert_eq!(s.whisker(2), None);
        assert_eq!(s.whisker(3), None);
        let (_, y) = ranges(&[s], &[]);
        assert!(y.start >= -0.1, "{y:?}");
    }
}
