//! Silhouette contours: OpenCV `findContours` (Suzuki & Abe 1985) is the reference extractor, with a
//! sub-pixel variant on top (marching squares on the 0/1 mask, edge crossings at the half-pixel).

use glam::DVec2;

use crate::{Error, Result};

pub(crate) fn check_mask(mask: &[bool], width: u32, height: u32) -> Result<()> {
    if mask.len() != width as usize * height as usize || width == 0 || height == 0 {
        return Err(Error::invalid(
            "mask",
            format!("{} pixels do not make a {width}×{height} image", mask.len()),
        ));
    }
    Ok(())
}

/// A rectangular window of an image: origin `(u0, v0)` and size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Window {
    pub u0: usize,
    pub v0: usize,
    pub w: usize,
    pub h: usize,
}

/// The bounding box of the `true` pixels of several same-size masks, grown by one pixel and clipped to
/// the image (so that cropping changes no border decision). `None` if every mask is empty.
pub(crate) fn bounding_window(masks: &[&[bool]], width: u32, height: u32) -> Option<Window> {
    let (w, h) = (width as usize, height as usize);
    let (mut lo_u, mut lo_v, mut hi_u, mut hi_v) = (usize::MAX, usize::MAX, 0, 0);
    for m in masks {
        for (v, row) in m.chunks_exact(w).enumerate() {
            if let (Some(a), Some(b)) = (row.iter().position(|&x| x), row.iter().rposition(|&x| x))
            {
                (lo_u, hi_u, lo_v, hi_v) = (lo_u.min(a), hi_u.max(b), lo_v.min(v), hi_v.max(v));
            }
        }
    }
    if lo_u == usize::MAX {
        return None;
    }
    let (u0, v0) = (lo_u.saturating_sub(1), lo_v.saturating_sub(1));
    let (u1, v1) = ((hi_u + 1).min(w - 1), (hi_v + 1).min(h - 1));
    Some(Window {
        u0,
        v0,
        w: u1 - u0 + 1,
        h: v1 - v0 + 1,
    })
}

/// The pixels of `mask` (image width `width`) inside `win`, row-major.
pub(crate) fn crop(mask: &[bool], width: u32, win: Window) -> Vec<bool> {
    let w = width as usize;
    (win.v0..win.v0 + win.h)
        .flat_map(|v| mask[v * w + win.u0..v * w + win.u0 + win.w].iter().copied())
        .collect()
}

/// Every boundary of a mask (outer borders and hole borders, `RETR_LIST`), each the closed chain of
/// border pixel centres found by OpenCV (`CHAIN_APPROX_NONE`). Pixels on the image's outermost row or
/// column are treated as background, as OpenCV does.
pub fn contours(mask: &[bool], width: u32, height: u32) -> Result<Vec<Vec<DVec2>>> {
    check_mask(mask, width, height)?;
    // Only the mask's bounding window is traced (identical result, far fewer pixels).
    let Some(win) = bounding_window(&[mask], width, height) else {
        return Ok(Vec::new());
    };
    let bytes: Vec<u8> = crop(mask, width, win).into_iter().map(u8::from).collect();
    let found = spinedrr_cv::find_contours(&bytes, win.h, win.w, [win.u0 as i32, win.v0 as i32])
        .map_err(Error::opencv)?;
    Ok(found
        .into_iter()
        .map(|c| {
            c.into_iter()
                .map(|[x, y]| DVec2::new(f64::from(x), f64::from(y)))
                .collect()
        })
        .collect())
}

/// All contour points of a mask in one list (what the distance metrics consume).
pub fn contour_points(mask: &[bool], width: u32, height: u32) -> Result<Vec<DVec2>> {
    Ok(contours(mask, width, height)?
        .into_iter()
        .flatten()
        .collect())
}

/// Border pixels computed directly: mask pixels with a 4-neighbour outside the mask (or on the image
/// edge). The independent check of [`contours`] and the edge map of the edge-based distance.
pub fn border_pixels(mask: &[bool], width: u32, height: u32) -> Result<Vec<bool>> {
    check_mask(mask, width, height)?;
    let (w, h) = (width as usize, height as usize);
    let at = |u: usize, v: usize| mask[v * w + u];
    let mut out = vec![false; mask.len()];
    for v in 0..h {
        for u in 0..w {
            if !at(u, v) {
                continue;
            }
            let edge = u == 0 || v == 0 || u + 1 == w || v + 1 == h;
            out[v * w + u] =
                edge || !at(u - 1, v) || !at(u + 1, v) || !at(u, v - 1) || !at(u, v + 1);
        }
    }
    Ok(out)
}

/// Sub-pixel boundary points: the midpoints between every pair of 4-adjacent pixels whose mask values
/// differ (the 0.5 iso-line of the mask under linear interpolation, as in marching squares). Unordered;
/// only the mask's bounding window is scanned.
pub fn subpixel_boundary(mask: &[bool], width: u32, height: u32) -> Result<Vec<DVec2>> {
    check_mask(mask, width, height)?;
    let Some(win) = bounding_window(&[mask], width, height) else {
        return Ok(Vec::new());
    };
    let w = width as usize;
    let mut out = Vec::new();
    for v in win.v0..win.v0 + win.h {
        for u in win.u0..win.u0 + win.w {
            let m = mask[v * w + u];
            if u + 1 < win.u0 + win.w && mask[v * w + u + 1] != m {
                out.push(DVec2::new(u as f64 + 0.5, v as f64));
            }
            if v + 1 < win.v0 + win.h && mask[(v + 1) * w + u] != m {
                out.push(DVec2::new(u as f64, v as f64 + 0.5));
            }
        }
    }
    Ok(out)
}
