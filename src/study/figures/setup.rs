//! The Setup's drawing: each view seen from beside the beam, drawn to one scale in mm — the source,
//! the central ray to the piercing point, the detector (its v extent at the SDD), the beam's fan to the
//! detector's edges, the aim, and every target's outline where it really is (the convex hull of its
//! vertices in the view's camera frame, stored with its reference DRR). Horizontal: depth from the
//! source along the central ray; vertical: offset along the detector's v axis (up = the top row).

use std::path::Path;

use glam::DVec2;
use plotters::coord::Shift;
use plotters::prelude::*;

use super::canvas::{Figure, Raster, write_figure};
use super::chart::{legend_grid, plot_err};
use crate::Result;
use crate::io::{Sidecar, sidecar_path};
use crate::study::config::StudyConfig;
use crate::study::experiments::{OUTLINE_KEY, reference_image_path};

/// One view as drawn.
struct ViewSketch {
    name: String,
    sdd_mm: f64,
    /// Source–aim distance (mm).
    aim_mm: f64,
    /// The detector's top and bottom edges along v (mm, camera y at the detector plane).
    detector_v_mm: (f64, f64),
    /// (target index, outline) per target with a stored outline.
    outlines: Vec<(usize, Vec<DVec2>)>,
}

pub struct SetupSketch {
    targets: Vec<String>,
    views: Vec<ViewSketch>,
}

const WIDTH: u32 = 1000;
const ROW_H: u32 = 330;
const LEGEND_H: u32 = 44;
const TITLE_H: u32 = 50;
const FONT: u32 = 16;

impl SetupSketch {
    /// The sketch of `cfg`'s views with the outlines stored beside the reference DRRs of `targets`
    /// under `out`; `None` when the detector's size in mm is unknown (an explicit K) or no view has an
    /// outline.
    pub fn load(out: &Path, cfg: &StudyConfig, targets: &[String]) -> Option<SetupSketch> {
        let (g, _) = cfg.geometry_config().ok()?;
        let sv = g.detector.stated_pixel_spacing_mm()?[1];
        let carm = cfg.carm().ok()?;
        let mut views = Vec::new();
        for view in cfg.studied_views(&carm) {
            let k = &view.intrinsics;
            let outlines: Vec<(usize, Vec<DVec2>)> = targets
                .iter()
                .enumerate()
                .filter_map(|(i, t)| {
                    let side =
                        Sidecar::read(&sidecar_path(&reference_image_path(out, t, &view.name)))
                            .ok()?;
                    let pts: Vec<[f64; 2]> =
                        serde_json::from_value(side.details.get(OUTLINE_KEY)?.clone()).ok()?;
                    (pts.len() >= 3)
                        .then(|| (i, pts.iter().map(|p| DVec2::new(p[0], p[1])).collect()))
                })
                .collect();
            views.push(ViewSketch {
                name: view.name.to_uppercase(),
                sdd_mm: k.fy * sv,
                aim_mm: view.aim().1,
                detector_v_mm: ((-0.5 - k.cy) * sv, (f64::from(k.height) - 0.5 - k.cy) * sv),
                outlines,
            });
        }
        (views.iter().any(|v| !v.outlines.is_empty())).then(|| SetupSketch {
            targets: targets.to_vec(),
            views,
        })
    }

    /// The depth range drawn (mm): from behind the source to past the farthest detector.
    fn depth_range(&self) -> (f64, f64) {
        let far = self.views.iter().map(|v| v.sdd_mm).fold(0.0, f64::max);
        (-0.06 * far, 1.08 * far)
    }
}

/// Writes `figures/setup_geometry.png` (and SVG) when the geometry allows; returns whether it did.
pub fn write(out: &Path, cfg: &StudyConfig, targets: &[String], figs: &Path) -> Result<bool> {
    match SetupSketch::load(out, cfg, targets) {
        Some(s) => write_figure(&figs.join(FILE), &s).map(|()| true),
        None => Ok(false),
    }
}

/// The sketch's file name under `figures/`.
pub const FILE: &str = "setup_geometry.png";

