//! Where the anatomy is: the union of two silhouettes dilated by a margin, the pixels over which the
//! region image similarities (NCC, SSIM, MI, gradient correlation) are computed, so that the empty
//! detector around a vertebra does not dominate them.

use crate::{Error, Result};

/// The margin (px, Chebyshev) by which the silhouettes' union is dilated: the SSIM window's reach (5 px)
/// plus the Sobel kernel's (1 px) and a few pixels of background on every side of the edge.
pub const REGION_MARGIN_PX: usize = 10;

/// A set of pixels of a `width × height` image, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Region {
    pub width: u32,
    pub height: u32,
    pub inside: Vec<bool>,
}

impl Region {
    /// The union of masks `a` and `b` (row-major, `width × height`) dilated by a square of half-width
    /// `margin` px (every pixel within Chebyshev distance `margin` of a silhouette pixel).
    pub fn around(
        a: &[bool],
        b: &[bool],
        width: u32,
        height: u32,
        margin: usize,
    ) -> Result<Region> {
        let (w, h) = (width as usize, height as usize);
        if a.len() != w * h || b.len() != w * h {
            return Err(Error::invalid(
                "region masks",
                format!(
                    "{} and {} pixels for a {width}×{height} image",
                    a.len(),
                    b.len()
                ),
            ));
        }
        let union: Vec<bool> = a.iter().zip(b).map(|(x, y)| *x || *y).collect();
        // Separable max filter: along rows, then along columns, each through a running count.
        let dilate = |src: &[bool], n: usize, stride: usize, lines: usize, step: usize| {
            let mut out = vec![false; src.len()];
            for l in 0..lines {
                let at = |i: usize| l * step + i * stride;
                let mut count = 0usize;
                for i in 0..n.min(margin) {
                    count += usize::from(src[at(i)]);
                }
                for i in 0..n {
                    if i + margin < n {
                        count += usize::from(src[at(i + margin)]);
                    }
                    if i > margin {
                        count -= usize::from(src[at(i - margin - 1)]);
                    }
                    out[at(i)] = count > 0;
                }
            }
            out
        };
        let rows = dilate(&union, w, 1, h, w);
        let inside = dilate(&rows, h, w, w, 1);
        Ok(Region {
            width,
            height,
            inside,
        })
    }

    /// The number of pixels in the region.
    pub fn len(&self) -> usize {
        self.inside.iter().filter(|&&x| x).count()
    }

    /// Whether the region holds no pixel.
    pub fn is_empty(&self) -> bool {
        !self.inside.contains(&true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_pixel_dilates_to_a_clipped_square() {
        let (w, h) = (9u32, 7u32);
        let mut a = vec![false; 63];
        a[3 * 9 + 1] = true; // (u, v) = (1, 3)
        let r = Region::around(&a, &[false; 63], w, h, 2).unwrap();
        for v in 0..7i32 {
            for u in 0..9i32 {
                let expect = (u - 1).abs() <= 2 && (v - 3).abs() <= 2;
                assert_eq!(r.inside[(v * 9 + u) as usize], expect, "({u}, {v})");
            }
        }
        assert_eq!(r.len(), 4 * 5);
        assert!(Region::around(&a, &a[1..], w, h, 2).is_err());
    }
}
