//! Chart figures: a single line chart and a grid of panels sharing one legend, drawn by
//! [`super::chart`] and written as PNG and SVG by [`super::canvas`].

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::canvas::{Figure, Raster, write_figure};
use super::chart::{
    ChartStyle, Mark, Panel, SINGLE, SIZE, Series, draw_lines, extents, legend_grid, plot_err,
};
use crate::Result;

/// Series above which a single chart gets its legend in a column beside the plot instead of inside it.
const LEGEND_INSIDE_MAX: usize = 10;

/// One chart: `series` with axes and a legend.
struct LineChart<'a> {
    panel: Panel,
    x_label: &'a str,
    y_label: &'a str,
}

impl Figure for LineChart<'_> {
    fn size(&self) -> (u32, u32) {
        if self.panel.series.len() > LEGEND_INSIDE_MAX {
            (SIZE.0 + 300, SIZE.1)
        } else {
            SIZE
        }
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<Vec<Raster>> {
        let p = &self.panel;
        if p.series.len() > LEGEND_INSIDE_MAX {
            let (plot, legend) = root.split_horizontally(SIZE.0);
            let style = ChartStyle {
                legend: None,
                ..SINGLE
            };
            draw_lines(&plot, p, self.x_label, self.y_label, style)?;
            let labels: Vec<(String, RGBAColor, bool)> = p
                .series
                .iter()
                .enumerate()
                .map(|(i, s)| {
                    let c = Palette99::pick(s.colour.unwrap_or(i)).to_rgba();
                    (s.label.clone(), c, s.dashed)
                })
                .collect();
            legend_grid(&legend, &labels, 15, 1)?;
        } else {
            draw_lines(root, p, self.x_label, self.y_label, SINGLE)?;
        }
        Ok(Vec::new())
    }
}

/// Draws `series` as a line chart and writes it to `path` (PNG) and beside it as SVG.
pub fn line_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: Vec<Series>,
) -> Result<()> {
    let panel = Panel {
        title: title.to_string(),
        series,
        marks: Vec::new(),
    };
    write_figure(
        path,
        &LineChart {
            panel,
            x_label,
            y_label,
        },
    )
}

/// Panels in a grid of `cols` columns sharing axis labels and one legend (the series of every panel are
/// the same lines, in the same order), under one title. Fonts are larger than a single chart's so the
/// figure stays readable when scaled to a page width.
pub struct PanelChart<'a> {
    pub title: &'a str,
    pub x_label: &'a str,
    /// One y label per panel row (the last one repeats).
    pub y_labels: Vec<String>,
    pub panels: Vec<Panel>,
    pub cols: usize,
    /// Extra legend entries after the series' (the paper's marks): a label and the index of the series
    /// colour it is drawn in (`None`: grey, the colour of reference bands).
    pub legend_extra: Vec<(String, Option<usize>)>,
}

impl PanelChart<'_> {
    /// Figure width (px): 600 per column, at least [`MIN_PANEL_CHART_WIDTH_PX`] so that a one-panel
    /// figure still holds its title and a legend row of three entries.
    fn width(&self) -> usize {
        (600 * self.grid().1).max(MIN_PANEL_CHART_WIDTH_PX)
    }

    fn grid(&self) -> (usize, usize) {
        let cols = self.cols.clamp(1, self.panels.len().max(1));
        (self.panels.len().div_ceil(cols).max(1), cols)
    }

    /// Legend entries per row and rows of the legend strip: an entry is the swatch and its longest
    /// label (~11 px per character at the legend's 22 px font), at least 330 px.
    fn legend_layout(&self) -> (usize, usize) {
        let longest = self
            .panels
            .iter()
            .flat_map(|p| p.series.iter().map(|s| s.label.chars().count()))
            .chain(self.legend_extra.iter().map(|(l, _)| l.chars().count()))
            .max()
            .unwrap_or(0);
        let n = self
            .panels
            .iter()
            .map(|p| p.series.len())
            .max()
            .unwrap_or(0)
            + self.legend_extra.len();
        let entry = (50 + 11 * longest).max(330);
        let per_row = (self.width() / entry).clamp(1, n.max(1));
        (per_row, n.div_ceil(per_row).max(1))
    }
}

/// Blank space (px) above a figure's title.
pub(super) const TITLE_MARGIN_PX: u32 = 10;

/// Least width of a [`PanelChart`] (px).
const MIN_PANEL_CHART_WIDTH_PX: usize = 1000;

