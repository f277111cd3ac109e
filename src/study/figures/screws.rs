//! The screw figure: for one level, per view, its monochromatic DRR beside its spectral radiograph with
//! the planned pedicle screws in place, and on the radiograph each screw's axis (entry → tip) where it
//! is and where the largest focal error of the grid draws it. Both views are cropped to one window size
//! in detector px, so they are drawn at one scale.

use std::path::Path;

use glam::{DVec2, DVec3};
use image::{Rgb, RgbImage};
use plotters::coord::Shift;
use plotters::prelude::*;

use super::canvas::{Figure, Raster, write_figure};
use super::chart::plot_err;
use super::composed::Conditions;
use super::{FigureEntry, Section};
use crate::Result;
use crate::geometry::{Perturbation, View};
use crate::io::{ImageF32, Sidecar, read_tiff_f32, sidecar_path};
use crate::study::config::{Family, StudyConfig, is_segment};
use crate::study::experiments::{SCREWS_KEY, screw_image_path};
use crate::study::schema::{ScrewRow, StudyTables};

const PANE: u32 = 470;
/// Blank margin around and between the panes (nothing is drawn to the canvas edge).
const M: u32 = 12;
const TITLE_H: u32 = 40;
const HEAD_H: u32 = 50;
const FOOT_H: u32 = 64;
const FONT: u32 = 17;
const TRUE_COLOUR: RGBColor = RGBColor(40, 200, 90);
const DRAWN_COLOUR: RGBColor = RGBColor(230, 50, 40);

/// One view's images and screws.
struct ViewImages {
    name: String,
    mono: ImageF32,
    spectral: ImageF32,
    /// Per screw: the true and the drawn (assumed view) projections of entry and tip (detector px).
    axes: Vec<([DVec2; 2], [DVec2; 2])>,
}

/// The figure of one target.
pub struct ScrewFigure {
    target: String,
    technique: String,
    drawn_under: String,
    views: Vec<ViewImages>,
    /// The crop: per view its top-left corner (detector px), one side length for all.
    corners: Vec<DVec2>,
    side_px: f64,
    mm_per_px: Option<f64>,
}

/// The images of `target` in `views` with its screws drawn under `assumed` (one perturbation for all
/// views); `None` when the experiment wrote no images for it.
pub fn load(
    out: &Path,
    target: &str,
    views: &[View],
    assumed: (&Perturbation, String),
    mm_per_px: Option<f64>,
) -> Result<Option<ScrewFigure>> {
    let mut loaded = Vec::new();
    let mut technique = String::new();
    for v in views {
        let (mono_path, spectral_path) = (
            screw_image_path(out, target, &v.name, "mono"),
            screw_image_path(out, target, &v.name, "spectral"),
        );
        if !(mono_path.exists() && spectral_path.exists()) {
            return Ok(None);
        }
        let side = Sidecar::read(&sidecar_path(&spectral_path))?;
        technique = side
            .details
            .get("technique")
            .and_then(|t| t.as_str())
            .unwrap_or_default()
            .to_string();
        let planned: Vec<serde_json::Value> = side
            .details
            .get(SCREWS_KEY)
            .and_then(|s| s.as_array().cloned())
            .unwrap_or_default();
        let point = |s: &serde_json::Value, k: &str| -> Option<DVec3> {
            let a: [f64; 3] = serde_json::from_value(s.get(k)?.clone()).ok()?;
            Some(DVec3::from(a))
        };
        let drawn = v.perturbed(assumed.0)?;
        let axes = planned
            .iter()
            .filter_map(|s| Some((point(s, "entry")?, point(s, "tip")?)))
            .map(|(e, t)| {
                (
                    [v.project(e), v.project(t)],
                    [drawn.project(e), drawn.project(t)],
                )
            })
            .collect();
        loaded.push(ViewImages {
            name: v.name.to_uppercase(),
            mono: read_tiff_f32(&mono_path)?,
            spectral: read_tiff_f32(&spectral_path)?,
            axes,
        });
    }
    if loaded.is_empty() {
        return Ok(None);
    }
    // Each view's box around the anatomy (non-zero mono pixels) and the screws; one side for all.
    let boxes: Vec<(DVec2, DVec2)> = loaded.iter().map(bounds).collect();
    let side_px = boxes
        .iter()
        .map(|(lo, hi)| (*hi - *lo).max_element())
        .fold(16.0, f64::max)
        * 1.15;
    let corners = boxes
        .iter()
        .map(|(lo, hi)| (*lo + *hi) * 0.5 - DVec2::splat(side_px / 2.0))
        .collect();
    Ok(Some(ScrewFigure {
        target: target.to_string(),
        technique,
        drawn_under: assumed.1,
        views: loaded,
        corners,
        side_px,
        mm_per_px,
    }))
}

