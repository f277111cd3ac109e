//! Signed-distance primitives (negative inside, millimetres) and their smooth union.
//!
//! The rounded box is exact (Quílez's formula); the tapered box (half-sizes varying linearly along its
//! length) is exact where it does not taper and a first-order estimate elsewhere. The elliptic
//! cross-sections and the ellipsoid use Taubin's first-order distance ([`ellipse_distance`],
//! [`ellipsoid_distance`]), exact on the axes and to first order near the surface; inside an elongated
//! ellipse its gradient norm reaches ~3 (the pedicles), so they are distance estimates, not 1-Lipschitz
//! bounds. The vertebral body ([`Shape::Body`]) is a rounded prism over a kidney-shaped section
//! ([`kidney_distance`]) with a concave waist and concave endplates. The polynomial smooth minimum and
//! rigid placements keep these properties.

use glam::{DMat3, DVec2, DVec3};

/// A rigid placement of a primitive: `local = axesᵀ (p − origin)`; the columns of `axes` are the local
/// x, y, z axes expressed in the parent frame (orthonormal, right-handed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    pub origin: DVec3,
    pub axes: DMat3,
}

impl Frame {
    pub fn at(origin: DVec3) -> Frame {
        Frame {
            origin,
            axes: DMat3::IDENTITY,
        }
    }

    /// A frame at the midpoint of `start → end` whose local x runs along the segment and whose local z is
    /// `up` made orthogonal to it.
    pub fn along(start: DVec3, end: DVec3, up: DVec3) -> Frame {
        let x = (end - start).normalize();
        let z = (up - x * up.dot(x)).normalize();
        let y = z.cross(x);
        Frame {
            origin: (start + end) * 0.5,
            axes: DMat3::from_cols(x, y, z),
        }
    }

    #[inline]
    pub fn to_local(&self, p: DVec3) -> DVec3 {
        self.axes.transpose() * (p - self.origin)
    }

    #[inline]
    pub fn to_parent(&self, q: DVec3) -> DVec3 {
        self.axes * q + self.origin
    }
}

/// A primitive in its own frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// Box `|x| ≤ half.x, |y| ≤ half.y, |z| ≤ half.z` with edges rounded by `radius` (exact SDF).
    RoundedBox { half: DVec3, radius: f64 },
    /// Elliptic cylinder along z, semi-axes `a` (x) and `b` (y), `|z| ≤ half_h`, rim rounded by `radius`.
    EllipticCylinder {
        a: f64,
        b: f64,
        half_h: f64,
        radius: f64,
    },
    /// Box along x (`|x| ≤ half_len`) whose half-sizes across (y) and up (z) run linearly from `start`
    /// at `x = −half_len` to `end` at `x = +half_len`; edges rounded by `radius`.
    TaperedBox {
        half_len: f64,
        start: DVec2,
        end: DVec2,
        radius: f64,
    },
    /// Ellipsoid with semi-axes `radii`.
    Ellipsoid { radii: DVec3 },
    /// A vertebral body: a prism `|z| ≤ half_h` over the kidney section of [`kidney_distance`]
    /// (half-width `a`, mid-sagittal half-depth `b`, posterior wall concave by `posterior`), rim rounded
    /// by `radius`; the lateral and anterior walls narrow by the fraction `waist` at mid-height
    /// (scaled by `1 − waist·(1 − (z/half_h)²)²`, flat toward the rims), and each endplate is concave by `concavity` at its
    /// centre, falling to zero at the rim.
    Body {
        a: f64,
        b: f64,
        half_h: f64,
        radius: f64,
        posterior: f64,
        waist: f64,
        concavity: f64,
    },
}

impl Shape {
    /// Signed distance (bound) at a local point.
    pub fn sdf(&self, p: DVec3) -> f64 {
        match *self {
            Shape::RoundedBox { half, radius } => {
                let q = p.abs() - half + DVec3::splat(radius);
                q.max(DVec3::ZERO).length() + q.max_element().min(0.0) - radius
            }
            Shape::EllipticCylinder {
                a,
                b,
                half_h,
                radius,
            } => {
                let d2 = ellipse_distance(DVec2::new(p.x, p.y), a - radius, b - radius);
                let q = DVec2::new(d2, p.z.abs() - (half_h - radius));
                q.max(DVec2::ZERO).length() + q.max_element().min(0.0) - radius
            }
            Shape::TaperedBox {
                half_len,
                start,
                end,
                radius,
            } => {
                let t = ((p.x + half_len) / (2.0 * half_len)).clamp(0.0, 1.0);
                let h = start.lerp(end, t);
                let half = DVec3::new(half_len, h.x, h.y);
                let q = p.abs() - half + DVec3::splat(radius);
                q.max(DVec3::ZERO).length() + q.max_element().min(0.0) - radius
            }
            Shape::Ellipsoid { radii } => ellipsoid_distance(p, radii),
            Shape::Body {
                a,
                b,
                half_h,
                radius,
                posterior,
                waist,
                concavity,
            } => {
                let t = (p.z / half_h).clamp(-1.0, 1.0);
                let s = 1.0 - waist * (1.0 - t * t).powi(2);
                let q = DVec2::new(p.x / s, if p.y > 0.0 { p.y / s } else { p.y });
                let d2 = kidney_distance(q, a - radius, b - radius, posterior) * s;
                let rho2 = (p.x / a).powi(2) + (p.y / b).powi(2);
                let top = half_h - concavity * (1.0 - rho2).max(0.0);
                let v = DVec2::new(d2, p.z.abs() - (top - radius));
                v.max(DVec2::ZERO).length() + v.max_element().min(0.0) - radius
            }
        }
    }

