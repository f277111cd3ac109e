//! Line charts and multi-panel figures (plotters, bitmap backend, embedded DejaVu Sans) with labelled
//! axes and legends placed where the lines cross them least, encoded as PNG and written atomically.

use std::path::Path;
use std::sync::OnceLock;

use plotters::prelude::*;

use crate::io::write_atomic_bytes;
use crate::{Error, Result};

const FONT: &[u8] = include_bytes!("../../../assets/DejaVuSans.ttf");
pub(super) const SIZE: (u32, u32) = (900, 600);

/// One labelled line of a chart, with an optional ± spread per point (drawn as whiskers).
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    /// Empty, or one value per point.
    pub spread: Vec<f64>,
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
struct ChartStyle {
    caption: u32,
    labels: u32,
    /// Legend font size; `None`: no legend in the chart (a figure-wide one is drawn instead).
    legend: Option<u32>,
}

const SINGLE: ChartStyle = ChartStyle {
    caption: 24,
    labels: 16,
    legend: Some(16),
};

/// The padded (x, y) ranges of the finite points (and of their error bars).
fn ranges(series: &[Series]) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for s in series {
        for (i, &(x, y)) in s.points.iter().enumerate() {
            if !(x.is_finite() && y.is_finite()) {
                continue;
            }
            let e = s
                .spread
                .get(i)
                .copied()
                .filter(|e| e.is_finite())
                .unwrap_or(0.0);
            (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y - e), y1.max(y + e));
        }
    }
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

/// Draws `series` (lines, point markers, ± spread whiskers when given) with axes and a legend on `area`.
fn draw_lines<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    style: ChartStyle,
) -> Result<()> {
    let (xr, yr) = ranges(series);
    let (aw, ah) = area.dim_in_pixel();
    let plot_px = (
        f64::from(aw) - f64::from(4 * style.labels + 50),
        f64::from(ah) - f64::from(2 * style.labels + style.caption + 60),
    );
    let legend_size = legend_box(series, style.legend.unwrap_or(0), plot_px);
    let legend = legend_corner(series, &xr, &yr, legend_size);
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", style.caption))
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
    for (i, s) in series.iter().enumerate() {
        let colour = Palette99::pick(i).to_rgba();
        let finite = |p: &&(f64, f64)| p.0.is_finite() && p.1.is_finite();
        let pts: Vec<(f64, f64)> = s.points.iter().filter(finite).copied().collect();
        chart
            .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
            .map_err(plot_err)?
            .label(s.label.clone())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
        chart
            .draw_series(pts.iter().map(|&p| Circle::new(p, 4, colour.filled())))
            .map_err(plot_err)?;
        let whiskers = s
            .points
            .iter()
            .zip(&s.spread)
            .filter(|&(&(x, y), &e)| x.is_finite() && y.is_finite() && e.is_finite() && e > 0.0)
            .map(|(&(x, y), &e)| {
                PathElement::new(vec![(x, y - e), (x, y + e)], colour.stroke_width(1))
            });
        chart.draw_series(whiskers).map_err(plot_err)?;
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

/// A legend of `labels` laid out in `cols` columns (row by row, centred in `area`): a coloured line and
/// the label of each series (colours as in [`draw_lines`]).
fn legend_grid<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    labels: &[String],
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
    for (i, label) in labels.iter().enumerate() {
        let colour = Palette99::pick(i).to_rgba();
        let x = x0 + step_x * (i % cols) as i32 + 10;
        let y = y0 + step_y * (i / cols) as i32;
        area.draw(&PathElement::new(
            vec![(x, y), (x + 36, y)],
            colour.stroke_width(3),
        ))
        .map_err(plot_err)?;
        let style = ("sans-serif", font).into_font().color(&BLACK).pos(anchor);
        area.draw(&Text::new(label.clone(), (x + 44, y), style))
            .map_err(plot_err)?;
    }
    Ok(())
}

/// Series above which a single chart gets its legend in a column beside the plot instead of inside it.
const LEGEND_INSIDE_MAX: usize = 10;

/// Draws `series` as a line chart and writes it to `path` (PNG).
pub fn line_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<()> {
    register_font()?;
    let beside = series.len() > LEGEND_INSIDE_MAX;
    let size = if beside { (SIZE.0 + 300, SIZE.1) } else { SIZE };
    let mut buf = vec![0u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        if beside {
            let (plot, legend) = root.split_horizontally(SIZE.0);
            let style = ChartStyle {
                legend: None,
                ..SINGLE
            };
            draw_lines(&plot, title, x_label, y_label, series, style)?;
            let labels: Vec<String> = series.iter().map(|s| s.label.clone()).collect();
            legend_grid(&legend, &labels, 15, 1)?;
        } else {
            draw_lines(&root, title, x_label, y_label, series, SINGLE)?;
        }
        root.present().map_err(plot_err)?;
    }
    encode_png_sized(path, buf, size)
}

/// One panel of a multi-panel figure.
pub struct Panel {
    pub title: String,
    pub series: Vec<Series>,
}

/// Panels in a grid of `cols` columns sharing axis labels and one legend (the series of every panel are
/// the same lines, in the same order), under one title, written to `path` (PNG). Fonts are larger than
/// a single chart's so the figure stays readable when scaled to a page width.
pub fn panel_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    panels: &[Panel],
    cols: usize,
) -> Result<()> {
    register_font()?;
    let cols = cols.clamp(1, panels.len().max(1));
    let rows = panels.len().div_ceil(cols).max(1);
    let size = (600 * cols as u32, 110 + 500 * rows as u32);
    let style = ChartStyle {
        caption: 26,
        labels: 20,
        legend: None,
    };
    let labels: Vec<String> = panels
        .iter()
        .max_by_key(|p| p.series.len())
        .map(|p| p.series.iter().map(|s| s.label.clone()).collect())
        .unwrap_or_default();
    let mut buf = vec![0u8; (size.0 * size.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        let root = root.titled(title, ("sans-serif", 32)).map_err(plot_err)?;
        let (strip, root) = root.split_vertically(50);
        legend_grid(&strip, &labels, 22, labels.len())?;
        for (area, p) in root.split_evenly((rows, cols)).iter().zip(panels) {
            draw_lines(area, &p.title, x_label, y_label, &p.series, style)?;
        }
        root.present().map_err(plot_err)?;
    }
    encode_png_sized(path, buf, size)
}

pub(super) fn encode_png_sized(path: &Path, buf: Vec<u8>, size: (u32, u32)) -> Result<()> {
    let img = image::RgbImage::from_raw(size.0, size.1, buf)
        .ok_or_else(|| Error::Internal("figure buffer size mismatch".into()))?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| Error::format(path, e.to_string()))?;
    write_atomic_bytes(path, &png)
}
