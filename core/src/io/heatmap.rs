//! Heatmap PNGs: a float image through viridis (a perceptually uniform colour map) with a colour bar
//! labelled with its minimum and maximum, written with its sidecar.

use std::path::Path;

use image::{Rgb, RgbImage};

use super::{ImageF32, Sidecar, kind, sidecar_path, write_atomic};
use crate::{Error, Result};

/// Width of the colour-bar panel right of the image (px).
const PANEL_PX: u32 = 130;
const FONT_SCALE: u32 = 2;

/// 3×5 bitmap glyphs (one row per byte, bit 2 = left column) for the bar labels.
fn glyph(c: char) -> [u8; 5] {
    match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        '-' => [0, 0, 7, 0, 0],
        '+' => [0, 2, 7, 2, 0],
        'e' => [0, 7, 5, 6, 3],
        _ => [0; 5],
    }
}

/// Draws `text` with its top-left corner at (x, y), clipped to the image.
fn draw_text(img: &mut RgbImage, x: u32, y: u32, text: &str, colour: Rgb<u8>) {
    for (k, c) in text.chars().enumerate() {
        let x0 = x + k as u32 * 4 * FONT_SCALE;
        for (row, bits) in glyph(c).iter().enumerate() {
            for col in 0..3u32 {
                if bits & (4 >> col) == 0 {
                    continue;
                }
                for dy in 0..FONT_SCALE {
                    for dx in 0..FONT_SCALE {
                        let (px, py) =
                            (x0 + col * FONT_SCALE + dx, y + row as u32 * FONT_SCALE + dy);
                        if px < img.width() && py < img.height() {
                            img.put_pixel(px, py, colour);
                        }
                    }
                }
            }
        }
    }
}

/// A short label for a bar end: plain decimals in a readable range, else scientific notation.
pub fn format_label(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 || (1e-2..1e4).contains(&a) {
        format!("{v:.3}")
    } else {
        format!("{v:.2e}")
    }
}

/// `[min, max]` of the finite values of `img` (`[0, 0]` when there are none): the colour bar's range.
fn value_range(img: &ImageF32) -> (f64, f64) {
    let (lo, hi) = img
        .data
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &v| {
            (l.min(v), h.max(v))
        });
    if lo <= hi {
        (f64::from(lo), f64::from(hi))
    } else {
        (0.0, 0.0)
    }
}

fn viridis(t: f64) -> Rgb<u8> {
    let c = colorous::VIRIDIS.eval_continuous(t.clamp(0.0, 1.0));
    Rgb([c.r, c.g, c.b])
}

/// Renders `img` through viridis over `[min, max]` of its finite values, with a vertical colour bar
/// (max at the top, min at the bottom, both labelled) in a panel to the right.
pub fn heatmap_rgb(img: &ImageF32) -> RgbImage {
    let (lo, hi) = value_range(img);
    let span = if hi > lo { hi - lo } else { 1.0 };
    let (w, h) = (img.width, img.height.max(60));
    let mut out = RgbImage::from_pixel(w + PANEL_PX, h, Rgb([255, 255, 255]));
    for v in 0..img.height {
        for u in 0..w {
            let x = f64::from(img.get(u, v));
            let c = if x.is_finite() {
                viridis((x - lo) / span)
            } else {
                Rgb([255, 0, 255])
            };
            out.put_pixel(u, v, c);
        }
    }
    let label_h = 5 * FONT_SCALE;
    let (bar_x, bar_w) = (w + 8, 20);
    let (bar_top, bar_bottom) = (label_h + 8, h - label_h - 8);
    for y in bar_top..bar_bottom {
        let t = f64::from(bar_bottom - 1 - y) / f64::from((bar_bottom - bar_top - 1).max(1));
        for x in bar_x..bar_x + bar_w {
            out.put_pixel(x, y, viridis(t));
        }
    }
    let black = Rgb([0, 0, 0]);
    draw_text(&mut out, bar_x, 2, &format_label(hi), black);
    draw_text(&mut out, bar_x, h - label_h - 2, &format_label(lo), black);
    out
}

/// Writes [`heatmap_rgb`] of `img` as a PNG, atomically, with `sidecar` (describing `img`: its geometry,
/// units and details) beside it as kind `heatmap`, its `details.colour_bar` giving the map and the
/// range of values it spans.
pub fn write_heatmap_png(path: &Path, img: &ImageF32, sidecar: &Sidecar) -> Result<()> {
    let rgb = heatmap_rgb(img);
    let (min, max) = value_range(img);
    let sidecar = sidecar
        .derived(kind::HEATMAP)
        .with_details(&serde_json::json!({
            "colour_bar": { "map": "viridis", "min": min, "max": max }
        }))?;
    write_atomic(path, |w| {
        rgb.write_to(w, image::ImageFormat::Png)
            .map_err(|e| Error::encode(format!("PNG {}", path.display()), e))
    })?;
    sidecar.write(&sidecar_path(path))
}
