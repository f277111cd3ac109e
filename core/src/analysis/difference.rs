//! Absolute differences of two images, `|A − B|` per pixel (written as heatmaps by
//! [`crate::io::write_heatmap_png`]).

use crate::io::ImageF32;
use crate::{Error, Result};

/// `|a − b|` per pixel.
pub fn abs_difference(a: &ImageF32, b: &ImageF32) -> Result<ImageF32> {
    if (a.width, a.height) != (b.width, b.height) {
        return Err(Error::invalid(
            "images",
            format!(
                "sizes differ: {}×{} vs {}×{}",
                a.width, a.height, b.width, b.height
            ),
        ));
    }
    Ok(ImageF32 {
        width: a.width,
        height: a.height,
        data: a
            .data
            .iter()
            .zip(&b.data)
            .map(|(x, y)| (x - y).abs())
            .collect(),
    })
}
