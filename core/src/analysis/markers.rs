//! Measuring a point from a rendered marker sphere: the sphere rendered alone in a window around its
//! projection, and the blob centroid of that window — how the study measures landmarks and the
//! calibration simulation measures BBs.

use glam::{DVec2, DVec3};

use super::blob_centroid;
use crate::Result;
use crate::geometry::View;
use crate::render::{ThicknessOptions, ThicknessRenderer};

/// Blob centroid (pixels of `view`) of a sphere of `radius_mm` at `position`, rendered alone by
/// `renderer`, searched within `1.5 r f / depth + 2` px of the projected centre. `None` when that search
/// disc is not wholly on the detector (a cut blob has a biased centroid) or the sphere is behind the
/// source. Only the disc's bounding box is rendered (the same rays as the full detector's pixels).
pub fn marker_centroid(
    renderer: &ThicknessRenderer,
    view: &View,
    position: DVec3,
    radius_mm: f64,
) -> Result<Option<DVec2>> {
    let k = view.intrinsics;
    let depth = view.depth(position);
    let radius_px = 1.5 * radius_mm * k.fx.max(k.fy) / depth + 2.0;
    let c = view.project(position);
    let (w, h) = (f64::from(k.width) - 1.0, f64::from(k.height) - 1.0);
    let inside = c.x - radius_px >= 0.0
        && c.y - radius_px >= 0.0
        && c.x + radius_px <= w
        && c.y + radius_px <= h;
    if !(inside && depth > 0.0) {
        return Ok(None);
    }
    let (u0, v0) = ((c.x - radius_px).floor(), (c.y - radius_px).floor());
    let (u1, v1) = (
        (c.x + radius_px).ceil().min(w),
        (c.y + radius_px).ceil().min(h),
    );
    let window = view.window(
        u0 as u32,
        v0 as u32,
        (u1 - u0) as u32 + 1,
        (v1 - v0) as u32 + 1,
    )?;
    let img = renderer.render(&window, &ThicknessOptions::image_only())?;
    let origin = DVec2::new(u0, v0);
    Ok(blob_centroid(&img.line_integral, c - origin, radius_px).map(|x| x + origin))
}
