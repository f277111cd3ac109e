//! The rasterising backend: every ray of a DRR starts at the X-ray source, so which triangles the ray
//! through pixel (u, v) crosses is a 2D question: is the pixel's direction `d = K⁻¹ [u, v, 1]ᵀ` inside the
//! cone the triangle spans from the source? For a triangle with camera-frame corners A, B, C (source at
//! the origin) that is the sign test of the three edge functions `E_AB(d) = (A × B) · d`, `E_BC`, `E_CA`,
//! oriented by the sign of `(A × B) · C` (front- or back-facing). Triangles are binned into bands of rows
//! and each band is rasterised by one worker: there is no acceleration structure to build and no traversal.
//!
//! Watertight by construction: two triangles sharing an edge compute its function from the same two
//! camera-frame vertices, `B × A = −(A × B)` exactly in floating point, and a pixel exactly on the edge
//! (`E = 0`) is given to exactly one of them by a tie rule on the sign of the edge normal (the 2D top-left
//! rule). A pixel through a shared vertex may in rare rounding cases be given to two triangles of its fan
//! (the hits coincide and are clustered) or to none (the ray's crossings do not pair up, and the renderer
//! repairs it like any other).
//!
//! The raster finds *which* triangles a ray crosses; distances, pairing and masks come from the same f64
//! code as the ray tracers (`pairing`), so the backends differ only on rays through edges and vertices,
//! where all of them agree on the path length.

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::scene::RenderScene;
use super::tracer::RawHit;
use crate::geometry::View;
use crate::{Error, Result};

/// Pixel margin of a triangle's bounding box: covers rounding in the projected corners (the edge
/// functions, not the box, decide coverage).
const BOX_MARGIN_PX: f64 = 1e-2;

/// A band's hit on a pixel: column, row within the band, and the triangle.
#[derive(Debug, Clone, Copy)]
struct Fragment {
    u: u32,
    row: u32,
    geom: u32,
    prim: u32,
}

/// One view's projected scene, binned into bands of `band_rows` rows.
pub(crate) struct RasterView<'a> {
    scene: &'a RenderScene,
    intr: crate::geometry::Intrinsics,
    dirs: PixelDirs,
    /// Camera-frame vertices per mesh (source at the origin).
    cam: Vec<Vec<DVec3>>,
    /// Projected vertices per mesh (pixels).
    px: Vec<Vec<DVec2>>,
    band_rows: usize,
    /// Triangles of band `b`: `bin_tris[bin_start[b]..bin_start[b + 1]]`, as (mesh, triangle).
    bin_start: Vec<usize>,
    bin_tris: Vec<(u32, u32)>,
}

impl<'a> RasterView<'a> {
    /// Projects every vertex and bins every triangle by the rows its bounding box spans. Fails when a
    /// vertex lies at or behind the source plane (a triangle there has no finite projection).
    pub(crate) fn new(scene: &'a RenderScene, view: &View, band_rows: usize) -> Result<Self> {
        let intr = view.intrinsics;
        let height = intr.height as usize;
        let bands = height.div_ceil(band_rows);
        let mut cam = Vec::with_capacity(scene.meshes.len());
        let mut px = Vec::with_capacity(scene.meshes.len());
        for m in &scene.meshes {
            let c: Vec<DVec3> = m
                .mesh
                .vertices
                .par_iter()
                .with_min_len(4096)
                .map(|&p| view.world_to_camera.apply(p))
                .collect();
            if let Some(bad) = c.iter().find(|p| p.z.is_nan() || p.z <= 1e-6) {
                return Err(Error::invalid(
                    format!("mesh '{}'", m.mesh.name),
                    format!(
                        "a vertex lies {:.3} mm from the source plane, at or behind the X-ray source; \
                         the raster backend cannot project it (use --backend embree)",
                        bad.z
                    ),
                ));
            }
            px.push(
                c.par_iter()
                    .with_min_len(4096)
                    .map(|&p| intr.project_camera(p))
                    .collect::<Vec<_>>(),
            );
            cam.push(c);
        }

        // Band range of every triangle, then a counting sort into bins.
        let row_range = |lo: f64, hi: f64| -> Option<(usize, usize)> {
            let r0 = (lo - BOX_MARGIN_PX).ceil().max(0.0);
            let r1 = (hi + BOX_MARGIN_PX).floor().min(height as f64 - 1.0);
            (r0 <= r1).then(|| (r0 as usize / band_rows, r1 as usize / band_rows))
        };
        let ranges: Vec<Vec<Option<(usize, usize)>>> = scene
            .meshes
            .iter()
            .zip(&px)
            .map(|(m, p)| {
                m.mesh
                    .triangles
                    .par_iter()
                    .with_min_len(4096)
                    .map(|t| {
                        let [a, b, c] = t.map(|i| p[i as usize].y);
                        row_range(a.min(b).min(c), a.max(b).max(c))
                    })
                    .collect()
            })
            .collect();
        let mut bin_start = vec![0usize; bands + 1];
        for r in ranges.iter().flatten().flatten() {
            for b in r.0..r.1 + 1 {
                bin_start[b + 1] += 1;
            }
        }
        for b in 0..bands {
            bin_start[b + 1] += bin_start[b];
        }
        let mut fill = bin_start.clone();
        let mut bin_tris = vec![(0u32, 0u32); bin_start[bands]];
        for (g, mesh_ranges) in ranges.iter().enumerate() {
            for (t, r) in mesh_ranges.iter().enumerate() {
                if let Some((b0, b1)) = *r {
                    for b in b0..b1 + 1 {
                        bin_tris[fill[b]] = (g as u32, t as u32);
                        fill[b] += 1;
                    }
                }
            }
        }
        Ok(RasterView {
            scene,
            intr,
            dirs: PixelDirs::new(&intr),
            cam,
            px,
            band_rows,
            bin_start,
            bin_tris,
        })
    }

