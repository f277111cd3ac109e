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
//! Depth comes with the coverage test: with the source at the origin, the plane of a triangle with normal
//! `n` is `n · x = n · A`, so the ray through pixel (u, v) meets it at camera depth `(n · A) / (n · d)`,
//! whose denominator is linear in (u, v) like the edge functions and whose numerator's sign says whether
//! the triangle faces the source (an entry) or not (an exit). No per-hit plane lookup is needed; the
//! crossings then go through the same pairing as the ray tracers' (`pairing`), so the backends differ
//! only in the last bits of the distances and on rays through edges and vertices, where all of them agree
//! on the path length.
//!
//! Per band, every bounding-box pixel of a triangle is written as a fragment and kept or dropped by its
//! coverage without a branch (a small triangle's box pixels are a coin toss for the branch predictor),
//! and a counting sort gathers each pixel's crossings.

mod edges;
mod summed;

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use self::edges::{Edges, PixelDirs};
use super::pairing::Crossing;
use super::scene::RenderScene;
use crate::geometry::View;

pub(crate) use self::summed::SumScratch;

/// Pixel margin of a triangle's bounding box: covers rounding in the projected corners (the edge
/// functions, not the box, decide coverage).
const BOX_MARGIN_PX: f64 = 1e-2;

/// Vertices closer to the source plane than this (mm, camera depth) are not projected (see
/// [`RasterView::new`]).
const MIN_DEPTH_MM: f64 = 1e-6;

/// A band's hit on a pixel: column, row within the band, and the crossing (`t`: camera-frame depth, mm).
#[derive(Debug, Clone, Copy)]
struct Fragment {
    u: u32,
    row: u32,
    crossing: Crossing,
}

const EMPTY_FRAGMENT: Fragment = Fragment {
    u: 0,
    row: 0,
    crossing: Crossing {
        t: 0.0,
        prim: 0,
        geom: 0,
        entry: false,
    },
};

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
    /// The triangles binned by band, per chunk of one mesh's triangles.
    bins: Vec<Bins>,
}

impl<'a> RasterView<'a> {
    /// Projects every vertex and bins every triangle by the rows its bounding box spans. `None` when a
    /// vertex lies at or behind the source plane (a triangle there has no finite projection; such a view
    /// has to be traced).
    pub(crate) fn new(scene: &'a RenderScene, view: &View, band_rows: usize) -> Option<Self> {
        assert!(
            band_rows.is_power_of_two(),
            "band rows must be a power of two"
        );
        let intr = view.intrinsics;
        let height = intr.height as usize;
        let mut cam = Vec::with_capacity(scene.meshes.len());
        let mut px = Vec::with_capacity(scene.meshes.len());
        for m in &scene.meshes {
            let (c, p): (Vec<DVec3>, Vec<DVec2>) = m
                .mesh
                .vertices
                .par_iter()
                .with_min_len(8192)
                .map(|&p| {
                    let c = view.world_to_camera.apply(p);
                    (c, intr.project_camera(c))
                })
                .unzip();
            if c.iter().any(|p| p.z.is_nan() || p.z <= MIN_DEPTH_MM) {
                return None;
            }
            cam.push(c);
            px.push(p);
        }

        // Chunks of each mesh's triangles, binned in parallel.
        let chunks: Vec<(usize, std::ops::Range<usize>)> = scene
            .meshes
            .iter()
            .enumerate()
            .flat_map(|(g, m)| {
                let n = m.mesh.triangles.len();
                (0..n.div_ceil(BIN_CHUNK))
                    .map(move |k| (g, k * BIN_CHUNK..((k + 1) * BIN_CHUNK).min(n)))
            })
            .collect();
        let bins: Vec<Bins> = chunks
            .into_par_iter()
            .map(|(g, tris)| {
                Bins::new(
                    &scene.meshes[g].mesh.triangles[tris.clone()],
                    &px[g],
                    g,
                    tris.start,
                    (intr.width as usize, height),
                    band_rows,
                )
            })
            .collect();
        Some(RasterView {
            scene,
            intr,
            dirs: PixelDirs::new(&intr),
            cam,
            px,
            band_rows,
            bins,
        })
    }

    pub(crate) fn band_rows(&self) -> usize {
        self.band_rows
    }

    /// Length of the camera-frame direction `K⁻¹ [u, v, 1]ᵀ` of pixel (u, v): the ray's path length per mm
    /// of depth.
    pub(crate) fn path_per_depth(&self, u: f64, v: f64) -> f64 {
        self.dirs.camera_dir(u, v).length()
    }

