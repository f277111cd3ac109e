//! The paper's |ΔDRR| heatmap panel of one target: a row per view, a column per heatmap Δf (focal
//! family), each view's panes cropped to a window around where any of its differences is non-zero,
//! every window the same size (the largest view's), so all panes are drawn at one scale with a scale
//! bar, and coloured through ONE scale, viridis over [0, max of all panes], with a colour bar labelled
//! in the images' units.

use std::path::Path;

use image::{Rgb, RgbImage};
use plotters::coord::Shift;
use plotters::prelude::*;

use super::canvas::{Figure, Raster};
use super::chart::plot_err;
use super::scale_bar::ScaleBar;
use crate::Result;
use crate::io::{ImageF32, read_tiff_f32};
use crate::study::experiments::difference_image_path;

/// Text size (px) of the pane labels and scale bars.
const SMALL_FONT: u32 = 15;
/// Pane side (px) in the figure.
const PANE: u32 = 380;
const LEFT: u32 = 30;
const TOP: u32 = 70;
const GAP: u32 = 46;
const BAR_W: u32 = 180;

/// The colour scale shared by every pane: viridis over [0, max].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColourScale {
    pub max: f64,
}

impl ColourScale {
    /// The scale spanning every finite value of `images` (from 0: |ΔDRR| ≥ 0).
    pub fn spanning<'a>(images: impl IntoIterator<Item = &'a ImageF32>) -> ColourScale {
        let max = images
            .into_iter()
            .flat_map(|i| i.data.iter())
            .filter(|v| v.is_finite())
            .fold(0.0f64, |m, &v| m.max(f64::from(v)));
        ColourScale { max }
    }

    /// The colour of `v`: viridis at v / max (clamped), magenta for a non-finite value.
    pub fn colour(&self, v: f64) -> Rgb<u8> {
        if !v.is_finite() {
            return Rgb([255, 0, 255]);
        }
        let t = if self.max > 0.0 { v / self.max } else { 0.0 };
        let c = colorous::VIRIDIS.eval_continuous(t.clamp(0.0, 1.0));
        Rgb([c.r, c.g, c.b])
    }
}

/// A square detector window: columns `u0..u0 + side`, rows `v0..v0 + side` (px).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Crop {
    pub u0: u32,
    pub v0: u32,
    pub side: u32,
}

impl Crop {
    /// The window of side `side` (at most the detector's smaller side) centred where this one is, kept
    /// on a `w × h` detector.
    pub fn resized(&self, side: u32, w: u32, h: u32) -> Crop {
        let side = side.min(w.min(h)).max(1);
        let place = |a: u32, n: u32| (a + self.side / 2).saturating_sub(side / 2).min(n - side);
        Crop {
            u0: place(self.u0, w),
            v0: place(self.v0, h),
            side,
        }
    }
}

/// The square window holding every pixel of `images` above 1 % of `scale.max`, with a 15 % margin,
/// kept on the detector (the whole detector when nothing is above it).
pub fn crop_of(images: &[&ImageF32], scale: ColourScale) -> Crop {
    let Some(first) = images.first() else {
        return Crop {
            u0: 0,
            v0: 0,
            side: 1,
        };
    };
    let (w, h) = (first.width, first.height);
    let (mut u0, mut u1, mut v0, mut v1) = (u32::MAX, 0, u32::MAX, 0);
    let threshold = 0.01 * scale.max;
    for img in images {
        for v in 0..img.height {
            for u in 0..img.width {
                if f64::from(img.get(u, v)) > threshold {
                    (u0, u1, v0, v1) = (u0.min(u), u1.max(u), v0.min(v), v1.max(v));
                }
            }
        }
    }
    let side_max = w.min(h).max(1);
    if u0 > u1 {
        return Crop {
            u0: 0,
            v0: 0,
            side: side_max,
        };
    }
    let extent = (u1 - u0 + 1).max(v1 - v0 + 1);
    let side = ((f64::from(extent) * 1.3).ceil() as u32).clamp(16.min(side_max), side_max);
    let centre = |a: u32, b: u32, n: u32| {
        let c = (a + b) / 2;
        c.saturating_sub(side / 2).min(n - side)
    };
    Crop {
        u0: centre(u0, u1, w),
        v0: centre(v0, v1, h),
        side,
    }
}