    pub(crate) fn band_rows(&self) -> usize {
        self.band_rows
    }

    /// Calls `visit(u, row in band, hits)` for every pixel of band `band` (rows `band · band_rows ..`)
    /// whose ray crosses at least one triangle, in row-major order. `scratch` is reused between bands.
    pub(crate) fn band_hits(
        &self,
        band: usize,
        scratch: &mut BandScratch,
        mut visit: impl FnMut(usize, usize, &[RawHit]),
    ) {
        let w = self.intr.width as usize;
        let h = self.intr.height as usize;
        let row0 = band * self.band_rows;
        let row1 = (row0 + self.band_rows).min(h) - 1;
        let frags = &mut scratch.fragments;
        frags.clear();
        let (mut umin, mut umax) = (usize::MAX, 0);
        for &(g, t) in &self.bin_tris[self.bin_start[band]..self.bin_start[band + 1]] {
            let tri = self.scene.meshes[g as usize].mesh.triangles[t as usize];
            let [a, b, c] = tri.map(|i| self.px[g as usize][i as usize]);
            let lo = a.min(b).min(c) - BOX_MARGIN_PX;
            let hi = a.max(b).max(c) + BOX_MARGIN_PX;
            let (Some(u1), Some(v1)) = (floor_index(hi.x, w - 1), floor_index(hi.y, row1)) else {
                continue;
            };
            let (u0, v0) = (ceil_index(lo.x), ceil_index(lo.y).max(row0));
            if u0 > u1 || v0 > v1 {
                continue;
            }
            let Some(edges) = Edges::new(tri.map(|i| self.cam[g as usize][i as usize]), &self.dirs)
            else {
                continue;
            };
            let before = frags.len();
            for v in v0..v1 + 1 {
                let row = edges.row(v as f64);
                let r = (v - row0) as u32;
                for u in (u0 as u32)..(u1 as u32 + 1) {
                    if row.covers(f64::from(u)) {
                        frags.push(Fragment {
                            u,
                            row: r,
                            geom: g,
                            prim: t,
                        });
                    }
                }
            }
            if frags.len() > before {
                umin = umin.min(u0);
                umax = umax.max(u1);
            }
        }
        if frags.is_empty() {
            return;
        }
        // Counting sort of the fragments by pixel over the band's occupied columns.
        let cols = umax - umin + 1;
        let cells = (row1 - row0 + 1) * cols;
        let cell = |f: &Fragment| f.row as usize * cols + f.u as usize - umin;
        let start = &mut scratch.start;
        start.clear();
        start.resize(cells + 1, 0);
        for f in frags.iter() {
            start[cell(f) + 1] += 1;
        }
        for i in 0..cells {
            start[i + 1] += start[i];
        }
        let fill = &mut scratch.fill;
        fill.clear();
        fill.extend_from_slice(&start[..cells]);
        let hits = &mut scratch.hits;
        hits.clear();
        hits.resize(
            frags.len(),
            RawHit {
                t: 0.0,
                geom: 0,
                prim: 0,
            },
        );
        for f in frags.iter() {
            let k = &mut fill[cell(f)];
            hits[*k] = RawHit {
                t: 0.0,
                geom: f.geom,
                prim: f.prim,
            };
            *k += 1;
        }
        for i in 0..cells {
            let (a, z) = (start[i], start[i + 1]);
            if a < z {
                visit(umin + i % cols, i / cols, &hits[a..z]);
            }
        }
    }
}

/// Per-thread buffers of [`RasterView::band_hits`].
#[derive(Default)]
pub(crate) struct BandScratch {
    fragments: Vec<Fragment>,
    start: Vec<usize>,
    fill: Vec<usize>,
    hits: Vec<RawHit>,
}

/// `ceil(x)` clamped below at 0, as an index.
#[inline]
fn ceil_index(x: f64) -> usize {
    let x = x.max(0.0);
    let i = x as usize;
    if (i as f64) < x { i + 1 } else { i }
}

