//! Row-major float32 images, float TIFF I/O and 8-bit PNG previews.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use tiff::decoder::{Decoder, DecodingResult};
use tiff::encoder::{TiffEncoder, colortype};

use super::write_atomic;
use crate::{Error, Result};

/// A `height × width` row-major float32 image; pixel (u, v) is `data[v * width + u]`.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageF32 {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

impl ImageF32 {
    pub fn zeros(width: u32, height: u32) -> Self {
        ImageF32 {
            width,
            height,
            data: vec![0.0; width as usize * height as usize],
        }
    }

    #[inline]
    pub fn get(&self, u: u32, v: u32) -> f32 {
        self.data[v as usize * self.width as usize + u as usize]
    }

    /// Largest finite value (0 for an empty or all-NaN image).
    pub fn max(&self) -> f32 {
        self.data
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(0.0f32, f32::max)
    }
}

/// Writes a single-channel float32 TIFF atomically.
pub fn write_tiff_f32(path: &Path, img: &ImageF32) -> Result<()> {
    write_atomic(path, |w| {
        let mut enc = TiffEncoder::new(w).map_err(|e| Error::format(path, e.to_string()))?;
        enc.write_image::<colortype::Gray32Float>(img.width, img.height, &img.data)
            .map_err(|e| Error::format(path, e.to_string()))
    })
}

/// Reads a single-channel TIFF (float32, or any integer type converted to f32).
pub fn read_tiff_f32(path: &Path) -> Result<ImageF32> {
    Ok(read_tiff(path)?.image)
}

/// Reads `path` as a DRR: one page of float samples, as spinedrr writes them. An integer TIFF (a
/// detector's raw image, an 8-bit export) or a stack of pages is refused, naming what it is: its values
/// are not a DRR's and comparing them as one would measure nonsense.
pub fn read_drr_tiff(path: &Path) -> Result<ImageF32> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    decode_drr_tiff(BufReader::new(file), path)
}

/// [`read_drr_tiff`] of bytes from any reader; `origin` names them in errors.
pub fn decode_drr_tiff<R: std::io::Read + std::io::Seek>(
    reader: R,
    origin: &Path,
) -> Result<ImageF32> {
    let path = origin;
    let t = decode_tiff(reader, path)?;
    if !t.float {
        return Err(Error::format(
            path,
            format!(
                "holds {} integer samples, not the float32 values of a DRR (spinedrr writes DRRs as \
                 float TIFF)",
                t.sample
            ),
        ));
    }
    if t.more_pages {
        return Err(Error::format(
            path,
            "holds more than one page (an image stack), not one DRR",
        ));
    }
    Ok(t.image)
}

/// A decoded TIFF: its first page, whether its samples are floats, and whether more pages follow.
struct Tiff {
    image: ImageF32,
    float: bool,
    sample: &'static str,
    more_pages: bool,
}

fn read_tiff(path: &Path) -> Result<Tiff> {
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    decode_tiff(BufReader::new(file), path)
}

fn decode_tiff<R: std::io::Read + std::io::Seek>(reader: R, path: &Path) -> Result<Tiff> {
    let bad = |e: tiff::TiffError| Error::format(path, format!("not a readable TIFF image: {e}"));
    let mut dec = Decoder::new(reader).map_err(bad)?;
    let (width, height) = dec.dimensions().map_err(bad)?;
    let colour = dec.colortype().map_err(bad)?;
    if !matches!(colour, tiff::ColorType::Gray(_)) {
        return Err(Error::format(
            path,
            format!("expected a single-channel image, found {colour:?}"),
        ));
    }
    let (data, float, sample): (Vec<f32>, bool, &'static str) = match dec
        .read_image()
        .map_err(bad)?
    {
        DecodingResult::F32(v) => (v, true, "32-bit float"),
        DecodingResult::F64(v) => (
            v.into_iter().map(|x| x as f32).collect(),
            true,
            "64-bit float",
        ),
        DecodingResult::U8(v) => (
            v.into_iter().map(f32::from).collect(),
            false,
            "8-bit unsigned",
        ),
        DecodingResult::U16(v) => (
            v.into_iter().map(f32::from).collect(),
            false,
            "16-bit unsigned",
        ),
        DecodingResult::I16(v) => (
            v.into_iter().map(f32::from).collect(),
            false,
            "16-bit signed",
        ),
        DecodingResult::U32(v) => (
            v.into_iter().map(|x| x as f32).collect(),
            false,
            "32-bit unsigned",
        ),
        DecodingResult::I32(v) => (
            v.into_iter().map(|x| x as f32).collect(),
            false,
            "32-bit signed",
        ),
        _ => {
            return Err(Error::format(
                path,
                "unsupported TIFF sample type (spinedrr reads 8-, 16- and 32-bit integers and 32- and \
                 64-bit floats)",
            ));
        }
    };
    if data.len() != width as usize * height as usize {
        return Err(Error::format(
            path,
            "pixel count does not match the image size",
        ));
    }
    Ok(Tiff {
        image: ImageF32 {
            width,
            height,
            data,
        },
        float,
        sample,
        more_pages: dec.more_images(),
    })
}

/// Writes an 8-bit grayscale PNG preview, scaled so that `[0, max]` maps to `[0, 255]`.
/// With `invert`, bright means little signal (for intensity images, where bone is dark).
pub fn write_preview_png(path: &Path, img: &ImageF32, invert: bool) -> Result<()> {
    let max = img.max();
    let scale = if max > 0.0 { 255.0 / max } else { 0.0 };
    let bytes: Vec<u8> = img
        .data
        .iter()
        .map(|&v| {
            let g = (v.max(0.0) * scale).round().clamp(0.0, 255.0) as u8;
            if invert { 255 - g } else { g }
        })
        .collect();
    write_gray_png(path, img.width, img.height, bytes)
}

/// Writes a binary mask as an 8-bit PNG (0 or 255).
pub fn write_mask_png(path: &Path, width: u32, height: u32, mask: &[bool]) -> Result<()> {
    let bytes = mask.iter().map(|&m| if m { 255 } else { 0 }).collect();
    write_gray_png(path, width, height, bytes)
}

fn write_gray_png(path: &Path, width: u32, height: u32, bytes: Vec<u8>) -> Result<()> {
    let img = image::GrayImage::from_raw(width, height, bytes)
        .ok_or_else(|| Error::invalid("image", "buffer size does not match width × height"))?;
    write_atomic(path, |w| {
        img.write_to(w, image::ImageFormat::Png)
            .map_err(|e| Error::format(path, e.to_string()))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiff_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.tiff");
        let mut img = ImageF32::zeros(7, 5);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = (i as f32).sqrt() * 1.37 - 2.0;
        }
        write_tiff_f32(&p, &img).unwrap();
        assert_eq!(read_tiff_f32(&p).unwrap(), img);
        std::fs::write(&p, b"not a tiff").unwrap();
        assert!(
            read_tiff_f32(&p)
                .unwrap_err()
                .to_string()
                .contains("a.tiff")
        );
    }
}
