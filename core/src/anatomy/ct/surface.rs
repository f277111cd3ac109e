//! Surfaces of segmentation labels: the largest 6-connected component of a label's voxels, meshed in
//! world coordinates by the watertight isosurface extractor ([`crate::anatomy::isosurface`]) at the 0.5
//! level of the binary mask, then optionally smoothed by Taubin's λ|μ filter (Taubin 1995, "A signal
//! processing approach to fair surface design": alternating `x += λ·L(x)` and `x += μ·L(x)` with the
//! umbrella Laplacian `L(x_i) = mean_j(x_j) − x_i`, `μ < −λ < 0`, which smooths without shrinking).
//! Smoothing moves vertices only, so the mesh stays closed and manifold.

use std::collections::VecDeque;

use glam::{DMat4, DVec3};

use super::LabelMap;
use crate::anatomy::TriMesh;
use crate::anatomy::isosurface::{Inside, ScalarGrid, extract_isosurface_with};
use crate::{Error, Result};

/// Options of [`label_surface`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceOptions {
    /// Keep only the largest 6-connected voxel component of the label.
    pub largest_component: bool,
    /// Taubin λ|μ iteration pairs (0 = no smoothing).
    pub smooth_iterations: usize,
    pub lambda: f64,
    pub mu: f64,
}

impl Default for SurfaceOptions {
    fn default() -> Self {
        SurfaceOptions {
            largest_component: true,
            smooth_iterations: 0,
            lambda: 0.5,
            mu: -0.53,
        }
    }
}

/// Most Taubin iteration pairs [`label_surface`] runs: its low-pass response settles within tens of
/// iterations; thousands only cost minutes.
pub const MAX_SMOOTH_ITERATIONS: usize = 500;

/// The closed outward surface (world mm) of the voxels of `seg` carrying `label`.
pub fn label_surface(seg: &LabelMap, label: u16, opts: &SurfaceOptions) -> Result<TriMesh> {
    if opts.smooth_iterations > MAX_SMOOTH_ITERATIONS {
        return Err(Error::invalid(
            "smooth_iterations",
            format!(
                "{} is more than the limit of {MAX_SMOOTH_ITERATIONS} Taubin iterations",
                opts.smooth_iterations
            ),
        ));
    }
    let mut keep: Vec<bool> = seg.values.iter().map(|&v| v == label).collect();
    if !keep.iter().any(|&k| k) {
        return Err(Error::invalid(
            "label",
            format!(
                "{label} is not present in the segmentation (labels present: {:?})",
                seg.labels_present()
            ),
        ));
    }
    if opts.largest_component {
        keep = largest_component(seg.dims, &keep);
    }
    let Some(mask) = super::VoxelMask::from_keep(seg, keep) else {
        // `keep` holds a voxel (checked above) and its largest component is never empty.
        return Err(Error::Internal(format!("label {label}: empty mask")));
    };
    let (lo, hi) = mask.bbox;
    let sub = [0, 1, 2].map(|a| hi[a] - lo[a] + 1);
    let mut values = Vec::with_capacity(sub[0] * sub[1] * sub[2]);
    for k in lo[2]..=hi[2] {
        for j in lo[1]..=hi[1] {
            for i in lo[0]..=hi[0] {
                values.push(if mask.keep[seg.linear(i, j, k)] {
                    1.0
                } else {
                    0.0
                });
            }
        }
    }
    let shift = DVec3::new(lo[0] as f64, lo[1] as f64, lo[2] as f64);
    let grid = ScalarGrid::new(
        sub,
        values,
        seg.index_to_world * DMat4::from_translation(shift),
    )?;
    let mut mesh = extract_isosurface_with(&grid, 0.5, Inside::Above)?;
    if mesh.triangles.is_empty() {
        return Err(Error::Numerical(format!(
            "label {label}: surface extraction produced zero triangles"
        )));
    }
    mesh.name = format!("label_{label}");
    taubin_smooth(&mut mesh, opts.smooth_iterations, opts.lambda, opts.mu);
    Ok(mesh)
}

/// The largest 6-connected component of `keep` (breadth-first flood fill).
pub fn largest_component(dims: [usize; 3], keep: &[bool]) -> Vec<bool> {
    let [nx, ny, nz] = dims;
    let mut comp = vec![u32::MAX; keep.len()];
    let (mut best, mut best_size, mut next) = (u32::MAX, 0usize, 0u32);
    let mut queue = VecDeque::new();
    for start in 0..keep.len() {
        if !keep[start] || comp[start] != u32::MAX {
            continue;
        }
        comp[start] = next;
        queue.push_back(start);
        let mut size = 0;
        while let Some(n) = queue.pop_front() {
            size += 1;
            let (i, j, k) = (n % nx, (n / nx) % ny, n / (nx * ny));
            let mut visit = |m: usize| {
                if keep[m] && comp[m] == u32::MAX {
                    comp[m] = next;
                    queue.push_back(m);
                }
            };
            if i > 0 {
                visit(n - 1)
            }
            if i + 1 < nx {
                visit(n + 1)
            }
            if j > 0 {
                visit(n - nx)
            }
            if j + 1 < ny {
                visit(n + nx)
            }
            if k > 0 {
                visit(n - nx * ny)
            }
            if k + 1 < nz {
                visit(n + nx * ny)
            }
        }
        if size > best_size {
            (best, best_size) = (next, size);
        }
        next += 1;
    }
    comp.iter().map(|&c| c == best).collect()
}

/// Taubin λ|μ smoothing with the umbrella Laplacian over each vertex's edge neighbours.
pub fn taubin_smooth(mesh: &mut TriMesh, iterations: usize, lambda: f64, mu: f64) {
    if iterations == 0 {
        return;
    }
    let n = mesh.vertices.len();
    let mut nbrs: Vec<Vec<u32>> = vec![Vec::new(); n];
    for t in &mesh.triangles {
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            nbrs[a as usize].push(b);
            nbrs[b as usize].push(a);
        }
    }
    for list in &mut nbrs {
        list.sort_unstable();
        list.dedup();
    }
    let step = |w: f64, v: &mut Vec<DVec3>| {
        let moved: Vec<DVec3> = (0..n)
            .map(|i| {
                let ns = &nbrs[i];
                if ns.is_empty() {
                    return v[i];
                }
                let mean = ns.iter().map(|&j| v[j as usize]).sum::<DVec3>() / ns.len() as f64;
                v[i] + w * (mean - v[i])
            })
            .collect();
        *v = moved;
    };
    for _ in 0..iterations {
        step(lambda, &mut mesh.vertices);
        step(mu, &mut mesh.vertices);
    }
}
