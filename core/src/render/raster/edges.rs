//! The raster's per-triangle math: edge functions in pixel space, the tie rule that gives a pixel exactly
//! on a shared edge to one triangle, and the plane depth along a pixel's ray (see the watertightness
//! argument in [`super`]).
//!
//! A triangle is set up from its corners' *centred homogeneous pixel coordinates* `H = K₀ X` (camera
//! frame `X`, `K₀` the intrinsics with the principal point at 0, [`PixelDirs::homogeneous`], computed once
//! per vertex), against pixel positions relative to the principal point, `q = [u − cx, v − cy, 1]ᵀ`, so
//! that `K⁻¹ [u, v, 1]ᵀ = K₀⁻¹ q`. For camera-frame corners A, B the edge function `(A × B) · K₀⁻¹ q` is
//! `(H_A × H_B) · q / det K₀` (`K₀ A × K₀ B = det K₀ · K₀⁻ᵀ (A × B)`): the pixel-space coefficients are one
//! cross product of two vertices' `H`, with no per-triangle transform by `K⁻¹`, and `det K₀ = fx fy > 0`
//! changes no sign. The plane and its depth scale alike: `((H_B − H_A) × (H_C − H_A)) · q =
//! det K₀ · n · K₀⁻¹ q` and `(H_A × H_B) · H_C = det K₀ · (A × B) · C`, whose ratio is the camera depth
//! `(n · A) / (n · d)`. Centring keeps a vertex on the optical axis exact: its `H` is `(0, 0, z)`, and
//! the edge functions of its fan vanish exactly at the principal point's pixel, where the tie rule then
//! decides, as it does for any pixel exactly on an edge.

use glam::DVec3;

/// `K` and `K⁻¹` as the raster uses them: a vertex's centred homogeneous pixel coordinates `K₀ X` and a
/// pixel's camera-frame direction `K⁻¹ [u, v, 1]ᵀ`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PixelDirs {
    fx: f64,
    fy: f64,
    skew: f64,
    cx: f64,
    cy: f64,
    inv_fx: f64,
    inv_fy: f64,
    /// `skew / (fx fy)`.
    k_skew: f64,
    /// `(cx − skew·cy/fy) / fx`.
    k_x: f64,
    /// `cy / fy`.
    k_y: f64,
}

impl PixelDirs {
    pub(crate) fn new(k: &crate::geometry::Intrinsics) -> Self {
        let (inv_fx, inv_fy) = (1.0 / k.fx, 1.0 / k.fy);
        PixelDirs {
            fx: k.fx,
            fy: k.fy,
            skew: k.skew,
            cx: k.cx,
            cy: k.cy,
            inv_fx,
            inv_fy,
            k_skew: k.skew * inv_fx * inv_fy,
            k_x: (k.cx - k.skew * k.cy * inv_fy) * inv_fx,
            k_y: k.cy * inv_fy,
        }
    }

    /// The centred homogeneous pixel coordinates `K₀ X` of camera-frame point `X` (`K₀`: K with the
    /// principal point at 0; its z is `X`'s depth).
    #[inline]
    pub(crate) fn homogeneous(&self, x: DVec3) -> DVec3 {
        DVec3::new(self.fx * x.x + self.skew * x.y, self.fy * x.y, x.z)
    }

    /// The camera-frame direction `K⁻¹ [u, v, 1]ᵀ` of pixel (u, v) (unit depth).
    #[inline]
    pub(crate) fn camera_dir(&self, u: f64, v: f64) -> DVec3 {
        DVec3::new(
            self.inv_fx * u - self.k_skew * v - self.k_x,
            self.inv_fy * v - self.k_y,
            1.0,
        )
    }

    /// The rows of `K⁻¹` that give [`Self::camera_dir`]: its x is `x[0]·u + x[1]·v + x[2]`, its y
    /// `y[0]·u + y[1]·v + y[2]` (the GPU's finishing pass computes the ray's length from them).
    #[cfg(feature = "gpu")]
    pub(crate) fn rows(&self) -> ([f64; 3], [f64; 3]) {
        (
            [self.inv_fx, -self.k_skew, -self.k_x],
            [0.0, self.inv_fy, -self.k_y],
        )
    }
}