impl Figure for SetupSketch {
    fn size(&self) -> (u32, u32) {
        (
            WIDTH,
            TITLE_H + LEGEND_H + ROW_H * self.views.len().max(1) as u32,
        )
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<Vec<Raster>> {
        let root = root
            .margin(super::charts::TITLE_MARGIN_PX, 0, 0, 0)
            .titled(
                "Each view from beside the beam, to one scale (mm)",
                ("sans-serif", 24),
            )
            .map_err(plot_err)?;
        let (strip, body) = root.split_vertically(LEGEND_H);
        let labels: Vec<(String, RGBAColor, bool)> = self
            .targets
            .iter()
            .enumerate()
            .map(|(i, t)| (t.clone(), Palette99::pick(i).to_rgba(), false))
            .collect();
        legend_grid(&strip, &labels, FONT, labels.len().max(1))?;
        let rows = body.split_evenly((self.views.len().max(1), 1));
        let (x0, x1) = self.depth_range();
        for (v, area) in self.views.iter().zip(&rows) {
            draw_view(area, v, (x0, x1))?;
        }
        Ok(Vec::new())
    }
}

fn builder<'a, 'b, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    title: &'b str,
) -> ChartBuilder<'a, 'b, DB> {
    let mut b = ChartBuilder::on(area);
    b.caption(title, ("sans-serif", 20))
        .margin(10)
        .x_label_area_size(48)
        .y_label_area_size(70);
    b
}

/// One view: the y range is chosen from the plot's pixel size so a mm is as long down as across.
fn draw_view<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    v: &ViewSketch,
    (x0, x1): (f64, f64),
) -> Result<()> {
    let title = format!(
        "{}: source–aim {:.0} mm, SDD {:.0} mm, magnification at the aim {:.3}",
        v.name,
        v.aim_mm,
        v.sdd_mm,
        v.sdd_mm / v.aim_mm
    );
    let probe = builder(area, &title)
        .build_cartesian_2d(0.0..1.0, 0.0..1.0)
        .map_err(plot_err)?;
    let (px, py) = probe.plotting_area().get_pixel_range();
    let half = 0.5 * (x1 - x0) * f64::from(py.end - py.start) / f64::from(px.end - px.start);
    // v grows downward on the detector: the axis runs from +half (bottom) to −half (top).
    let mut chart = builder(area, &title)
        .build_cartesian_2d(x0..x1, half..-half)
        .map_err(plot_err)?;
    let whole = |x: &f64| format!("{x:.0}");
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("depth from the source along the central ray (mm)")
        .y_desc("along v (mm)")
        .x_label_formatter(&whole)
        .y_label_formatter(&whole)
        .label_style(("sans-serif", FONT))
        .axis_desc_style(("sans-serif", FONT))
        .draw()
        .map_err(plot_err)?;
    let (top, bottom) = v.detector_v_mm;
    let fan = Polygon::new(
        vec![(0.0, 0.0), (v.sdd_mm, top), (v.sdd_mm, bottom)],
        RGBColor(255, 200, 80).mix(0.18).filled(),
    );
    chart.draw_series(std::iter::once(fan)).map_err(plot_err)?;
    for (i, outline) in &v.outlines {
        let c = Palette99::pick(*i).to_rgba();
        let pts: Vec<(f64, f64)> = outline.iter().map(|p| (p.x, p.y)).collect();
        chart
            .draw_series(std::iter::once(Polygon::new(
                pts.clone(),
                c.mix(0.12).filled(),
            )))
            .map_err(plot_err)?;
        let mut closed = pts;
        closed.push(closed[0]);
        chart
            .draw_series(std::iter::once(PathElement::new(closed, c.stroke_width(2))))
            .map_err(plot_err)?;
    }
    let grey = RGBColor(90, 90, 90);
    chart
        .draw_series(DashedLineSeries::new(
            vec![(0.0, 0.0), (v.sdd_mm, 0.0)],
            8,
            6,
            grey.stroke_width(1),
        ))
        .map_err(plot_err)?;
    chart
        .draw_series(std::iter::once(PathElement::new(
            vec![(v.sdd_mm, top), (v.sdd_mm, bottom)],
            BLACK.stroke_width(4),
        )))
        .map_err(plot_err)?;
    chart
        .draw_series(std::iter::once(Circle::new(
            (0.0, 0.0),
            6,
            RGBColor(220, 40, 40).filled(),
        )))
        .map_err(plot_err)?;
    chart
        .draw_series(std::iter::once(Cross::new(
            (v.aim_mm, 0.0),
            7,
            BLACK.stroke_width(2),
        )))
        .map_err(plot_err)?;
    let font = ("sans-serif", FONT).into_font().color(&BLACK);
    for (text, at) in [
        ("source".to_string(), (0.0, 0.6 * top)),
        ("aim".to_string(), (v.aim_mm, 0.9 * top)),
        (
            "detector".to_string(),
            (v.sdd_mm - 0.05 * (x1 - x0), 1.08 * top),
        ),
    ] {
        chart
            .draw_series(std::iter::once(Text::new(text, at, font.clone())))
            .map_err(plot_err)?;
    }
    Ok(())
}
