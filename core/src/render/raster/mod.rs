//! The rasterising backend: every ray of a DRR starts at the X-ray source, so which triangles the ray
//! through pixel (u, v) crosses is a 2D question: is the pixel's direction `d = K⁻¹ [u, v, 1]ᵀ` inside the
//! cone the triangle spans from the source? For a triangle with camera-frame corners A, B, C (source at
//! the origin) that is the sign test of the three edge functions `E_AB(d) = (A × B) · d`, `E_BC`, `E_CA`,
//! oriented by the sign of `(A × B) · C` (front- or back-facing). Triangles are binned into bands of rows
//! and each band is rasterised by one worker: there is no acceleration structure to build and no traversal.
//!
//! The functions are evaluated in pixel space from each vertex's (centred) homogeneous pixel coordinates
//! `K₀ A`, computed once per vertex (see [`edges`]). Watertight by construction: two triangles sharing an
//! edge compute its function from the same two vertices, `B × A = −(A × B)` exactly in floating point,
//! and a pixel exactly on the edge (`E = 0`) is given to exactly one of them by a tie rule on the sign of
//! the edge normal (the 2D top-left rule). A pixel through a shared vertex may in rare rounding cases be given to two triangles of its fan
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

use glam::{DVec2, DVec3, Vec4};
use rayon::prelude::*;

pub(crate) use self::edges::{Edges, PixelDirs};
use super::pairing::Crossing;
use super::scene::RenderScene;
use crate::geometry::View;

pub(crate) use self::summed::SumScratch;

/// Pixel margin of a triangle's bounding box: covers rounding in the projected corners (the edge
/// functions, not the box, decide coverage).
const BOX_MARGIN_PX: f64 = 1e-2;