/// A triangle's three edge functions in pixel space, `E(u, v) = a·(u − cx) + (b·(v − cy) + c)`, oriented
/// so that the inside is positive, and its depth along the pixel rays. A shared edge's coefficients are one cross
/// product of its two vertices' `H`, taken in the opposite order by the neighbour: exactly the opposite
/// numbers, which, evaluated in the same order, give exactly the opposite value.
pub(crate) struct Edges {
    /// Coefficients of `E(q) = a·(u − cx) + b·(v − cy) + c` (see the module docs).
    e: [[f64; 3]; 3],
    /// The principal point `(cx, cy)`.
    centre: [f64; 2],
    /// Per edge, [`f64::MIN_POSITIVE`] when the triangle owns pixels exactly on it (the tie rule,
    /// [`owns_edge`]), else 0 (see [`RowEdges::covers`]).
    bias: [f64; 3],
    /// `det K₀ · n · K⁻¹ [u, v, 1]ᵀ = p[0]·(u − cx) + p[1]·(v − cy) + p[2]` for the plane normal `n`, so
    /// a pixel's ray meets the plane at depth `det / (p · [u − cx, v − cy, 1])`.
    p: [f64; 3],
    /// `det K₀ · n · A`, the plane's offset from the source: negative when the triangle faces the source.
    det: f64,
    /// The corners' depth range (the plane depth of a covered pixel lies in it).
    z_range: (f64, f64),
    /// The triangle faces the source (rays enter the mesh through it).
    pub entry: bool,
}

impl Edges {
    /// From the corners' centred homogeneous pixel coordinates `H = K₀ X` ([`PixelDirs::homogeneous`],
    /// source at the origin). `None` for a triangle whose plane contains the source (seen edge-on; rays
    /// slide along it).
    #[inline]
    pub(crate) fn new([a, b, c]: [DVec3; 3], dirs: &PixelDirs) -> Option<Self> {
        let (ab, bc, ca) = (a.cross(b), b.cross(c), c.cross(a));
        let det = ab.dot(c);
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        // Negation is exact, so orienting keeps neighbours' edge functions exact opposites (a product by
        // ±1, without a branch: front- and back-facing triangles alternate unpredictably).
        let sign = if det > 0.0 { 1.0 } else { -1.0 };
        let e = [ab, bc, ca].map(|n| (n * sign).to_array());
        Some(Edges {
            e,
            centre: [dirs.cx, dirs.cy],
            bias: e.map(|e| if owns_edge(e) { f64::MIN_POSITIVE } else { 0.0 }),
            p: (b - a).cross(c - a).to_array(),
            det,
            z_range: (a.z.min(b.z).min(c.z), a.z.max(b.z).max(c.z)),
            entry: det < 0.0,
        })
    }

    /// The edge functions along pixel row `v`.
    #[inline]
    pub(crate) fn row(&self, v: f64) -> RowEdges {
        let y = v - self.centre[1];
        RowEdges {
            cx: self.centre[0],
            a: self.e.map(|e| e[0]),
            r: self.e.map(|e| e[1] * y + e[2]),
            bias: self.bias,
            pa: self.p[0],
            pr: self.p[1] * y + self.p[2],
            det: self.det,
            z_range: self.z_range,
        }
    }
}

/// Edge functions restricted to one row: `E_i(u) = a_i·(u − cx) + r_i`; depth `det / (pa·(u − cx) + pr)`.
pub(crate) struct RowEdges {
    cx: f64,
    a: [f64; 3],
    r: [f64; 3],
    /// [`f64::MIN_POSITIVE`] for an edge the triangle owns, else 0 (see [`Self::covers`]).
    bias: [f64; 3],
    pa: f64,
    pr: f64,
    det: f64,
    z_range: (f64, f64),
}

impl RowEdges {
    /// Depth (camera z, mm) at which the ray through covered pixel `(u, v)` crosses the triangle, kept
    /// within the corners' depths (a ray nearly in the plane meets it at an ill-conditioned depth).
    #[inline]
    pub(crate) fn depth(&self, u: f64) -> f64 {
        let z = self.det / (self.pa * (u - self.cx) + self.pr);
        // `max` first: a NaN becomes the near end.
        z.max(self.z_range.0).min(self.z_range.1)
    }

    /// Whether the ray through pixel centre `(u, v)` crosses the triangle: inside every edge, or exactly
    /// on an edge the triangle owns (a NaN covers nothing), without a branch. `E ≥ 0` is tested as
    /// `E + bias > 0` with the smallest normal number (2.2e-308) as the bias, which is exact for every `E`
    /// that is not subnormal: `E = a·(u − cx) + r` is rounded from terms of the size of the coefficients
    /// (products of two vertices' `H`, far above 1e-100 for any scene in mm), so it is exactly 0 or many
    /// orders of magnitude above the bias.
    #[inline]
    pub(crate) fn covers(&self, u: f64) -> bool {
        let x = u - self.cx;
        let side = |i: usize| (self.a[i] * x + self.r[i]) + self.bias[i] > 0.0;
        side(0) & side(1) & side(2)
    }
}

