//! The intrinsic matrix `K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]` and the detector size.

use glam::{DMat3, DVec2, DVec3};
use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// Largest detector side accepted (pixels). Anything larger is a typo, not a detector.
pub const MAX_DETECTOR_PX: u32 = 8192;

/// Largest focal length and largest |skew| accepted (pixels): 1000 × the largest detector side. A focal
/// length that long sees less than a thousandth of a radian across any detector; past it, pixel
/// arithmetic loses its precision, not only its meaning.
pub const MAX_FOCAL_PX: f64 = 1000.0 * MAX_DETECTOR_PX as f64;

/// Smallest focal length accepted (pixels): below one pixel, a single pixel spans close to 90°.
pub const MIN_FOCAL_PX: f64 = 1.0;

/// Largest |cx|, |cy| accepted (pixels): 10 × the largest detector side, so the piercing point may lie
/// off the detector (an offset detector) but not at infinity. The bounds are multiples of the largest
/// detector, not of this one, so a detector window ([`crate::geometry::View::window`]) stays valid.
pub const MAX_PRINCIPAL_POINT_PX: f64 = 10.0 * MAX_DETECTOR_PX as f64;

/// Pinhole intrinsics in pixels plus the detector size.
///
/// `fx = SDD / pixel_spacing_u`, `fy = SDD / pixel_spacing_v`; `(cx, cy)` is the piercing point.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub skew: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: u32,
    pub height: u32,
}

impl Intrinsics {
    /// Intrinsics of a flat detector at `sdd_mm` from the source with the piercing point at the detector
    /// centre (`cx = (width - 1) / 2` under the integer-pixel-centre convention).
    pub fn from_detector(
        sdd_mm: f64,
        pixel_spacing_mm: [f64; 2],
        width: u32,
        height: u32,
    ) -> Result<Self> {
        for (name, v) in [
            ("sdd_mm", sdd_mm),
            ("pixel_spacing_mm[0]", pixel_spacing_mm[0]),
            ("pixel_spacing_mm[1]", pixel_spacing_mm[1]),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::invalid(
                    name,
                    format!("must be a positive number, got {v}"),
                ));
            }
        }
        let k = Intrinsics {
            fx: sdd_mm / pixel_spacing_mm[0],
            fy: sdd_mm / pixel_spacing_mm[1],
            skew: 0.0,
            cx: (f64::from(width) - 1.0) / 2.0,
            cy: (f64::from(height) - 1.0) / 2.0,
            width,
            height,
        };
        k.validate()?;
        Ok(k)
    }

    /// Builds intrinsics from a 3×3 matrix (row-major) and a detector size.
    pub fn from_matrix(k: [[f64; 3]; 3], width: u32, height: u32) -> Result<Self> {
        if k[1][0] != 0.0 || k[2][0] != 0.0 || k[2][1] != 0.0 || k[2][2] != 1.0 {
            return Err(Error::invalid(
                "K",
                "must be upper triangular with K[2][2] = 1 ([[fx, s, cx], [0, fy, cy], [0, 0, 1]])",
            ));
        }
        let out = Intrinsics {
            fx: k[0][0],
            fy: k[1][1],
            skew: k[0][1],
            cx: k[0][2],
            cy: k[1][2],
            width,
            height,
        };
        out.validate()?;
        Ok(out)
    }

    /// Checks that every parameter is finite and within its domain ([`MIN_FOCAL_PX`] ≤ fx, fy ≤
    /// [`MAX_FOCAL_PX`], |skew| ≤ [`MAX_FOCAL_PX`], |cx|, |cy| ≤ [`MAX_PRINCIPAL_POINT_PX`]) and the
    /// detector size is sane.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("fx", self.fx),
            ("fy", self.fy),
            ("skew", self.skew),
            ("cx", self.cx),
            ("cy", self.cy),
        ] {
            if !v.is_finite() {
                return Err(Error::invalid(
                    format!("intrinsics.{name}"),
                    format!("must be finite, got {v}"),
                ));
            }
        }
        for (name, v) in [("width", self.width), ("height", self.height)] {
            if v == 0 || v > MAX_DETECTOR_PX {
                return Err(Error::invalid(
                    format!("detector {name}"),
                    format!("must be between 1 and {MAX_DETECTOR_PX} pixels, got {v}"),
                ));
            }
        }
        if self.fx <= 0.0 || self.fy <= 0.0 {
            return Err(Error::invalid(
                "intrinsics.fx/fy",
                format!(
                    "focal lengths must be positive, got fx = {}, fy = {}",
                    self.fx, self.fy
                ),
            ));
        }
        for (name, v) in [("fx", self.fx), ("fy", self.fy)] {
            if !(MIN_FOCAL_PX..=MAX_FOCAL_PX).contains(&v) {
                return Err(Error::invalid(
                    format!("intrinsics.{name}"),
                    format!(
                        "focal length {v} px is outside [{MIN_FOCAL_PX}, {MAX_FOCAL_PX}] px \
                         (1000 × the largest detector side, {MAX_DETECTOR_PX} px)"
                    ),
                ));
            }
        }
        if self.skew.abs() > MAX_FOCAL_PX {
            return Err(Error::invalid(
                "intrinsics.skew",
                format!(
                    "skew {} px exceeds ±{MAX_FOCAL_PX} px (1000 × the largest detector side, \
                     {MAX_DETECTOR_PX} px)",
                    self.skew
                ),
            ));
        }
        for (name, v) in [("cx", self.cx), ("cy", self.cy)] {
            if v.abs() > MAX_PRINCIPAL_POINT_PX {
                return Err(Error::invalid(
                    format!("intrinsics.{name}"),
                    format!(
                        "principal point {v} px is beyond ±{MAX_PRINCIPAL_POINT_PX} px (10 × the \
                         largest detector side, {MAX_DETECTOR_PX} px)"
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The matrix `K`.
    pub fn matrix(&self) -> DMat3 {
        DMat3::from_cols(
            DVec3::new(self.fx, 0.0, 0.0),
            DVec3::new(self.skew, self.fy, 0.0),
            DVec3::new(self.cx, self.cy, 1.0),
        )
    }

    /// `K` as row-major nested arrays (the sidecar and JSON layout).
    pub fn matrix_rows(&self) -> [[f64; 3]; 3] {
        [
            [self.fx, self.skew, self.cx],
            [0.0, self.fy, self.cy],
            [0.0, 0.0, 1.0],
        ]
    }

    /// Pixel of a camera-frame point: `(fx x + s y) / z + cx`, `fy y / z + cy`.
    #[inline]
    pub fn project_camera(&self, p: DVec3) -> DVec2 {
        let inv_z = 1.0 / p.z;
        let x = p.x * inv_z;
        let y = p.y * inv_z;
        DVec2::new(self.fx * x + self.skew * y + self.cx, self.fy * y + self.cy)
    }

    /// Camera-frame direction `K⁻¹ [u, v, 1]ᵀ` (not normalised; its z is 1).
    #[inline]
    pub fn back_project(&self, u: f64, v: f64) -> DVec3 {
        let y = (v - self.cy) / self.fy;
        let x = (u - self.cx - self.skew * y) / self.fx;
        DVec3::new(x, y, 1.0)
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }
}