/// `img` inside `crop`, box-averaged (or nearest-sampled when enlarged) to `px × px`, through `scale`.
pub fn pane_raster(img: &ImageF32, crop: Crop, px: u32, scale: ColourScale) -> RgbImage {
    let step = f64::from(crop.side) / f64::from(px);
    RgbImage::from_fn(px, px, |x, y| {
        let (a0, b0) = (f64::from(x) * step, f64::from(y) * step);
        let (ua, ub) = (
            a0.floor() as u32,
            ((a0 + step).ceil() as u32).max(a0 as u32 + 1),
        );
        let (va, vb) = (
            b0.floor() as u32,
            ((b0 + step).ceil() as u32).max(b0 as u32 + 1),
        );
        let (mut sum, mut n) = (0.0, 0u32);
        for v in va..vb.min(crop.side) {
            for u in ua..ub.min(crop.side) {
                let (iu, iv) = (crop.u0 + u, crop.v0 + v);
                if iu < img.width && iv < img.height {
                    sum += f64::from(img.get(iu, iv));
                    n += 1;
                }
            }
        }
        scale.colour(if n > 0 { sum / f64::from(n) } else { 0.0 })
    })
}

/// One target's panel: `images[row][col]` is view `views[row]` at Δf `dfs[col]`.
pub struct HeatmapPanel {
    pub title: String,
    pub views: Vec<String>,
    pub dfs: Vec<f64>,
    pub images: Vec<Vec<ImageF32>>,
    pub crops: Vec<Crop>,
    pub scale: ColourScale,
    pub units: String,
    /// The detector's u pixel spacing (mm), for the scale bar.
    pub mm_per_px: Option<f64>,
}

impl HeatmapPanel {
    /// The panel of `target` from the study's difference images under `out`; `None` when one is missing.
    pub fn load(
        out: &Path,
        target: &str,
        views: &[String],
        dfs: &[f64],
        units: &str,
        mm_per_px: Option<f64>,
    ) -> Result<Option<HeatmapPanel>> {
        if views.is_empty() || dfs.is_empty() {
            return Ok(None); // a study without heatmaps has no panel (not an empty one)
        }
        let mut images = Vec::new();
        for view in views {
            let mut row = Vec::new();
            for &df in dfs {
                let path = difference_image_path(out, target, view, df);
                if !path.exists() {
                    return Ok(None);
                }
                row.push(read_tiff_f32(&path)?);
            }
            images.push(row);
        }
        Ok(Some(HeatmapPanel::new(
            format!("{target}: |ΔDRR| under a focal offset Δf, one colour scale"),
            views.to_vec(),
            dfs.to_vec(),
            images,
            units,
            mm_per_px,
        )))
    }

    pub fn new(
        title: String,
        views: Vec<String>,
        dfs: Vec<f64>,
        images: Vec<Vec<ImageF32>>,
        units: &str,
        mm_per_px: Option<f64>,
    ) -> HeatmapPanel {
        let scale = ColourScale::spanning(images.iter().flatten());
        let crops: Vec<Crop> = images
            .iter()
            .map(|row| crop_of(&row.iter().collect::<Vec<_>>(), scale))
            .collect();
        let side = crops.iter().map(|c| c.side).max().unwrap_or(1);
        let crops = crops
            .iter()
            .zip(&images)
            .map(|(c, row)| {
                row.first()
                    .map_or(*c, |img| c.resized(side, img.width, img.height))
            })
            .collect();
        HeatmapPanel {
            title,
            views,
            dfs,
            images,
            crops,
            scale,
            units: units.to_string(),
            mm_per_px,
        }
    }

    /// Top-left pixel of pane (row, col).
    pub fn pane_origin(&self, row: usize, col: usize) -> (i32, i32) {
        (
            (LEFT + col as u32 * (PANE + GAP)) as i32,
            (TOP + row as u32 * (PANE + GAP)) as i32,
        )
    }