/// Tie rule for a pixel exactly on an edge: of the two opposite orientations of a non-degenerate edge
/// normal, exactly one owns the edge.
#[inline]
fn owns_edge([a, b, c]: [f64; 3]) -> bool {
    // Non-short-circuit `|` and `&`: no branch on signs that are a coin toss.
    (a > 0.0) | ((a == 0.0) & ((b > 0.0) | ((b == 0.0) & (c > 0.0))))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Intrinsics;

    fn intrinsics() -> Intrinsics {
        Intrinsics {
            fx: 1800.0,
            fy: 1750.0,
            skew: 3.5,
            cx: 500.0,
            cy: 520.0,
            width: 1000,
            height: 1000,
        }
    }

    /// Whether the ray through pixel (u, v) crosses the triangle, by intersecting it with the plane and
    /// testing barycentric coordinates (independent of the edge functions).
    fn barycentric_inside(k: &Intrinsics, tri: [DVec3; 3], u: f64, v: f64) -> bool {
        let d = k.back_project(u, v);
        let n = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
        let p = d * (n.dot(tri[0]) / n.dot(d));
        let area = |x: DVec3, y: DVec3, z: DVec3| (y - x).cross(z - x).dot(n);
        [
            area(p, tri[1], tri[2]),
            area(tri[0], p, tri[2]),
            area(tri[0], tri[1], p),
        ]
        .iter()
        .all(|&x| x > 0.0)
    }

    #[test]
    fn edge_functions_match_barycentric_inside() {
        let k = intrinsics();
        let dirs = PixelDirs::new(&k);
        let tri = [
            DVec3::new(-10.0, -12.0, 1000.0),
            DVec3::new(20.0, -5.0, 1100.0),
            DVec3::new(0.0, 15.0, 1050.0),
        ];
        let fwd = Edges::new(tri.map(|x| dirs.homogeneous(x)), &dirs).expect("edges");
        let rev = Edges::new([tri[0], tri[2], tri[1]].map(|x| dirs.homogeneous(x)), &dirs)
            .expect("reversed");
        let mut inside = 0;
        for v in 480..560 {
            for u in 470..540 {
                let truth = barycentric_inside(&k, tri, u as f64, v as f64);
                assert_eq!(fwd.row(v as f64).covers(u as f64), truth, "u {u} v {v}");
                assert_eq!(
                    rev.row(v as f64).covers(u as f64),
                    truth,
                    "reversed, u {u} v {v}"
                );
                inside += usize::from(truth);
            }
        }
        assert!(inside > 200, "the grid must sample the inside ({inside})");
    }

    #[test]
    fn shared_edges_are_watertight() {
        // A fan of triangles around a centre vertex, all pixels near it: every pixel inside the fan's
        // outline is covered exactly once, including pixels on the shared edges.
        let k = intrinsics();
        let dirs = PixelDirs::new(&k);
        let centre = DVec3::new(0.0, 0.0, 1000.0);
        let ring: Vec<DVec3> = (0..7)
            .map(|i| {
                let a = i as f64 / 7.0 * std::f64::consts::TAU + 0.1;
                DVec3::new(8.0 * a.cos(), 8.0 * a.sin(), 1000.0 + 20.0 * a.sin())
            })
            .collect();
        let fan: Vec<Edges> = (0..7)
            .map(|i| {
                Edges::new(
                    [centre, ring[i], ring[(i + 1) % 7]].map(|x| dirs.homogeneous(x)),
                    &dirs,
                )
                .expect("fan")
            })
            .collect();
        let (cu, cv) = (k.cx.round(), k.cy.round());
        let mut checked = 0;
        for v in (cv as i64 - 10)..=(cv as i64 + 10) {
            for u in (cu as i64 - 10)..=(cu as i64 + 10) {
                let covered = fan
                    .iter()
                    .filter(|e| e.row(v as f64).covers(u as f64))
                    .count();
                assert!(covered <= 1, "pixel ({u}, {v}) covered {covered} times");
                checked += covered;
            }
        }
        assert!(
            checked > 200,
            "the fan must cover the sampled pixels ({checked})"
        );
        // Opposite normals own an edge exactly once.
        for e in [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 5.0, -3.0]] {
            assert!(owns_edge(e) != owns_edge(e.map(|x| -x)));
        }
    }

    #[test]
    fn pixel_on_a_shared_edge_belongs_to_one_triangle() {
        // Two triangles sharing an edge whose projection passes exactly through pixel centres: the edge
        // runs along the optical axis's column (u = cx) when both ends have x = 0.
        let k = Intrinsics {
            skew: 0.0,
            ..intrinsics()
        };
        let dirs = PixelDirs::new(&k);
        let (a, b) = (
            DVec3::new(0.0, -10.0, 1000.0),
            DVec3::new(0.0, 10.0, 1000.0),
        );
        let left = Edges::new(
            [a, b, DVec3::new(-10.0, 0.0, 1000.0)].map(|x| dirs.homogeneous(x)),
            &dirs,
        )
        .expect("left");
        let right = Edges::new(
            [b, a, DVec3::new(10.0, 0.0, 1000.0)].map(|x| dirs.homogeneous(x)),
            &dirs,
        )
        .expect("right");
        for v in (k.cy as i64 - 5)..=(k.cy as i64 + 5) {
            let n = [&left, &right]
                .iter()
                .filter(|e| e.row(v as f64).covers(k.cx))
                .count();
            assert_eq!(n, 1, "pixel (cx, {v})");
        }
    }
}