/// `floor(x)` clamped above at `max`, as an index; `None` when `x < 0` (nothing to cover).
#[inline]
fn floor_index(x: f64, max: usize) -> Option<usize> {
    (x >= 0.0).then(|| (x as usize).min(max))
}

/// The constants that turn a camera-frame edge normal `n` into its pixel-space edge function
/// `E(u, v) = n · K⁻¹ [u, v, 1]ᵀ = a·u + (b·v + c)`. The coefficients are sums of products of `n`'s
/// components, so the opposite normal of a neighbour's shared edge gets exactly the opposite coefficients
/// and, evaluated in the same order, exactly the opposite value.
#[derive(Debug, Clone, Copy)]
struct PixelDirs {
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
    fn new(k: &crate::geometry::Intrinsics) -> Self {
        let (inv_fx, inv_fy) = (1.0 / k.fx, 1.0 / k.fy);
        PixelDirs {
            inv_fx,
            inv_fy,
            k_skew: k.skew * inv_fx * inv_fy,
            k_x: (k.cx - k.skew * k.cy * inv_fy) * inv_fx,
            k_y: k.cy * inv_fy,
        }
    }

    /// `[a, b, c]` of the edge function of normal `n`.
    #[inline]
    fn coefficients(&self, n: DVec3) -> [f64; 3] {
        [
            n.x * self.inv_fx,
            n.y * self.inv_fy - n.x * self.k_skew,
            n.z - n.x * self.k_x - n.y * self.k_y,
        ]
    }
}

/// A triangle's three edge functions in pixel space, oriented so that the inside is positive.
struct Edges {
    e: [[f64; 3]; 3],
}

impl Edges {
    /// From the camera-frame corners (source at the origin). `None` for a triangle whose plane contains
    /// the source (seen edge-on; rays slide along it).
    #[inline]
    fn new([a, b, c]: [DVec3; 3], dirs: &PixelDirs) -> Option<Self> {
        let (ab, bc, ca) = (a.cross(b), b.cross(c), c.cross(a));
        let det = ab.dot(c);
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        // Negation is exact, so orienting keeps neighbours' edge functions exact opposites.
        let n = if det > 0.0 {
            [ab, bc, ca]
        } else {
            [-ab, -bc, -ca]
        };
        Some(Edges {
            e: n.map(|n| dirs.coefficients(n)),
        })
    }

    /// The edge functions along pixel row `v`.
    #[inline]
    fn row(&self, v: f64) -> RowEdges {
        RowEdges {
            a: self.e.map(|e| e[0]),
            r: self.e.map(|e| e[1] * v + e[2]),
            e: self.e,
        }
    }
}

/// Edge functions restricted to one row: `E_i(u) = a_i·u + r_i`.
struct RowEdges {
    a: [f64; 3],
    r: [f64; 3],
    e: [[f64; 3]; 3],
}

impl RowEdges {
    /// Whether the ray through pixel centre `(u, v)` crosses the triangle.
    #[inline]
    fn covers(&self, u: f64) -> bool {
        let v = [
            self.a[0] * u + self.r[0],
            self.a[1] * u + self.r[1],
            self.a[2] * u + self.r[2],
        ];
        let inside = (v[0] > 0.0) & (v[1] > 0.0) & (v[2] > 0.0);
        let outside = (v[0] < 0.0) | (v[1] < 0.0) | (v[2] < 0.0);
        if inside | outside {
            return inside;
        }
        // On an edge (or NaN, which covers nothing).
        (0..3).all(|i| v[i] > 0.0 || (v[i] == 0.0 && owns_edge(self.e[i])))
    }
}

/// Tie rule for a pixel exactly on an edge: of the two opposite orientations of a non-degenerate edge
/// normal, exactly one owns the edge.
#[inline]
fn owns_edge([a, b, c]: [f64; 3]) -> bool {
    a > 0.0 || (a == 0.0 && (b > 0.0 || (b == 0.0 && c > 0.0)))
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
        let fwd = Edges::new(tri, &dirs).expect("edges");
        let rev = Edges::new([tri[0], tri[2], tri[1]], &dirs).expect("reversed");
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
            .map(|i| Edges::new([centre, ring[i], ring[(i + 1) % 7]], &dirs).expect("fan"))
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
        let left = Edges::new([a, b, DVec3::new(-10.0, 0.0, 1000.0)], &dirs).expect("left");
        let right = Edges::new([b, a, DVec3::new(10.0, 0.0, 1000.0)], &dirs).expect("right");
        for v in (k.cy as i64 - 5)..=(k.cy as i64 + 5) {
            let n = [&left, &right]
                .iter()
                .filter(|e| e.row(v as f64).covers(k.cx))
                .count();
            assert_eq!(n, 1, "pixel (cx, {v})");
        }
    }
}
