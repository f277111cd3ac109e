//! One drawing, two formats: a [`Figure`] draws its vector content (axes, lines, text) on any plotters
//! backend and hands back its raster content (DRR backgrounds, heatmap panes) as [`Raster`]s; the
//! writer puts the rasters under the vector content in both a PNG (bitmap backend) and an SVG (SVG
//! backend: text stays `<text>`, rasters become embedded PNG `<image>`s).

use std::path::{Path, PathBuf};

use base64::Engine as _;
use image::RgbImage;
use plotters::coord::Shift;
use plotters::prelude::*;

use super::chart::{encode_png_sized, plot_err, register_font};
use crate::io::write_atomic_bytes;
use crate::{Error, Result};

/// A raster placed with its top-left corner at pixel (x, y) of the figure, drawn at its own size.
pub struct Raster {
    pub x: i32,
    pub y: i32,
    pub image: RgbImage,
}

/// A figure drawable on any backend.
pub trait Figure {
    /// Size in pixels (PNG) and in SVG user units.
    fn size(&self) -> (u32, u32);
    /// Draws the vector content on `root` (already white) and returns the rasters to put under it. Must
    /// be deterministic: it is called once per format.
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<Vec<Raster>>;
}

/// The SVG file beside a figure's PNG.
pub fn svg_path(png: &Path) -> PathBuf {
    png.with_extension("svg")
}

/// Writes `fig` to `png` and to [`svg_path`]`(png)`.
pub fn write_figure(png: &Path, fig: &impl Figure) -> Result<()> {
    register_font()?;
    let size = fig.size();
    let mut svg = String::new();
    let rasters = {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        let rasters = fig.draw(&root)?;
        root.present().map_err(plot_err)?;
        rasters
    };
    let svg = with_underlay(&svg, size, &rasters)?;
    write_atomic_bytes(&svg_path(png), svg.as_bytes())?;

    let mut img = RgbImage::from_pixel(size.0, size.1, image::Rgb([255, 255, 255]));
    for r in &rasters {
        blit(&mut img, r);
    }
    let mut buf = img.into_raw();
    {
        let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
        fig.draw(&root)?;
        root.present().map_err(plot_err)?;
    }
    encode_png_sized(png, buf, size)
}

fn blit(img: &mut RgbImage, r: &Raster) {
    for (x, y, p) in r.image.enumerate_pixels() {
        let (u, v) = (r.x + x as i32, r.y + y as i32);
        if u >= 0 && v >= 0 && (u as u32) < img.width() && (v as u32) < img.height() {
            img.put_pixel(u as u32, v as u32, *p);
        }
    }
}

/// `svg` with a white background and the rasters inserted right after the opening `<svg …>` tag, so
/// every vector element is drawn over them.
fn with_underlay(svg: &str, size: (u32, u32), rasters: &[Raster]) -> Result<String> {
    let open = svg
        .find("<svg")
        .and_then(|i| svg[i..].find('>').map(|j| i + j + 1))
        .ok_or_else(|| Error::Internal("the SVG backend wrote no <svg> tag".into()))?;
    let mut under = format!(
        "\n<rect x=\"0\" y=\"0\" width=\"{}\" height=\"{}\" fill=\"#FFFFFF\"/>\n",
        size.0, size.1
    );
    for r in rasters {
        let mut png = Vec::new();
        r.image
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .map_err(|e| Error::encode("SVG raster PNG", e))?;
        under.push_str(&format!(
            "<image x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" href=\"data:image/png;base64,{}\"/>\n",
            r.x,
            r.y,
            r.image.width(),
            r.image.height(),
            base64::engine::general_purpose::STANDARD.encode(&png)
        ));
    }
    Ok(format!("{}{under}{}", &svg[..open], &svg[open..]))
}