    /// Half extents of the local bounding box.
    pub fn half_extent(&self) -> DVec3 {
        match *self {
            Shape::RoundedBox { half, .. } => half,
            Shape::EllipticCylinder { a, b, half_h, .. } => DVec3::new(a, b, half_h),
            Shape::TaperedBox {
                half_len,
                start,
                end,
                ..
            } => DVec3::new(half_len, start.x.max(end.x), start.y.max(end.y)),
            Shape::Ellipsoid { radii } => radii,
            Shape::Body {
                a,
                b,
                half_h,
                posterior,
                ..
            } => DVec3::new(a, b + posterior, half_h),
        }
    }
}

/// A placed primitive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placed {
    pub frame: Frame,
    pub shape: Shape,
}

impl Placed {
    #[inline]
    pub fn sdf(&self, p: DVec3) -> f64 {
        self.shape.sdf(self.frame.to_local(p))
    }

    /// Axis-aligned bounds in the parent frame (`centre ± |axes|·half`).
    pub fn bounds(&self) -> (DVec3, DVec3) {
        let h = self.shape.half_extent();
        let a = self.frame.axes;
        let r = DVec3::new(
            a.row(0).abs().dot(h),
            a.row(1).abs().dot(h),
            a.row(2).abs().dot(h),
        );
        (self.frame.origin - r, self.frame.origin + r)
    }
}

/// Approximate signed distance to the ellipse `(x/a)² + (y/b)² = 1`: the implicit `k₀ − 1` divided by
/// its gradient norm, `k₀ (k₀ − 1) / k₁` with `k₀ = ‖(x/a, y/b)‖`, `k₁ = ‖(x/a², y/b²)‖` (Taubin's
/// first-order distance), clamped to `−min(a, b)` inside. Exact on both axes and to first order near the
/// curve, so offsets (rounded rims) keep the nominal semi-axes.
#[inline]
pub fn ellipse_distance(p: DVec2, a: f64, b: f64) -> f64 {
    let k0 = DVec2::new(p.x / a, p.y / b).length();
    let k1 = DVec2::new(p.x / (a * a), p.y / (b * b)).length();
    if k1 < 1e-12 {
        return -a.min(b);
    }
    // No interior point is deeper than the minor semi-axis; the clamp also removes the direction-
    // dependent jump of the first-order formula at the centre (its gradient blows up there).
    (k0 * (k0 - 1.0) / k1).max(-a.min(b))
}

/// Taubin's first-order distance to the ellipsoid `Σ (p_i/r_i)² = 1` (as [`ellipse_distance`]),
/// clamped to `−min(r)` inside.
#[inline]
pub fn ellipsoid_distance(p: DVec3, r: DVec3) -> f64 {
    let k0 = (p / r).length();
    let k1 = (p / (r * r)).length();
    if k1 < 1e-12 {
        return -r.min_element();
    }
    (k0 * (k0 - 1.0) / k1).max(-r.min_element())
}

/// Size of the smooth maximum that rounds the edges of the kidney's posterior notch (mm).
const KIDNEY_BLEND_MM: f64 = 3.0;

/// Approximate signed distance to a kidney-shaped section: the ellipse of half-width `a` reaching
/// `y = +b` anteriorly and `y = −b − posterior` posteriorly, with a shallow notch (a circle of radius
/// `1.5 a` touching `(0, −b)`) cut from its posterior side, so the mid-sagittal depth is `2b` and the
/// posterolateral lobes reach up to `posterior` further back. The notch's edges are rounded by a smooth maximum.
#[inline]
pub fn kidney_distance(p: DVec2, a: f64, b: f64, posterior: f64) -> f64 {
    let de = ellipse_distance(
        DVec2::new(p.x, p.y + posterior / 2.0),
        a,
        b + posterior / 2.0,
    );
    if posterior <= 0.0 {
        return de;
    }
    let rc = 1.5 * a;
    let dc = (p - DVec2::new(0.0, -b - rc)).length() - rc;
    -smooth_min(-de, dc, KIDNEY_BLEND_MM)
}

