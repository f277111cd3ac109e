//! Contour distances between a reference contour `A` and a perturbed contour `B` (point sets, px):
//! directed nearest-neighbour distances `d(a, B) = min_b ‖a − b‖` and the metrics built from them.

use glam::DVec2;

use super::contours::{border_pixels, bounding_window, check_mask, crop};
use crate::{Error, Result};

/// A uniform grid over a point set for exact nearest-neighbour queries (ring search).
struct PointGrid {
    cell: f64,
    origin: DVec2,
    nx: i64,
    ny: i64,
    buckets: Vec<Vec<DVec2>>,
}

impl PointGrid {
    fn new(points: &[DVec2]) -> Self {
        let (lo, hi) = points.iter().fold(
            (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let extent = (hi - lo).max(DVec2::ONE);
        // About two points per cell on a contour of n points.
        let cell = ((extent.x * extent.y) / points.len().max(1) as f64)
            .sqrt()
            .max(1.0);
        let nx = (extent.x / cell).floor() as i64 + 1;
        let ny = (extent.y / cell).floor() as i64 + 1;
        let mut buckets = vec![Vec::new(); (nx * ny) as usize];
        for &p in points {
            let (i, j) = (((p.x - lo.x) / cell) as i64, ((p.y - lo.y) / cell) as i64);
            buckets[(j * nx + i) as usize].push(p);
        }
        PointGrid {
            cell,
            origin: lo,
            nx,
            ny,
            buckets,
        }
    }

    /// Exact distance from `q` to the nearest grid point: rings of cells until the ring is farther than
    /// the best distance found.
    fn nearest(&self, q: DVec2) -> f64 {
        let ci = ((q.x - self.origin.x) / self.cell).floor() as i64;
        let cj = ((q.y - self.origin.y) / self.cell).floor() as i64;
        let mut best = f64::INFINITY;
        // Beyond this ring every cell of the grid has been visited.
        let r_max = ci
            .abs()
            .max(cj.abs())
            .max((self.nx - 1 - ci).abs())
            .max((self.ny - 1 - cj).abs());
        for r in 0..=r_max {
            let (i0, i1, j0, j1) = (ci - r, ci + r, cj - r, cj + r);
            for j in j0.max(0)..=j1.min(self.ny - 1) {
                for i in i0.max(0)..=i1.min(self.nx - 1) {
                    if (j != j0 && j != j1) && (i != i0 && i != i1) {
                        continue; // interior cells were visited by smaller rings
                    }
                    for p in &self.buckets[(j * self.nx + i) as usize] {
                        best = best.min((*p - q).length_squared());
                    }
                }
            }
            // Every point outside the rings searched so far is at least r · cell away.
            if best.is_finite() && best.sqrt() <= r as f64 * self.cell {
                break;
            }
        }
        best.sqrt()
    }
}

/// Distances from each point of `from` to the nearest point of `to` (exact).
pub fn directed_distances(from: &[DVec2], to: &[DVec2]) -> Vec<f64> {
    if to.is_empty() {
        return vec![f64::INFINITY; from.len()];
    }
    let grid = PointGrid::new(to);
    from.iter().map(|&q| grid.nearest(q)).collect()
}

/// Both directed distance lists of a contour pair, from which every contour metric follows.
#[derive(Debug, Clone)]
pub struct ContourDistances {
    pub ref_to_pert: Vec<f64>,
    pub pert_to_ref: Vec<f64>,
}

impl ContourDistances {
    /// Computes both directions; both contours must be non-empty.
    pub fn between(reference: &[DVec2], perturbed: &[DVec2]) -> Result<Self> {
        if reference.is_empty() || perturbed.is_empty() {
            return Err(Error::invalid(
                "contour",
                "a contour is empty (the silhouette has no pixels)",
            ));
        }
        Ok(ContourDistances {
            ref_to_pert: directed_distances(reference, perturbed),
            pert_to_ref: directed_distances(perturbed, reference),
        })
    }

    /// The paper's one-sided Chamfer distance `Σ_{x ∈ C_gt} min_{y ∈ C_err} ‖x − y‖` (px; grows with the
    /// number of contour points).
    pub fn chamfer_sum(&self) -> f64 {
        self.ref_to_pert.iter().sum()
    }

    /// Symmetric mean Chamfer distance `(mean d(A→B) + mean d(B→A)) / 2` (px).
    pub fn chamfer_mean(&self) -> f64 {
        0.5 * (mean(&self.ref_to_pert) + mean(&self.pert_to_ref))
    }

    /// Hausdorff distance `max(max d(A→B), max d(B→A))` (px).
    pub fn hausdorff(&self) -> f64 {
        let m = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
        m(&self.ref_to_pert).max(m(&self.pert_to_ref))
    }

    /// HD95: the larger of the two directed 95th percentiles (linear interpolation between ranks, as
    /// numpy's default), robust to a few outlying contour points.
    pub fn hd95(&self) -> f64 {
        percentile(&self.ref_to_pert, 95.0).max(percentile(&self.pert_to_ref, 95.0))
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// The `q`-th percentile with linear interpolation between order statistics.
pub fn percentile(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let pos = q / 100.0 * (s.len() - 1) as f64;
    let (i, f) = (pos.floor() as usize, pos.fract());
    if i + 1 < s.len() {
        s[i] * (1.0 - f) + s[i + 1] * f
    } else {
        s[i]
    }
}

/// Edge-based contour distance: the Euclidean distance transform (OpenCV `distanceTransform`,
/// `DIST_L2`, `DIST_MASK_PRECISE`, i.e. exact) of one silhouette's border pixels, sampled at the other's
/// border pixels, averaged over both directions (px). Returns `(mean, max)`.
pub fn edge_distance(
    reference: &[bool],
    perturbed: &[bool],
    width: u32,
    height: u32,
) -> Result<(f64, f64)> {
    check_mask(reference, width, height)?;
    check_mask(perturbed, width, height)?;
    // Every edge pixel of both masks lies in their joint bounding window, so the distance transform
    // is computed there only (exact, and much smaller than the detector).
    let empty = || Error::invalid("mask", "a silhouette is empty");
    let win = bounding_window(&[reference, perturbed], width, height).ok_or_else(empty)?;
    let (cw, ch) = (win.w as u32, win.h as u32);
    let ea = border_pixels(&crop(reference, width, win), cw, ch)?;
    let eb = border_pixels(&crop(perturbed, width, win), cw, ch)?;
    if !ea.iter().any(|&e| e) || !eb.iter().any(|&e| e) {
        return Err(empty());
    }
    let da = distance_to_edges(&ea, cw, ch)?;
    let db = distance_to_edges(&eb, cw, ch)?;
    let sample = |dt: &[f32], edges: &[bool]| -> (f64, f64, usize) {
        edges
            .iter()
            .zip(dt)
            .filter(|(e, _)| **e)
            .fold((0.0, 0.0f64, 0), |(s, m, n), (_, &d)| {
                (s + f64::from(d), m.max(f64::from(d)), n + 1)
            })
    };
    let (sa, ma, na) = sample(&db, &ea);
    let (sb, mb, nb) = sample(&da, &eb);
    Ok((0.5 * (sa / na as f64 + sb / nb as f64), ma.max(mb)))
}

/// Per-pixel Euclidean distance to the nearest `true` pixel of `edges`.
fn distance_to_edges(edges: &[bool], width: u32, height: u32) -> Result<Vec<f32>> {
    // distanceTransform measures the distance to the nearest zero pixel.
    let bytes: Vec<u8> = edges.iter().map(|&e| if e { 0 } else { 255 }).collect();
    spinedrr_cv::distance_transform(&bytes, height as usize, width as usize).map_err(Error::opencv)
}
