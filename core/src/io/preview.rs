//! Display-size PNG previews of figures (the report page embeds them): decoded, downscaled, posterised
//! and re-encoded here, in the optimised core, because every study report encodes one per figure and
//! this is pixel work (the study crate itself compiles without optimisation in the test build).

use std::path::Path;

use image::ImageEncoder as _;
use image::codecs::png::{CompressionType, FilterType, PngEncoder};

use crate::{Error, Result};

/// The PNG at `path` as a preview PNG: downscaled (triangle filter) to `max_width` px wide if wider, its
/// height in proportion, every channel rounded to `levels` evenly spaced levels ([`posterise`]), encoded
/// at PNG's best compression.
pub fn png_preview(path: &Path, max_width: u32, levels: u32) -> Result<Vec<u8>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let img = image::load_from_memory(&bytes).map_err(|e| Error::format(path, e.to_string()))?;
    let mut rgb = img.to_rgb8();
    if img.width() > max_width {
        let h = (f64::from(img.height()) * f64::from(max_width) / f64::from(img.width()))
            .round()
            .max(1.0) as u32;
        let filter = image::imageops::FilterType::Triangle;
        rgb = image::imageops::resize(&rgb, max_width, h, filter);
    }
    posterise(&mut rgb, levels);
    let mut png = Vec::new();
    let (w, h) = rgb.dimensions();
    PngEncoder::new_with_quality(&mut png, CompressionType::Best, FilterType::Adaptive)
        .write_image(&rgb, w, h, image::ExtendedColorType::Rgb8)
        .map_err(|e| Error::encode(format!("preview of {}", path.display()), e))?;
    Ok(png)
}

/// Rounds every channel to the nearest of `levels` (at least 2) evenly spaced levels (0 and 255 kept):
/// the anti-aliased edges of a downscaled chart otherwise make hundreds of thousands of colours, which PNG
/// compresses poorly; with few levels the preview is a fraction of the size and looks the same at
/// display size.
pub fn posterise(img: &mut image::RgbImage, levels: u32) {
    let step = 255.0 / f64::from(levels.max(2) - 1);
    for p in img.pixels_mut() {
        for c in &mut p.0 {
            *c = ((f64::from(*c) / step).round() * step).round() as u8;
        }
    }
}