/// Polynomial smooth minimum (Quílez): equals `min(a, b)` when `|a − b| ≥ k`, otherwise blends with a
/// fillet of size about `k/4`; `k = 0` gives the plain minimum. It never exceeds `min(a, b)`.
#[inline]
pub fn smooth_min(a: f64, b: f64, k: f64) -> f64 {
    if k <= 0.0 {
        return a.min(b);
    }
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.min(b) - h * h * k * 0.25
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounded_box_distance_is_exact_on_faces_and_corners() {
        let s = Shape::RoundedBox {
            half: DVec3::new(2.0, 3.0, 4.0),
            radius: 0.5,
        };
        assert!((s.sdf(DVec3::new(5.0, 0.0, 0.0)) - 3.0).abs() < 1e-12);
        assert!((s.sdf(DVec3::ZERO) + 2.0).abs() < 1e-12);
        let c = DVec3::new(1.5, 2.5, 3.5);
        let p = c + DVec3::ONE.normalize() * 2.0;
        assert!((s.sdf(p) - 1.5).abs() < 1e-12);
    }

    #[test]
    fn elliptic_cylinder_is_exact_on_minor_axis_and_lipschitz() {
        let s = Shape::EllipticCylinder {
            a: 20.0,
            b: 15.0,
            half_h: 10.0,
            radius: 2.0,
        };
        assert!((s.sdf(DVec3::new(0.0, 18.0, 0.0)) - 3.0).abs() < 1e-12);
        assert!((s.sdf(DVec3::new(0.0, 0.0, 12.0)) - 2.0).abs() < 1e-12);
        let (p, q) = (DVec3::new(19.0, 3.0, 9.5), DVec3::new(19.2, 2.9, 9.3));
        assert!((s.sdf(p) - s.sdf(q)).abs() <= (p - q).length() + 1e-12);
    }

    #[test]
    fn kidney_has_the_nominal_midline_depth_and_posterior_lobes() {
        let (a, b, e) = (20.0, 16.0, 2.5);
        assert!(kidney_distance(DVec2::new(0.0, b), a, b, e).abs() < 1e-9);
        assert!(kidney_distance(DVec2::new(0.0, -b), a, b, e).abs() < 0.05);
        assert!(kidney_distance(DVec2::new(a, -e / 2.0), a, b, e).abs() < 1e-9);
        // A posterolateral lobe reaches behind the midline's posterior wall.
        assert!(kidney_distance(DVec2::new(0.4 * a, -b), a, b, e) < -0.2);
        let body = Shape::Body {
            a,
            b,
            half_h: 12.0,
            radius: 2.0,
            posterior: e,
            waist: 0.07,
            concavity: 1.0,
        };
        // Concave endplate at the centre, waist narrower than the rim.
        assert!(body.sdf(DVec3::new(0.0, 0.0, 11.0)).abs() < 1e-9);
        assert!(body.sdf(DVec3::new(a * 0.95, 0.0, 0.0)) > 0.0);
        assert!(body.sdf(DVec3::new(a * 0.95, 0.0, 11.0)) < 0.0);
    }

    #[test]
    fn ellipsoid_and_tapered_box_are_exact_on_their_axes() {
        let r = DVec3::new(4.0, 3.0, 9.0);
        assert!((ellipsoid_distance(DVec3::new(0.0, 0.0, 11.0), r) - 2.0).abs() < 1e-12);
        assert!((ellipsoid_distance(DVec3::new(5.0, 0.0, 0.0), r) - 1.0).abs() < 1e-12);
        let s = Shape::TaperedBox {
            half_len: 10.0,
            start: DVec2::new(3.0, 8.0),
            end: DVec2::new(2.0, 4.0),
            radius: 1.0,
        };
        assert!((s.sdf(DVec3::new(0.0, 0.0, 7.0)) - 1.0).abs() < 1e-12);
        assert!((s.sdf(DVec3::new(12.0, 0.0, 0.0)) - 2.0).abs() < 1e-12);
    }

    #[test]
    fn smooth_min_is_below_min_and_equal_far_apart() {
        assert_eq!(smooth_min(1.0, 5.0, 2.0), 1.0);
        assert!(smooth_min(1.0, 1.5, 2.0) < 1.0);
    }

    #[test]
    fn frame_along_round_trips() {
        let f = Frame::along(DVec3::ZERO, DVec3::new(0.0, -10.0, -2.0), DVec3::Z);
        let p = DVec3::new(1.0, 2.0, 3.0);
        assert!((f.to_parent(f.to_local(p)) - p).length() < 1e-12);
        assert!((f.axes.determinant() - 1.0).abs() < 1e-12);
    }
}