impl Figure for PanelChart<'_> {
    fn size(&self) -> (u32, u32) {
        let rows = self.grid().0;
        let legend_rows = self.legend_layout().1 as u32;
        (
            self.width() as u32,
            80 + TITLE_MARGIN_PX + 30 * legend_rows + 500 * rows as u32,
        )
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<Vec<Raster>> {
        let (rows, cols) = self.grid();
        let width = self.width() as u32;
        let style = ChartStyle {
            caption: 26,
            labels: super::legible(width, 20),
            legend: None,
        };
        let mut labels: Vec<(String, RGBAColor, bool)> = self
            .panels
            .iter()
            .max_by_key(|p| p.series.len())
            .map(|p| {
                p.series
                    .iter()
                    .enumerate()
                    .map(|(i, s)| {
                        let c = Palette99::pick(s.colour.unwrap_or(i)).to_rgba();
                        (s.label.clone(), c, s.dashed)
                    })
                    .collect()
            })
            .unwrap_or_default();
        let grey = RGBColor(120, 120, 120).to_rgba();
        labels.extend(self.legend_extra.iter().map(|(l, c)| {
            (
                l.clone(),
                c.map_or(grey, |i| Palette99::pick(i).to_rgba()),
                false,
            )
        }));
        let (per_row, legend_rows) = self.legend_layout();
        // A top margin keeps the title's ascenders (parentheses) inside the canvas.
        let root = root
            .margin(TITLE_MARGIN_PX, 0, 0, 0)
            .titled(self.title, ("sans-serif", 32))
            .map_err(plot_err)?;
        let (strip, root) = root.split_vertically(20 + 30 * legend_rows as i32);
        legend_grid(&strip, &labels, super::legible(width, 22), per_row)?;
        for (i, (area, p)) in root
            .split_evenly((rows, cols))
            .iter()
            .zip(&self.panels)
            .enumerate()
        {
            let row = i / cols;
            let y_label = self
                .y_labels
                .get(row)
                .or(self.y_labels.last())
                .map_or("", String::as_str);
            draw_lines(area, p, self.x_label, y_label, style)?;
        }
        Ok(Vec::new())
    }
}

/// What a panel's title names with its view left out: `AP` and `LAT` → ``, `direct-ap` and
/// `direct-lat` → `direct`, `AP: final mTRE < 2 mm` → `: final mTRE < 2 mm`; a title naming no single
/// view (`AP+LAT`, `kabsch`, `fx: estimated − true`) is itself.
fn view_free(title: &str) -> String {
    let t = title.to_lowercase();
    for view in ["ap", "lat"] {
        if t == view {
            return String::new();
        }
        if let Some(rest) = t.strip_prefix(&format!("{view}:")) {
            return format!(":{rest}");
        }
        if let Some(rest) = t.strip_suffix(&format!("-{view}")) {
            return rest.to_string();
        }
    }
    t
}

/// Draws panels that show the same thing in different views (AP beside LAT: [`view_free`] titles
/// equal) at one y scale, the union of their data's, so that comparing the views by eye compares
/// their values; every other panel keeps its own scale.
pub(super) fn share_view_scales(panels: &mut [Panel]) {
    let keys: Vec<String> = panels.iter().map(|p| view_free(&p.title)).collect();
    for key in super::distinct(keys.iter()) {
        let group: Vec<usize> = (0..panels.len()).filter(|&i| keys[i] == *key).collect();
        share_y(panels, &group);
    }
}

/// Draws the panels `group` (indices into `panels`) at one y scale, the union of their data's (points,
/// whiskers, bands and marks), so that values compare by eye across them.
pub(super) fn share_y(panels: &mut [Panel], group: &[usize]) {
    if group.len() < 2 {
        return;
    }
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for &i in group {
        let (x0, x1, y0, y1) = extents(&panels[i].series, &panels[i].marks);
        if x0 <= x1 {
            (lo, hi) = (lo.min(y0), hi.max(y1));
        }
    }
    if lo <= hi {
        for &i in group {
            panels[i].marks.push(Mark::Extent { lo, hi });
        }
    }
}

/// [`PanelChart`] with one y label, written to `path` (PNG) and beside it as SVG; panels that differ
/// only in their view share one y scale ([`share_view_scales`]).
pub fn panel_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    panels: Vec<Panel>,
    cols: usize,
) -> Result<()> {
    let mut panels = panels;
    share_view_scales(&mut panels);
    let fig = PanelChart {
        title,
        x_label,
        y_labels: vec![y_label.to_string()],
        panels,
        cols,
        legend_extra: Vec::new(),
    };
    write_figure(path, &fig)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn panel(title: &str, ys: &[f64]) -> Panel {
        Panel {
            title: title.into(),
            series: vec![Series::line(
                "s",
                ys.iter().enumerate().map(|(i, &y)| (i as f64, y)).collect(),
            )],
            marks: Vec::new(),
        }
    }

    fn y_span(p: &Panel) -> (f64, f64) {
        let (_, _, y0, y1) = extents(&p.series, &p.marks);
        (y0, y1)
    }

    /// AP and LAT of one quantity (and of one method) get the union of their y extents; a panel of
    /// another method, or of both views together, keeps its own.
    #[test]
    fn views_of_one_thing_share_a_scale_and_nothing_else_does() {
        let mut panels = vec![
            panel("direct-ap", &[0.0, 450.0]),
            panel("direct-lat", &[2.0, 400.0]),
            panel("direct-ap+lat", &[0.1, 6.0]),
            panel("kabsch", &[0.2, 5.5]),
            panel("AP", &[0.9, 0.6]),
            panel("LAT", &[0.88, 0.55]),
        ];
        share_view_scales(&mut panels);
        assert_eq!(y_span(&panels[0]), (0.0, 450.0));
        assert_eq!(y_span(&panels[1]), (0.0, 450.0));
        assert_eq!(y_span(&panels[2]), (0.1, 6.0));
        assert_eq!(y_span(&panels[3]), (0.2, 5.5));
        assert_eq!(y_span(&panels[4]), (0.55, 0.9));
        assert_eq!(y_span(&panels[5]), (0.55, 0.9));
        assert_eq!(
            view_free("AP: final mTRE < 2 mm"),
            view_free("LAT: final mTRE < 2 mm")
        );
        assert_ne!(view_free("AP+LAT"), view_free("AP"));
    }
}