/// Vertices closer to the source plane than this (mm, camera depth) are not projected (see
/// [`RasterView::new`]).
pub(crate) const MIN_DEPTH_MM: f64 = 1e-6;

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
    /// Centred homogeneous pixel coordinates `K₀ X` of the camera-frame vertices per mesh (source at the
    /// origin; see [`Edges::new`]).
    hom: Vec<Vec<DVec3>>,
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
        // Pixel boxes are kept in 16 bits (validated detectors have at most 8192 px a side).
        if intr.width > 1 << 16 || intr.height > 1 << 16 {
            return None;
        }
        let height = intr.height as usize;
        let dirs = PixelDirs::new(&intr);
        let mut hom = Vec::with_capacity(scene.meshes.len());
        let mut px = Vec::with_capacity(scene.meshes.len());
        for m in &scene.meshes {
            let (mut c, mut p) = (Vec::new(), Vec::new());
            m.mesh
                .vertices
                .par_iter()
                .with_min_len(8192)
                .map(|&p| {
                    let c = view.world_to_camera.apply(p);
                    (dirs.homogeneous(c), VertexBox::new(intr.project_camera(c)))
                })
                .unzip_into_vecs(&mut c, &mut p);
            // A homogeneous z is the camera depth.
            if c.iter().any(|p| p.z.is_nan() || p.z <= MIN_DEPTH_MM) {
                return None;
            }
            hom.push(c);
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
            dirs,
            hom,
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
        let h = self.intr.height as usize;
        let row0 = band * self.band_rows;
        let row1 = (row0 + self.band_rows).min(h) - 1;
        for bins in &self.bins {
            let g = bins.mesh as usize;
            let (triangles, hom) = (&self.scene.meshes[g].mesh.triangles, &self.hom[g]);
            let band_tris = &bins.tris[bins.start[band] as usize..bins.start[band + 1] as usize];
            for bt in band_tris {
                // The triangle's pixel box, clamped to the band (its rows meet the band: it is binned
                // here).
                let (v0, v1) = (usize::from(bt.v0).max(row0), usize::from(bt.v1).min(row1));
                let tri = triangles[bt.t as usize];
                let Some(edges) = Edges::new(tri.map(|i| hom[i as usize]), &self.dirs) else {
                    continue;
                };
                visit(
                    g,
                    bt.t,
                    (usize::from(bt.u0), usize::from(bt.u1), v0, v1),
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

/// A binned triangle: its index in the mesh and its pixel box (the pixel centres its bounding box holds,
/// within the image: columns `u0..=u1`, rows `v0..=v1`).
#[derive(Debug, Clone, Copy, Default)]
struct BinnedTriangle {
    t: u32,
    u0: u16,
    u1: u16,
    v0: u16,
    v1: u16,
}

/// A chunk of one mesh's triangles, binned by the bands of rows their bounding boxes span.
struct Bins {
    mesh: u32,
    /// Triangles of band `b`: `tris[start[b]..start[b + 1]]`.
    start: Vec<u32>,
    tris: Vec<BinnedTriangle>,
}

impl Bins {
    /// Bins `triangles` (the mesh's triangles from index `first`) of mesh `mesh`, whose projected vertices
    /// are `px`, into bands of `band_rows` (a power of two) rows of a `width × height` image (each side at
    /// most 65 536 px). A triangle is binned with its pixel box, computed once here; one whose box holds no
    /// pixel centre (most triangles of a fine mesh on a coarse detector) is dropped.
    fn new(
        triangles: &[[u32; 3]],
        px: &[VertexBox],
        mesh: usize,
        first: usize,
        (width, height): (usize, usize),
        band_rows: usize,
    ) -> Self {
        let bands = height.div_ceil(band_rows);
        // `(0, −last column, 0, −last row)`: the image as a box in `VertexBox`'s form.
        let image = Vec4::new(0.0, 1.0 - width as f32, 0.0, 1.0 - height as f32);
        let shift = band_rows.trailing_zeros();
        // Every triangle is written and the length advances when its box holds a pixel centre, without a
        // branch (for a fine mesh on a coarse detector, whether it does is a coin toss per triangle).
        let mut boxed = vec![BinnedTriangle::default(); triangles.len()];
        let mut kept = 0;
        for (k, t) in triangles.iter().enumerate() {
            let [a, b, c] = t.map(|i| px[i as usize].0);
            // The box of the corners' boxes, within the image: `(u0, −u1, v0, −v1)`.
            let m = a.min(b).min(c).max(image);
            // A box that holds no pixel centre converts to meaningless (saturated) numbers; it is
            // overwritten by the next triangle, or cut off after the loop.
            boxed[kept] = BinnedTriangle {
                t: (first + k) as u32,
                u0: m.x as u16,
                u1: -m.y as u16,
                v0: m.z as u16,
                v1: -m.w as u16,
            };
            // `u0 ≤ u1` and `v0 ≤ v1` (whole numbers below 2²³: the sums are exact).
            kept += usize::from((m.x + m.y <= 0.0) & (m.z + m.w <= 0.0));
        }
        boxed.truncate(kept);
        let mut start = vec![0u32; bands + 1];
        let bands_of =
            |bt: &BinnedTriangle| (usize::from(bt.v0) >> shift, usize::from(bt.v1) >> shift);
        for bt in &boxed {
            let (b0, b1) = bands_of(bt);
            for n in &mut start[b0 + 1..b1 + 2] {
                *n += 1;
            }
        }
        for b in 0..bands {
            start[b + 1] += start[b];
        }
        let mut fill = start.clone();
        let mut tris = vec![BinnedTriangle::default(); start[bands] as usize];
        for bt in &boxed {
            let (b0, b1) = bands_of(bt);
            for k in &mut fill[b0..b1 + 1] {
                tris[*k as usize] = *bt;
                *k += 1;
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

/// Bound of the pixel coordinates a [`VertexBox`] is rounded from: far beyond any detector
/// ([`crate::geometry::MAX_DETECTOR_PX`]), so clamping to it changes no pixel range, and small enough that
/// every whole number up to it is exact in an `f32`, whatever the projection gave (a huge but finite K).
const COORD_CLAMP: f64 = (1u64 << 22) as f64;

/// A projected vertex's pixel box: the columns `u0..=u1` and rows `v0..=v1` whose centres lie within
/// [`BOX_MARGIN_PX`] of it (the margin covers rounding in the projection; the edge functions, not the box,
/// decide coverage), as whole numbers in `f32`, stored `(u0, −u1, v0, −v1)` so that a triangle's box is
/// the lane-wise minimum of its corners' (two SIMD instructions). That is the box of the corners' boxes:
/// rounding `x ± margin` up or down is monotone, so `⌈min x − m⌉ = min ⌈x − m⌉` and
/// `⌊max x + m⌋ = max ⌊x + m⌋`, and each vertex is rounded once instead of once per triangle, in floating
/// point (no integer conversion until a triangle is known to hold a pixel centre).
#[derive(Debug, Clone, Copy)]
struct VertexBox(Vec4);

impl VertexBox {
    /// The box of pixel position `p`. A vertex at or behind the source plane projects to an infinity or a
    /// NaN and gets a meaningless box, but [`RasterView::new`] then refuses the view before any box is used.
    #[inline]
    fn new(p: DVec2) -> Self {
        VertexBox(Vec4::new(
            ceil_clamped(p.x - BOX_MARGIN_PX),
            -floor_clamped(p.x + BOX_MARGIN_PX),
            ceil_clamped(p.y - BOX_MARGIN_PX),
            -floor_clamped(p.y + BOX_MARGIN_PX),
        ))
    }
}

/// `2⁵² + 2⁵¹`: adding and subtracting it rounds an `f64` of magnitude below 2⁵¹ to the nearest whole
/// number (ties to even), exactly, without leaving floating point.
const ROUNDER: f64 = 6_755_399_441_055_744.0;

/// `⌈x⌉` of `x` clamped to ±[`COORD_CLAMP`].
#[inline]
fn ceil_clamped(x: f64) -> f32 {
    let x = x.clamp(-COORD_CLAMP, COORD_CLAMP);
    let r = (x + ROUNDER) - ROUNDER;
    (r + f64::from(u8::from(r < x))) as f32
}

/// `⌊x⌋` of `x` clamped to ±[`COORD_CLAMP`].
#[inline]
fn floor_clamped(x: f64) -> f32 {
    let x = x.clamp(-COORD_CLAMP, COORD_CLAMP);
    let r = (x + ROUNDER) - ROUNDER;
    (r - f64::from(u8::from(r > x))) as f32
}

#[cfg(test)]
mod tests;