/// The box (detector px) of the non-zero pixels of the monochromatic DRR and of every screw point.
fn bounds(v: &ViewImages) -> (DVec2, DVec2) {
    let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
    let img = &v.mono;
    for y in 0..img.height {
        for x in 0..img.width {
            if img.data[(y * img.width + x) as usize] > 0.0 {
                let p = DVec2::new(f64::from(x), f64::from(y));
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
    }
    for (t, d) in &v.axes {
        for p in t.iter().chain(d) {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    if !lo.is_finite() {
        return (
            DVec2::ZERO,
            DVec2::new(f64::from(img.width), f64::from(img.height)),
        );
    }
    (lo, hi)
}

/// The crop of `img` (top-left `corner`, `side` detector px) resampled to `PANE`², grey by the 99.5th
/// percentile of the crop (bone bright; what is above it, metal, saturates).
fn pane(img: &ImageF32, corner: DVec2, side: f64) -> RgbImage {
    let s = side / f64::from(PANE);
    let sample = |i: u32, j: u32| -> f32 {
        let u = (corner.x + (f64::from(i) + 0.5) * s).round();
        let v = (corner.y + (f64::from(j) + 0.5) * s).round();
        if u < 0.0 || v < 0.0 || u >= f64::from(img.width) || v >= f64::from(img.height) {
            return 0.0;
        }
        img.data[(v as u32 * img.width + u as u32) as usize]
    };
    let mut values: Vec<f32> = (0..PANE)
        .flat_map(|j| (0..PANE).map(move |i| (i, j)))
        .map(|(i, j)| sample(i, j))
        .filter(|x| x.is_finite())
        .collect();
    values.sort_by(f32::total_cmp);
    let top = values
        .get(values.len().saturating_sub(1) * 995 / 1000)
        .copied()
        .unwrap_or(1.0)
        .max(1e-6);
    RgbImage::from_fn(PANE, PANE, |i, j| {
        let g = (sample(i, j).max(0.0) / top).min(1.0).powf(0.7);
        let g = (30.0 + 215.0 * g) as u8;
        Rgb([g, g, g])
    })
}

impl Figure for ScrewFigure {
    fn size(&self) -> (u32, u32) {
        (
            2 * PANE + 3 * M,
            TITLE_H + (HEAD_H + PANE) * self.views.len() as u32 + FOOT_H,
        )
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<Vec<Raster>> {
        let text = |s: &str, x: i32, y: i32, size: u32, colour: RGBColor| {
            root.draw(&Text::new(
                s.to_string(),
                (x, y),
                ("sans-serif", size).into_font().color(&colour),
            ))
            .map_err(plot_err)
        };
        text(
            &format!(
                "{}: monochromatic DRR beside the spectral radiograph with screws",
                self.target
            ),
            M as i32,
            12,
            22,
            BLACK,
        )?;
        let mut rasters = Vec::new();
        for (k, (v, corner)) in self.views.iter().zip(&self.corners).enumerate() {
            let y0 = TITLE_H + k as u32 * (HEAD_H + PANE);
            let (left, right) = (M as i32, (2 * M + PANE) as i32);
            let head = y0 as i32 + 4;
            text(
                &format!("{}: monochromatic DRR (μ·L)", v.name),
                left,
                head,
                FONT,
                BLACK,
            )?;
            text(
                &format!("{}: spectral, with screws", v.name),
                right,
                head,
                FONT,
                BLACK,
            )?;
            text(&self.technique, right, head + 22, FONT - 3, BLACK)?;
            let top = (y0 + HEAD_H) as i32;
            rasters.push(Raster {
                x: left,
                y: top,
                image: pane(&v.mono, *corner, self.side_px),
            });
            rasters.push(Raster {
                x: right,
                y: top,
                image: pane(&v.spectral, *corner, self.side_px),
            });
            let s = f64::from(PANE) / self.side_px;
            let at = |p: DVec2| {
                let q = (p - *corner) * s;
                (right + q.x.round() as i32, top + q.y.round() as i32)
            };
            for (truth, drawn) in &v.axes {
                root.draw(&PathElement::new(
                    vec![at(drawn[0]), at(drawn[1])],
                    DRAWN_COLOUR.stroke_width(2),
                ))
                .map_err(plot_err)?;
                root.draw(&PathElement::new(
                    vec![at(truth[0]), at(truth[1])],
                    TRUE_COLOUR.stroke_width(2),
                ))
                .map_err(plot_err)?;
            }
        }
        let y = (TITLE_H + (HEAD_H + PANE) * self.views.len() as u32) as i32;
        let window = match self.mm_per_px {
            Some(mm) => format!(
                "{:.0} px = {:.0} mm at the detector",
                self.side_px,
                self.side_px * mm
            ),
            None => format!("{:.0} px", self.side_px),
        };
        text(
            &format!(
                "green: each screw's axis (entry → tip) where it is; red: drawn under {}",
                self.drawn_under
            ),
            M as i32,
            y + 8,
            FONT - 1,
            BLACK,
        )?;
        text(
            &format!("every pane shows a window of {window}: both views at one scale"),
            M as i32,
            y + 34,
            FONT - 1,
            BLACK,
        )?;
        Ok(rasters)
    }
}

/// The screw figure of the first single level of `screws.csv` (`screws_<target>.png`) under the grid's
/// largest focal error, its caption's numbers read from that table; no entry without the images.
pub fn figures(
    out: &Path,
    cfg: &StudyConfig,
    tables: &StudyTables,
    figs: &Path,
    c: &Conditions,
) -> Result<Vec<FigureEntry>> {
    let rows = &tables.screws;
    let Some(target) = rows
        .iter()
        .map(|r| r.target.as_str())
        .find(|t| !is_segment(t))
    else {
        return Ok(Vec::new());
    };
    let focal: Vec<&ScrewRow> = rows
        .iter()
        .filter(|r| r.target == target && r.family == Family::Focal)
        .collect();
    let Some(df) = focal.iter().map(|r| r.df_px).max_by(f64::total_cmp) else {
        return Ok(Vec::new());
    };
    let mm = super::mm_per_px(cfg);
    let words = match mm {
        Some(p) => format!("Δf = {df} px (an SDD error of {:.0} mm)", df * p),
        None => format!("Δf = {df} px"),
    };
    let carm = cfg.carm()?;
    let views: Vec<View> = cfg.studied_views(&carm).cloned().collect();
    let Some(fig) = load(
        out,
        target,
        &views,
        (&Perturbation::focal(df), words.clone()),
        mm,
    )?
    else {
        return Ok(Vec::new());
    };
    let file = format!("screws_{target}.png");
    write_figure(&figs.join(&file), &fig)?;
    let offsets: Vec<String> = views
        .iter()
        .filter_map(|v| {
            let most = focal
                .iter()
                .filter(|r| r.view == v.name && r.df_px == df)
                .map(|r| r.tip_px)
                .max_by(f64::total_cmp)?;
            Some(format!("{most:.1} px in {}", v.name.to_uppercase()))
        })
        .collect();
    let title = format!("{target}: the planned pedicle screws on the radiograph");
    Ok(vec![c.entry(
        Section::Screws,
        &file,
        &title,
        &format!(
            "per view the monochromatic DRR (the target's meshes, μ·L) beside the spectral radiograph \
             with two titanium pedicle screws ({}); on it each screw's axis where it is (green) and as \
             drawn under {words} (red: the tip moves by up to {} — `tables/screws.csv`); both views \
             cropped to one window, so at one scale",
            fig.technique,
            offsets.join(", ")
        ),
        true,
    )])
}
