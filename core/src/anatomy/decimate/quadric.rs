//! Garland–Heckbert error quadrics (Garland & Heckbert 1997, "Surface simplification using quadric
//! error metrics"): the squared distance of a point `p` to a plane `n·p + d = 0` is
//! `pᵀ(nnᵀ)p + 2d·nᵀp + d²`, so a sum of planes is one symmetric 4×4 matrix `Q = Σ w·[n d]ᵀ[n d]`
//! and the error of `p` is `[p 1] Q [p 1]ᵀ`.

use glam::{DMat3, DVec3};

/// An area-weighted sum of plane quadrics, with the total weight (so `error / weight` is the mean
/// squared distance to the planes, mm²).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Quadric {
    /// Upper triangle of `A = Σ w nnᵀ`: xx, xy, xz, yy, yz, zz.
    a: [f64; 6],
    /// `b = Σ w d n`.
    b: DVec3,
    /// `c = Σ w d²`.
    c: f64,
    /// `Σ w`.
    pub weight: f64,
}

impl Quadric {
    /// The quadric of the plane through `p` with unit normal `n`, weighted by `w`.
    pub fn plane(n: DVec3, p: DVec3, w: f64) -> Quadric {
        let d = -n.dot(p);
        Quadric {
            a: [
                w * n.x * n.x,
                w * n.x * n.y,
                w * n.x * n.z,
                w * n.y * n.y,
                w * n.y * n.z,
                w * n.z * n.z,
            ],
            b: w * d * n,
            c: w * d * d,
            weight: w,
        }
    }

    fn matrix(&self) -> DMat3 {
        let a = &self.a;
        DMat3::from_cols(
            DVec3::new(a[0], a[1], a[2]),
            DVec3::new(a[1], a[3], a[4]),
            DVec3::new(a[2], a[4], a[5]),
        )
    }

    /// Weighted squared-distance error `pᵀAp + 2bᵀp + c` (clamped at 0 against round-off).
    pub fn error(&self, p: DVec3) -> f64 {
        (p.dot(self.matrix() * p) + 2.0 * self.b.dot(p) + self.c).max(0.0)
    }

    /// The minimiser `p = −A⁻¹b` when `A` is well conditioned (relative determinant above 1e-6),
    /// else `None` (flat or cylindrical neighbourhoods, where the minimiser is a plane or a line).
    pub fn minimiser(&self) -> Option<DVec3> {
        let m = self.matrix();
        let scale = (self.a[0] + self.a[3] + self.a[5]) / 3.0;
        if scale <= 0.0 {
            return None;
        }
        let det = m.determinant();
        if det.abs() <= 1e-6 * scale * scale * scale {
            return None;
        }
        let p = -(m.inverse() * self.b);
        p.is_finite().then_some(p)
    }
}

impl std::ops::Add for Quadric {
    type Output = Quadric;
    fn add(self, o: Quadric) -> Quadric {
        let mut a = self.a;
        for (x, y) in a.iter_mut().zip(o.a) {
            *x += y;
        }
        Quadric {
            a,
            b: self.b + o.b,
            c: self.c + o.c,
            weight: self.weight + o.weight,
        }
    }
}

impl std::ops::AddAssign for Quadric {
    fn add_assign(&mut self, o: Quadric) {
        *self = *self + o;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn error_is_squared_plane_distance_and_corner_is_minimiser() {
        let q = Quadric::plane(DVec3::X, DVec3::new(1.0, 0.0, 0.0), 1.0)
            + Quadric::plane(DVec3::Y, DVec3::new(0.0, 2.0, 0.0), 1.0)
            + Quadric::plane(DVec3::Z, DVec3::new(0.0, 0.0, 3.0), 1.0);
        let p = DVec3::new(4.0, -1.0, 3.5);
        assert!((q.error(p) - (9.0 + 9.0 + 0.25)).abs() < 1e-12);
        let m = q.minimiser().unwrap();
        assert!((m - DVec3::new(1.0, 2.0, 3.0)).length() < 1e-12);
        let flat = Quadric::plane(DVec3::Z, DVec3::ZERO, 2.0);
        assert!(flat.minimiser().is_none());
        assert_eq!(flat.weight, 2.0);
    }
}
