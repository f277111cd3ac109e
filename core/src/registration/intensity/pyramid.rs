//! The multi-resolution schedule: detectors binned by `b` (b × b pixels averaged into one) and the
//! intrinsics that go with them.
//!
//! Pixel centres sit at integer coordinates, so binned pixel `i` averages fine pixels `b·i … b·i + b − 1`,
//! whose centre is fine coordinate `b·i + (b − 1)/2`: a fine coordinate `c` maps to `(c − (b − 1)/2) / b`.
//! Hence `fx' = fx / b`, `fy' = fy / b`, `s' = s / b`, `cx' = (cx − (b − 1)/2) / b` (same for `cy`), and the
//! binned detector is `⌊w / b⌋ × ⌊h / b⌋` (a remainder row or column is dropped).
//!
//! A detector *subsampled* by `b` keeps every `b`-th pixel instead, fine pixel `b·i + o` with
//! `o = ⌊(b − 1)/2⌋` (the pixel nearest the block's centre): `cx' = (cx − o) / b`. Its rays are rays of the
//! full detector, so a DRR rendered through it samples exactly the pixels the subsampled fixed image kept.

use crate::geometry::{Intrinsics, View};
use crate::io::ImageF32;
use crate::{Error, Result};

/// The view of the detector binned by `b` (same source and orientation).
pub fn binned_view(view: &View, b: u32) -> Result<View> {
    let k = view.intrinsics;
    let (w, h) = (k.width / b.max(1), k.height / b.max(1));
    if b == 0 || w < 8 || h < 8 {
        return Err(Error::invalid(
            "levels",
            format!(
                "binning {}×{} px of view '{}' by {b} leaves fewer than 8×8 pixels",
                k.width, k.height, view.name
            ),
        ));
    }
    let bf = f64::from(b);
    let half = (bf - 1.0) / 2.0;
    let binned = Intrinsics {
        fx: k.fx / bf,
        fy: k.fy / bf,
        skew: k.skew / bf,
        cx: (k.cx - half) / bf,
        cy: (k.cy - half) / bf,
        width: w,
        height: h,
    };
    binned.validate()?;
    Ok(View {
        intrinsics: binned,
        ..view.clone()
    })
}

/// The view of the detector subsampled by `b` (see the module documentation).
pub fn subsampled_view(view: &View, b: u32) -> Result<View> {
    let mut v = binned_view(view, b)?;
    let k = view.intrinsics;
    let (bf, o) = (f64::from(b), f64::from((b.max(1) - 1) / 2));
    v.intrinsics.cx = (k.cx - o) / bf;
    v.intrinsics.cy = (k.cy - o) / bf;
    v.intrinsics.validate()?;
    Ok(v)
}

/// The image subsampled by `b`: pixel `(i, j)` is fine pixel `(b·i + o, b·j + o)` (see the module
/// documentation; remainders dropped).
pub fn subsampled_image(img: &ImageF32, b: u32) -> ImageF32 {
    let b = b.max(1) as usize;
    let o = (b - 1) / 2;
    let (w, h) = (img.width as usize / b, img.height as usize / b);
    let fw = img.width as usize;
    ImageF32 {
        width: w as u32,
        height: h as u32,
        data: (0..h)
            .flat_map(|j| (0..w).map(move |i| (j, i)))
            .map(|(j, i)| img.data[(b * j + o) * fw + b * i + o])
            .collect(),
    }
}

/// The image binned by `b`: each output pixel is the mean of a `b × b` block (remainders dropped).
pub fn binned_image(img: &ImageF32, b: u32) -> ImageF32 {
    if b <= 1 {
        return img.clone();
    }
    let mut out = ImageF32::zeros(0, 0);
    binned_image_into(img, b, &mut out);
    out
}

/// [`binned_image`] into `out`, reusing its buffer (`b ≥ 1`; `b = 1` copies).
pub fn binned_image_into(img: &ImageF32, b: u32, out: &mut ImageF32) {
    let b = b.max(1);
    let (w, h) = (img.width / b, img.height / b);
    let (bu, fw) = (b as usize, img.width as usize);
    out.width = w;
    out.height = h;
    out.data.clear();
    out.data.resize(w as usize * h as usize, 0.0);
    let norm = 1.0 / (bu * bu) as f64;
    for v in 0..h as usize {
        for u in 0..w as usize {
            let mut s = 0.0;
            for dv in 0..bu {
                let row = &img.data[(v * bu + dv) * fw + u * bu..][..bu];
                s += row.iter().map(|&x| f64::from(x)).sum::<f64>();
            }
            out.data[v * w as usize + u] = (s * norm) as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::CArm;
    use glam::DVec3;

    #[test]
    fn a_point_projects_to_the_centre_of_its_bin() {
        let ap = CArm::default_paper().view("ap").unwrap().clone();
        for b in [2, 3, 4, 8] {
            let v = binned_view(&ap, b).unwrap();
            for p in [DVec3::new(10.0, 5.0, -20.0), DVec3::new(-30.0, 40.0, 7.0)] {
                let (fine, coarse) = (ap.project(p), v.project(p));
                let back = coarse * f64::from(b) + glam::DVec2::splat((f64::from(b) - 1.0) / 2.0);
                assert!((back - fine).length() < 1e-9, "b = {b}");
            }
        }
    }

    #[test]
    fn a_subsampled_pixel_is_the_fine_pixel_it_keeps() {
        let ap = CArm::default_paper().view("ap").unwrap().clone();
        for b in [2u32, 3, 4, 8] {
            let v = subsampled_view(&ap, b).unwrap();
            let o = f64::from((b - 1) / 2);
            for p in [DVec3::new(10.0, 5.0, -20.0), DVec3::new(-30.0, 40.0, 7.0)] {
                let (fine, coarse) = (ap.project(p), v.project(p));
                let back = coarse * f64::from(b) + glam::DVec2::splat(o);
                assert!((back - fine).length() < 1e-9, "b = {b}");
            }
        }
        let img = ImageF32 {
            width: 7,
            height: 5,
            data: (0..35).map(|i| i as f32).collect(),
        };
        let s = subsampled_image(&img, 3);
        // Kept: columns 1 and 4 of row 1 (fine pixels 8 and 11).
        assert_eq!((s.width, s.height, s.data.clone()), (2, 1, vec![8.0, 11.0]));
        assert_eq!(
            subsampled_image(&img, 2).data,
            vec![0.0, 2.0, 4.0, 14.0, 16.0, 18.0]
        );
    }

    #[test]
    fn binning_averages_blocks() {
        let img = ImageF32 {
            width: 5,
            height: 4,
            data: (0..20).map(|i| i as f32).collect(),
        };
        let b = binned_image(&img, 2);
        assert_eq!((b.width, b.height), (2, 2));
        assert_eq!(b.data, vec![3.0, 5.0, 13.0, 15.0]);
    }
}