    /// Calls `visit(mesh, triangle, (u0, u1, v0, v1), edges)` for every triangle binned to band `band`
    /// whose pixel box, clamped to the band, holds a pixel centre and whose plane does not contain the
    /// source: the one walk over a band's triangles that [`Self::band_hits`] and
    /// [`Self::band_line_integral`] share.
    #[inline]
    fn band_triangles(
        &self,
        band: usize,
        mut visit: impl FnMut(usize, u32, (usize, usize, usize, usize), Edges),
    ) {
        let w = self.intr.width as usize;
        let h = self.intr.height as usize;
        let row0 = band * self.band_rows;
        let row1 = (row0 + self.band_rows).min(h) - 1;
        // Pixel centres a triangle of the band may cover.
        let box_lo = DVec2::new(0.0, row0 as f64);
        let box_hi = DVec2::new((w - 1) as f64, row1 as f64);
        for bins in &self.bins {
            let g = bins.mesh as usize;
            let (triangles, px, cam) = (
                &self.scene.meshes[g].mesh.triangles,
                &self.px[g],
                &self.cam[g],
            );
            let band_tris = &bins.tris[bins.start[band] as usize..bins.start[band + 1] as usize];
            for &t in band_tris {
                let tri = triangles[t as usize];
                let [a, b, c] = tri.map(|i| px[i as usize]);
                // The pixel box, clamped to the band (and empty when it holds no pixel centre).
                let lo = (a.min(b).min(c) - BOX_MARGIN_PX).max(box_lo);
                let hi = (a.max(b).max(c) + BOX_MARGIN_PX).min(box_hi);
                let (u0, v0) = (ceil_small(lo.x), ceil_small(lo.y));
                let (u1, v1) = (floor_small(hi.x), floor_small(hi.y));
                if u0 > u1 || v0 > v1 {
                    continue;
                }
                let Some(edges) = Edges::new(tri.map(|i| cam[i as usize]), &self.dirs) else {
                    continue;
                };
                visit(
                    g,
                    t,
                    (u0 as usize, u1 as usize, v0 as usize, v1 as usize),
                    edges,
                );
            }
        }
    }

    /// Calls `visit(u, row in band, crossings)` for every pixel of band `band` (rows `band · band_rows ..`)
    /// whose ray crosses at least one triangle, in row-major order. A crossing's `t` is the camera-frame
    /// depth of the point where the ray crosses the triangle's plane (mm), grouped by mesh (not sorted by
    /// depth). `scratch` is reused between bands.
    pub(crate) fn band_hits(
        &self,
        band: usize,
        scratch: &mut BandScratch,
        mut visit: impl FnMut(usize, usize, &mut [Crossing]),
    ) {
        let h = self.intr.height as usize;
        let row0 = band * self.band_rows;
        let row1 = (row0 + self.band_rows).min(h) - 1;
        let frags = &mut scratch.fragments;
        let len = &mut 0usize;
        let (mut umin, mut umax) = (usize::MAX, 0);
        self.band_triangles(band, |g, t, (u0, u1, v0, v1), edges| {
            // Every bounding-box pixel is written and the length advances by its coverage (no
            // branch: for a small triangle, whether a box pixel is covered is a coin toss).
            let before = *len;
            let need = before + (v1 - v0 + 1) * (u1 - u0 + 1);
            if frags.len() < need {
                frags.resize(need.next_power_of_two(), EMPTY_FRAGMENT);
            }
            for v in v0..v1 + 1 {
                let row = edges.row(v as f64);
                let r = (v - row0) as u32;
                for u in (u0 as u32)..(u1 as u32 + 1) {
                    let uf = f64::from(u);
                    frags[*len] = Fragment {
                        u,
                        row: r,
                        crossing: Crossing {
                            t: row.depth(uf),
                            prim: t,
                            geom: g as u16,
                            entry: edges.entry,
                        },
                    };
                    *len += usize::from(row.covers(uf));
                }
            }
            if *len > before {
                umin = umin.min(u0);
                umax = umax.max(u1);
            }
        });
        let frags = &frags[..*len];
        if frags.is_empty() {
            return;
        }
        // Counting sort of the fragments by pixel over the band's occupied columns.
        let cols = umax - umin + 1;
        let cells = (row1 - row0 + 1) * cols;
        let start = &mut scratch.start;
        start.clear();
        start.resize(cells + 1, 0);
        let cell_of = &mut scratch.cell_of;
        cell_of.clear();
        cell_of.extend(
            frags
                .iter()
                .map(|f| (f.row as usize * cols + f.u as usize - umin) as u32),
        );
        for &c in cell_of.iter() {
            start[c as usize + 1] += 1;
        }
        for i in 0..cells {
            start[i + 1] += start[i];
        }
        let fill = &mut scratch.fill;
        fill.clear();
        fill.extend_from_slice(&start[..cells]);
        let hits = &mut scratch.hits;
        hits.clear();
        hits.resize(frags.len(), frags[0].crossing);
        for (f, &c) in frags.iter().zip(cell_of.iter()) {
            let k = &mut fill[c as usize];
            hits[*k] = f.crossing;
            *k += 1;
        }
        for i in 0..cells {
            let (a, z) = (start[i], start[i + 1]);
            if a < z {
                visit(umin + i % cols, i / cols, &mut hits[a..z]);
            }
        }
    }
}