    /// Every pane's raster, row by row.
    pub fn rasters(&self) -> Vec<Raster> {
        let mut out = Vec::new();
        for (row, (images, crop)) in self.images.iter().zip(&self.crops).enumerate() {
            for (col, img) in images.iter().enumerate() {
                let (x, y) = self.pane_origin(row, col);
                out.push(Raster {
                    x,
                    y,
                    image: pane_raster(img, *crop, PANE, self.scale),
                });
            }
        }
        out
    }
}

impl Figure for HeatmapPanel {
    fn size(&self) -> (u32, u32) {
        let cols = self.dfs.len().max(1) as u32;
        let rows = self.views.len().max(1) as u32;
        (
            LEFT + cols * (PANE + GAP) + BAR_W,
            TOP + rows * (PANE + GAP),
        )
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<Vec<Raster>> {
        let (w, h) = self.size();
        let centre = plotters::style::text_anchor::Pos::new(
            plotters::style::text_anchor::HPos::Center,
            plotters::style::text_anchor::VPos::Top,
        );
        let title = ("sans-serif", 26).into_font().color(&BLACK).pos(centre);
        root.draw(&Text::new(
            self.title.clone(),
            ((w - BAR_W) as i32 / 2, 14),
            title,
        ))
        .map_err(plot_err)?;
        let font = ("sans-serif", 18).into_font().color(&BLACK).pos(centre);
        let small = ("sans-serif", SMALL_FONT)
            .into_font()
            .color(&BLACK)
            .pos(centre);
        for (row, (view, crop)) in self.views.iter().zip(&self.crops).enumerate() {
            for (col, df) in self.dfs.iter().enumerate() {
                let (x, y) = self.pane_origin(row, col);
                let (p, half) = (PANE as i32, PANE as i32 / 2);
                let label = format!("{}, Δf = {df} px", view.to_uppercase());
                root.draw(&Text::new(label, (x + half, y - 24), font.clone()))
                    .map_err(plot_err)?;
                root.draw(&Rectangle::new([(x - 1, y - 1), (x + p, y + p)], BLACK))
                    .map_err(plot_err)?;
                let window = format!(
                    "u {}–{}, v {}–{} px",
                    crop.u0,
                    crop.u0 + crop.side,
                    crop.v0,
                    crop.v0 + crop.side
                );
                root.draw(&Text::new(window, (x + half, y + p + 4), small.clone()))
                    .map_err(plot_err)?;
                let bar = ScaleBar::for_span(f64::from(crop.side), self.mm_per_px);
                bar.draw(
                    root,
                    (x + p - 6, y + p - 6),
                    f64::from(PANE) / f64::from(crop.side),
                    SMALL_FONT,
                )?;
            }
        }
        let bar_area = root.clone().shrink(
            ((w - BAR_W) as i32 - 10, TOP as i32 - 10),
            (BAR_W + 10, h.saturating_sub(TOP + GAP) + 20),
        );
        let mut rasters = self.rasters();
        rasters.push(self.colour_bar(&bar_area)?);
        Ok(rasters)
    }
}

impl HeatmapPanel {
    /// The colour bar (0 at the bottom, the scale's maximum at the top) with a value axis in `units`.
    fn colour_bar<DB: DrawingBackend>(&self, area: &DrawingArea<DB, Shift>) -> Result<Raster> {
        let max = if self.scale.max > 0.0 {
            self.scale.max
        } else {
            1.0
        };
        let mut chart = ChartBuilder::on(area)
            .margin(10)
            .y_label_area_size(0)
            .right_y_label_area_size(120)
            .build_cartesian_2d(0.0..1.0, 0.0..max)
            .map_err(plot_err)?
            .set_secondary_coord(0.0..1.0, 0.0..max);
        chart
            .configure_secondary_axes()
            .y_desc(&self.units)
            .y_labels(6)
            .label_style(("sans-serif", 15))
            .draw()
            .map_err(plot_err)?;
        let (px, py) = chart.plotting_area().get_pixel_range();
        let bar_w = (px.end - px.start).max(1) as u32;
        let bar_h = (py.end - py.start).max(1) as u32;
        let image = RgbImage::from_fn(bar_w, bar_h, |_, y| {
            let t = f64::from(bar_h - 1 - y) / f64::from((bar_h - 1).max(1));
            self.scale.colour(t * self.scale.max)
        });
        Ok(Raster {
            x: px.end - bar_w as i32,
            y: py.start,
            image,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `n × n` zero image with `value` in the square [a, b)².
    fn square(n: u32, a: u32, b: u32, value: f32) -> ImageF32 {
        let mut img = ImageF32::zeros(n, n);
        for v in a..b {
            for u in a..b {
                img.data[(v * n + u) as usize] = value;
            }
        }
        img
    }

    /// The four panes share one scale: the same value has the same colour in each, whatever the
    /// pane's own maximum, and that colour is viridis at value / (the largest value of any pane).
    #[test]
    fn one_colour_scale_for_every_pane() {
        let mut images = Vec::new();
        for (row, peak) in [(0, 2.0f32), (1, 8.0)] {
            let mut r = Vec::new();
            for col in 0..2 {
                let mut img = square(200, 60, 140, 1.0);
                img.data[60 * 200 + 100 + row + col] = peak + col as f32;
                r.push(img);
            }
            images.push(r);
        }
        let panel = HeatmapPanel::new(
            "t".into(),
            vec!["ap".into(), "lat".into()],
            vec![100.0, 500.0],
            images,
            "u",
            None,
        );
        assert_eq!(panel.scale, ColourScale { max: 9.0 });
        let expected = colorous::VIRIDIS.eval_continuous(1.0 / 9.0);
        let rasters = panel.rasters();
        assert_eq!(rasters.len(), 4);
        for (i, r) in rasters.iter().enumerate() {
            // The pane centre is inside the value-1 square of every image.
            let c = r.image.get_pixel(PANE / 2, PANE / 2 + 20);
            assert_eq!(c.0, [expected.r, expected.g, expected.b], "pane {i}");
        }
        assert_eq!(panel.scale.colour(0.0), panel.scale.colour(-1.0));
        assert_ne!(panel.scale.colour(4.5), panel.scale.colour(9.0));
    }

    /// Views whose anatomy differs in size get windows of one size (the larger), each still holding
    /// its own anatomy: the panes are drawn at one scale.
    #[test]
    fn every_view_is_cropped_to_one_window_size() {
        let small = square(400, 150, 200, 1.0);
        let large = square(400, 100, 300, 1.0);
        let panel = HeatmapPanel::new(
            "t".into(),
            vec!["ap".into(), "lat".into()],
            vec![100.0],
            vec![vec![small], vec![large]],
            "u",
            Some(0.3),
        );
        let own = crop_of(&[&square(400, 100, 300, 1.0)], panel.scale);
        assert_eq!(panel.crops[0].side, own.side);
        assert_eq!(panel.crops[1].side, own.side);
        let c = panel.crops[0];
        assert!(c.u0 <= 150 && c.u0 + c.side >= 200 && c.v0 <= 150 && c.v0 + c.side >= 200);
        // A window near the edge stays on the detector.
        let near = Crop {
            u0: 380,
            v0: 0,
            side: 20,
        };
        let r = near.resized(100, 400, 400);
        assert_eq!((r.u0 + r.side, r.v0, r.side), (400, 0, 100));
    }

    #[test]
    fn the_crop_holds_the_anatomy_with_a_margin_and_stays_on_the_detector() {
        let img = square(400, 100, 200, 1.0);
        let c = crop_of(&[&img], ColourScale { max: 1.0 });
        assert_eq!(c.side, 130);
        assert!(c.u0 <= 100 && c.u0 + c.side >= 200 && c.v0 <= 100 && c.v0 + c.side >= 200);
        let corner = square(400, 350, 400, 1.0);
        let c = crop_of(&[&corner], ColourScale { max: 1.0 });
        assert_eq!(c.u0 + c.side, 400);
        let blank = ImageF32::zeros(64, 48);
        assert_eq!(
            crop_of(&[&blank], ColourScale { max: 0.0 }),
            Crop {
                u0: 0,
                v0: 0,
                side: 48
            }
        );
    }
}