/// Triangles per binning chunk.
const BIN_CHUNK: usize = 16384;

/// A chunk of one mesh's triangles, binned by the bands of rows their bounding boxes span.
struct Bins {
    mesh: u32,
    /// Triangles (indices into the mesh) of band `b`: `tris[start[b]..start[b + 1]]`.
    start: Vec<u32>,
    tris: Vec<u32>,
}

impl Bins {
    /// Bins `triangles` (the mesh's triangles from index `first`) of mesh `mesh`, whose projected vertices
    /// are `px`, into bands of `band_rows` (a power of two) rows of a `width × height` image.
    fn new(
        triangles: &[[u32; 3]],
        px: &[DVec2],
        mesh: usize,
        first: usize,
        (width, height): (usize, usize),
        band_rows: usize,
    ) -> Self {
        let bands = height.div_ceil(band_rows);
        let (last_col, last_row) = (width as f64 - 1.0, height as f64 - 1.0);
        let shift = band_rows.trailing_zeros();
        // First and last band of each triangle's rows, `None` when its box holds no pixel centre (no
        // pixel row, or no pixel column: most triangles of a fine mesh on a coarse detector).
        let ranges: Vec<Option<(u32, u32)>> = triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| px[i as usize]);
                let lo = (a.min(b).min(c) - BOX_MARGIN_PX).max(DVec2::ZERO);
                let hi = (a.max(b).max(c) + BOX_MARGIN_PX).min(DVec2::new(last_col, last_row));
                // Here `0 ≤ lo` and `hi < size` (`max` and `min` drop a NaN).
                if lo.x > hi.x || lo.y > hi.y || ceil_small(lo.x) > floor_small(hi.x) {
                    return None;
                }
                let (r0, r1) = (ceil_small(lo.y) as usize, hi.y as usize);
                (r0 <= r1).then_some(((r0 >> shift) as u32, (r1 >> shift) as u32))
            })
            .collect();
        let mut start = vec![0u32; bands + 1];
        for &(b0, b1) in ranges.iter().flatten() {
            for b in b0..b1 + 1 {
                start[b as usize + 1] += 1;
            }
        }
        for b in 0..bands {
            start[b + 1] += start[b];
        }
        let mut fill = start.clone();
        let mut tris = vec![0u32; start[bands] as usize];
        for (t, r) in ranges.iter().enumerate() {
            if let Some((b0, b1)) = *r {
                for b in b0..b1 + 1 {
                    let k = &mut fill[b as usize];
                    tris[*k as usize] = (first + t) as u32;
                    *k += 1;
                }
            }
        }
        Bins {
            mesh: mesh as u32,
            start,
            tris,
        }
    }
}

/// Per-thread buffers of [`RasterView::band_hits`].
#[derive(Default)]
pub(crate) struct BandScratch {
    /// Fragments of the band (only a prefix is in use: its length grows as needed and never shrinks).
    fragments: Vec<Fragment>,
    cell_of: Vec<u32>,
    start: Vec<usize>,
    fill: Vec<usize>,
    hits: Vec<Crossing>,
}

/// Bound of the pixel coordinates [`ceil_small`] and [`floor_small`] take: far beyond any detector
/// ([`crate::geometry::MAX_DETECTOR_PX`]), so clamping to it changes no pixel range, and small enough that
/// the rounding arithmetic cannot overflow whatever the projection gave (a huge but finite K, an
/// infinity).
const COORD_CLAMP: f64 = (1u64 << 31) as f64;

/// `ceil(x)` of a coordinate, which the caller has clamped to the image from below (`0 ≤ x`; larger
/// values saturate at 2³¹, a NaN gives 0).
#[inline]
fn ceil_small(x: f64) -> i64 {
    let x = x.min(COORD_CLAMP);
    let i = x as i64;
    i + i64::from((i as f64) < x)
}

/// `floor(x)` of a coordinate, which the caller has clamped to the image from above (`x < 2³¹`; smaller
/// values saturate at −2³¹, a NaN gives 0).
#[inline]
fn floor_small(x: f64) -> i64 {
    x.max(-COORD_CLAMP) as i64
}

#[cfg(test)]
mod tests;
