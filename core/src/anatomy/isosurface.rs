//! Watertight isosurface extraction from a scalar grid by **marching tetrahedra**.
//!
//! Each grid cube is split into the six tetrahedra of the Kuhn (Freudenthal) triangulation, all sharing
//! the cube's main diagonal `(0,0,0)–(1,1,1)`. Neighbouring cubes split their shared face along the same
//! diagonal, so the tetrahedra tile space and the piecewise-linear isosurface of the interpolated field is
//! a closed 2-manifold. Unlike classic marching cubes (Lorensen & Cline 1987) there are no ambiguous faces,
//! hence no holes.
//!
//! * Vertices lie on the grid edges used by the tetrahedra (3 axis edges, 3 face diagonals and the body
//!   diagonal per grid point) at the linear crossing `t = (iso − v_a) / (v_b − v_a)`, clamped to
//!   `[1e-3, 1 − 1e-3]` so no triangle degenerates. A vertex is identified by its grid edge (welding by edge
//!   id), so adjacent tetrahedra share it exactly.
//! * The grid is padded by one virtual layer of "outside" samples, so surfaces touching the border close;
//!   a crossing to a padding sample is placed half way along the edge (half a voxel outside the grid).
//! * Each triangle is oriented so that its normal points from the inside to the outside end of one of its
//!   edges (exact: that edge crosses the triangle's plane once); triangles are flipped when the affine
//!   `index_to_world` has a negative determinant, so the mesh is always outward (positive volume).
//! * Work is split into z-slabs processed in parallel (rayon); vertices are then deduplicated by a sort of
//!   the edge ids, which keeps the output deterministic.

use glam::{DMat4, DVec3};
use rayon::prelude::*;

use super::TriMesh;
use crate::{Error, Result};

/// Most samples a grid the tool builds may hold: 2²⁸ (1 GiB of f32). Beyond it the allocation, and the
/// hours of sampling that follow, come from a voxel size typed wrong, not from a use.
pub const MAX_GRID_SAMPLES: u64 = 1 << 28;

/// Refuses a grid of `dims` (`nx × ny × nz` samples of `bytes_per_sample` bytes) for `what` (e.g.
/// "voxel_mm 0.0001") larger than [`MAX_GRID_SAMPLES`], with the estimate in the message. `dims` are
/// floating point so that the dimensions of an absurd voxel size (which overflow `usize`) are checked
/// before they are computed.
pub fn check_grid_size(what: &str, dims: [f64; 3], bytes_per_sample: usize) -> Result<()> {
    let samples = dims[0] * dims[1] * dims[2];
    if samples.is_finite() && samples <= MAX_GRID_SAMPLES as f64 {
        return Ok(());
    }
    let gib = samples * bytes_per_sample as f64 / f64::from(1u32 << 30);
    Err(Error::invalid(
        what,
        format!(
            "needs a grid of {:.0} × {:.0} × {:.0} = {samples:.3e} samples ({gib:.3e} GiB), more than the \
             limit of {MAX_GRID_SAMPLES} samples ({} GiB); use a larger voxel size",
            dims[0],
            dims[1],
            dims[2],
            MAX_GRID_SAMPLES as f64 * bytes_per_sample as f64 / f64::from(1u32 << 30),
        ),
    ))
}

/// A scalar field sampled on a regular grid, `values[i + nx·(j + ny·k)]` at index `(i, j, k)` (x fastest).
#[derive(Debug, Clone, PartialEq)]
pub struct ScalarGrid {
    pub dims: [usize; 3],
    pub values: Vec<f32>,
    /// Affine map from continuous index coordinates `(i, j, k)` to world millimetres.
    pub index_to_world: DMat4,
}

/// Which side of the iso-value is the solid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Inside {
    /// Inside where `value < iso`: signed distance fields (negative inside).
    #[default]
    Below,
    /// Inside where `value > iso`: label maps, densities, CT numbers.
    Above,
}

impl ScalarGrid {
    /// A grid, checked: every dimension ≥ 1, `values.len() == nx·ny·nz`, finite invertible affine.
    pub fn new(dims: [usize; 3], values: Vec<f32>, index_to_world: DMat4) -> Result<Self> {
        let g = ScalarGrid {
            dims,
            values,
            index_to_world,
        };
        g.check()?;
        Ok(g)
    }

    /// Samples `f(world point)` at every grid point (in parallel over z).
    pub fn from_fn<F>(dims: [usize; 3], index_to_world: DMat4, f: F) -> Result<Self>
    where
        F: Fn(DVec3) -> f64 + Sync,
    {
        let [nx, ny, nz] = dims;
        let mut values = vec![0f32; nx * ny * nz];
        values
            .par_chunks_mut((nx * ny).max(1))
            .enumerate()
            .for_each(|(k, slice)| {
                for j in 0..ny {
                    for i in 0..nx {
                        let p = index_to_world
                            .transform_point3(DVec3::new(i as f64, j as f64, k as f64));
                        slice[i + nx * j] = f(p) as f32;
                    }
                }
            });
        ScalarGrid::new(dims, values, index_to_world)
    }

    /// Samples a distance-like `f` exactly only where its value may fall in `[band_lo, band_hi]`.
    ///
    /// The grid is visited in 4×4×4 blocks; `f` is evaluated at the block centre, and when that value is
    /// farther from the band than `lipschitz ×` the block's half-diagonal (world units), the whole
    /// block gets the centre value (right side of every iso-value in the band, magnitude approximate).
    /// Otherwise every sample of the block is evaluated. Extraction at any iso in the band is then
    /// identical to [`ScalarGrid::from_fn`] while far fewer points are evaluated.
    pub fn from_fn_banded<F>(
        dims: [usize; 3],
        index_to_world: DMat4,
        f: F,
        band: [f64; 2],
        lipschitz: f64,
    ) -> Result<Self>
    where
        F: Fn(DVec3) -> f64 + Sync,
    {
        const B: usize = 4;
        let [nx, ny, nz] = dims;
        let step = [
            index_to_world.x_axis,
            index_to_world.y_axis,
            index_to_world.z_axis,
        ]
        .map(|c| c.truncate().length())
        .into_iter()
        .fold(0.0, f64::max);
        let reach = lipschitz * step * (3.0f64).sqrt() * B as f64 / 2.0;
        let at = |i: f64, j: f64, k: f64| f(index_to_world.transform_point3(DVec3::new(i, j, k)));
        let mut values = vec![0f32; nx * ny * nz];
        values
            .par_chunks_mut((nx * ny * B).max(1))
            .enumerate()
            .for_each(|(kb, slab)| {
                let k0 = kb * B;
                let layers = slab.len() / (nx * ny).max(1);
                for jb in (0..ny).step_by(B) {
                    for ib in (0..nx).step_by(B) {
                        let c = at(ib as f64 + 1.5, jb as f64 + 1.5, k0 as f64 + 1.5);
                        let far = c > band[1] + reach || c < band[0] - reach;
                        for dk in 0..layers {
                            for j in jb..(jb + B).min(ny) {
                                for i in ib..(ib + B).min(nx) {
                                    let v = if far {
                                        c
                                    } else {
                                        at(i as f64, j as f64, (k0 + dk) as f64)
                                    };
                                    slab[i + nx * (j + ny * dk)] = v as f32;
                                }
                            }
                        }
                    }
                }
            });
        ScalarGrid::new(dims, values, index_to_world)
    }

    fn check(&self) -> Result<()> {
        let [nx, ny, nz] = self.dims;
        if nx == 0 || ny == 0 || nz == 0 {
            return Err(Error::invalid(
                "grid dims",
                format!("{:?} has a zero", self.dims),
            ));
        }
        let n = nx.checked_mul(ny).and_then(|v| v.checked_mul(nz));
        if n != Some(self.values.len()) {
            return Err(Error::invalid(
                "grid values",
                format!("{} values for dims {:?}", self.values.len(), self.dims),
            ));
        }
        let padded = (nx as u64 + 2) * (ny as u64 + 2) * (nz as u64 + 2);
        if padded >= u64::MAX / 8 {
            return Err(Error::invalid("grid dims", "grid too large"));
        }
        let det = self.index_to_world.determinant();
        if !det.is_finite() || det == 0.0 || !self.index_to_world.is_finite() {
            return Err(Error::invalid(
                "grid index_to_world",
                "affine is singular or not finite",
            ));
        }
        Ok(())
    }
}

/// The six Kuhn tetrahedra of a cube; corner `c` has offset `(c & 1, (c >> 1) & 1, (c >> 2) & 1)`.
const TETS: [[usize; 4]; 6] = [
    [0, 1, 3, 7],
    [0, 1, 5, 7],
    [0, 2, 3, 7],
    [0, 2, 6, 7],
    [0, 4, 5, 7],
    [0, 4, 6, 7],
];
const T_EPS: f64 = 1e-3;

/// Read-only view of the padded grid used during extraction.
struct Field<'a> {
    grid: &'a ScalarGrid,
    iso: f32,
    inside: Inside,
    /// Padded dimensions (`n + 2` per axis); padded index `p` is grid index `p − 1`.
    pd: [u64; 3],
}

impl Field<'_> {
    /// Value at padded index, `None` in the padding layer.
    #[inline]
    fn value(&self, p: [u64; 3]) -> Option<f32> {
        let [nx, ny, nz] = self.grid.dims;
        let (i, j, k) = (
            p[0].wrapping_sub(1),
            p[1].wrapping_sub(1),
            p[2].wrapping_sub(1),
        );
        if i >= nx as u64 || j >= ny as u64 || k >= nz as u64 {
            return None;
        }
        Some(self.grid.values[i as usize + nx * (j as usize + ny * k as usize)])
    }

    #[inline]
    fn is_inside(&self, p: [u64; 3]) -> bool {
        match (self.value(p), self.inside) {
            (Some(v), Inside::Below) => v < self.iso,
            (Some(v), Inside::Above) => v > self.iso,
            (None, _) => false,
        }
    }

    #[inline]
    fn linear(&self, p: [u64; 3]) -> u64 {
        p[0] + self.pd[0] * (p[1] + self.pd[1] * p[2])
    }

    #[inline]
    fn unlinear(&self, l: u64) -> [u64; 3] {
        [
            l % self.pd[0],
            (l / self.pd[0]) % self.pd[1],
            l / (self.pd[0] * self.pd[1]),
        ]
    }

    /// Edge id from base corner `p` in direction `d` (bits x=1, y=2, z=4).
    #[inline]
    fn edge_key(&self, p: [u64; 3], d: usize) -> u64 {
        self.linear(p) * 8 + d as u64
    }

    /// Crossing point of edge `key` in (unpadded) index coordinates.
    fn edge_point(&self, key: u64) -> DVec3 {
        let d = (key % 8) as usize;
        let a = self.unlinear(key / 8);
        let b = [
            a[0] + (d & 1) as u64,
            a[1] + ((d >> 1) & 1) as u64,
            a[2] + ((d >> 2) & 1) as u64,
        ];
        let t = match (self.value(a), self.value(b)) {
            (Some(va), Some(vb)) => {
                let t = (f64::from(self.iso) - f64::from(va)) / (f64::from(vb) - f64::from(va));
                if t.is_finite() {
                    t.clamp(T_EPS, 1.0 - T_EPS)
                } else {
                    0.5
                }
            }
            _ => 0.5,
        };
        let pa = DVec3::new(a[0] as f64, a[1] as f64, a[2] as f64) - DVec3::ONE;
        let pb = DVec3::new(b[0] as f64, b[1] as f64, b[2] as f64) - DVec3::ONE;
        pa + (pb - pa) * t
    }

    /// Emits the triangles of one cube (base corner at padded index `p`) as edge-key triples.
    fn cube(&self, p: [u64; 3], out: &mut Vec<[u64; 3]>) {
        let corner = |c: usize| {
            [
                p[0] + (c & 1) as u64,
                p[1] + ((c >> 1) & 1) as u64,
                p[2] + ((c >> 2) & 1) as u64,
            ]
        };
        let mut inside = [false; 8];
        for (c, v) in inside.iter_mut().enumerate() {
            *v = self.is_inside(corner(c));
        }
        if inside.iter().all(|&v| v) || inside.iter().all(|&v| !v) {
            return;
        }
        // Kuhn tetrahedra use only edges from a corner to a superset corner (c ⊂ c' bitwise).
        let key = |a: usize, b: usize| {
            let (lo, hi) = if a < b { (a, b) } else { (b, a) };
            self.edge_key(corner(lo), hi ^ lo)
        };
        for tet in TETS {
            let (mut ins, mut outs) = ([0usize; 4], [0usize; 4]);
            let (mut ni, mut no) = (0, 0);
            for c in tet {
                if inside[c] {
                    ins[ni] = c;
                    ni += 1;
                } else {
                    outs[no] = c;
                    no += 1;
                }
            }
            match ni {
                1 => {
                    let a = ins[0];
                    let tri = [key(a, outs[0]), key(a, outs[1]), key(a, outs[2])];
                    self.push_oriented(tri, (a, outs[0]), out);
                }
                3 => {
                    let d = outs[0];
                    let tri = [key(ins[0], d), key(ins[1], d), key(ins[2], d)];
                    self.push_oriented(tri, (ins[0], d), out);
                }
                2 => {
                    let (a, b, c, d) = (ins[0], ins[1], outs[0], outs[1]);
                    // The quad ac–ad–bd–bc; both triangles contain edge a→c.
                    let (ac, ad, bd, bc) = (key(a, c), key(a, d), key(b, d), key(b, c));
                    self.push_oriented([ac, ad, bd], (a, c), out);
                    self.push_oriented([ac, bd, bc], (a, c), out);
                }
                _ => {}
            }
        }
    }

    /// Pushes `tri` oriented so its normal points along the edge `inside corner → outside corner`.
    fn push_oriented(&self, tri: [u64; 3], (cin, cout): (usize, usize), out: &mut Vec<[u64; 3]>) {
        let [a, b, c] = tri.map(|k| self.edge_point(k));
        let off = |c: usize| DVec3::new((c & 1) as f64, ((c >> 1) & 1) as f64, (c >> 2) as f64);
        let dir = off(cout) - off(cin);
        if (b - a).cross(c - a).dot(dir) >= 0.0 {
            out.push(tri);
        } else {
            out.push([tri[0], tri[2], tri[1]]);
        }
    }
}

/// Extracts the isosurface `value = iso` of an SDF-like grid (inside where `value < iso`).
///
/// See the module documentation for the algorithm; the result is closed, manifold and outward.
/// An empty mesh is returned when no sample is inside (or every sample is).
pub fn extract_isosurface(grid: &ScalarGrid, iso: f32) -> Result<TriMesh> {
    extract_isosurface_with(grid, iso, Inside::Below)
}

/// [`extract_isosurface`] with an explicit inside convention (use [`Inside::Above`] for label maps).
pub fn extract_isosurface_with(grid: &ScalarGrid, iso: f32, inside: Inside) -> Result<TriMesh> {
    grid.check()?;
    if !iso.is_finite() {
        return Err(Error::invalid("iso", format!("{iso} is not finite")));
    }
    let [nx, ny, nz] = grid.dims;
    let field = Field {
        grid,
        iso,
        inside,
        pd: [nx as u64 + 2, ny as u64 + 2, nz as u64 + 2],
    };
    // Cubes have base corners at padded indices 0..=n per axis (n + 1 cubes).
    let cube_layers = nz + 1;
    let slab = 4usize;
    let tris: Vec<[u64; 3]> = (0..cube_layers.div_ceil(slab))
        .into_par_iter()
        .flat_map_iter(|s| {
            let mut out = Vec::new();
            for k in s * slab..((s + 1) * slab).min(cube_layers) {
                for j in 0..=ny {
                    for i in 0..=nx {
                        field.cube([i as u64, j as u64, k as u64], &mut out);
                    }
                }
            }
            out
        })
        .collect();
    let mut keys: Vec<u64> = tris.iter().flatten().copied().collect();
    keys.par_sort_unstable();
    keys.dedup();
    if keys.len() > u32::MAX as usize {
        return Err(Error::invalid(
            "grid",
            "isosurface has more than 2^32 vertices",
        ));
    }
    let m = grid.index_to_world;
    let vertices: Vec<DVec3> = keys
        .par_iter()
        .map(|&k| m.transform_point3(field.edge_point(k)))
        .collect();
    let flip = m.determinant() < 0.0;
    let index = |k: u64| keys.binary_search(&k).map(|i| i as u32).unwrap_or(0);
    let triangles: Vec<[u32; 3]> = tris
        .par_iter()
        .map(|t| {
            let [a, b, c] = t.map(index);
            if flip { [a, c, b] } else { [a, b, c] }
        })
        .collect();
    Ok(TriMesh::new("isosurface", vertices, triangles))
}

/// Keeps the connected components (sharing vertices) whose enclosed volume is at least
/// `min_volume_mm3`; used to drop slivers of an eroded surface that vanish. Unused vertices are removed.
pub fn remove_small_components(mesh: &TriMesh, min_volume_mm3: f64) -> TriMesh {
    let n = mesh.vertices.len();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn find(parent: &mut [u32], mut x: u32) -> u32 {
        while parent[x as usize] != x {
            parent[x as usize] = parent[parent[x as usize] as usize];
            x = parent[x as usize];
        }
        x
    }
    for t in &mesh.triangles {
        let r0 = find(&mut parent, t[0]);
        for &v in &t[1..] {
            let r = find(&mut parent, v);
            parent[r as usize] = r0;
        }
    }
    let mut volume = std::collections::HashMap::<u32, f64>::new();
    for (i, t) in mesh.triangles.iter().enumerate() {
        let [a, b, c] = mesh.corners(i);
        *volume.entry(find(&mut parent, t[0])).or_default() += a.dot(b.cross(c)) / 6.0;
    }
    let kept: Vec<(usize, [u32; 3])> = (mesh.triangles.iter().copied().enumerate())
        .filter(|&(_, t)| volume[&find(&mut parent, t[0])] >= min_volume_mm3)
        .collect();
    TriMesh::compacted(&mesh.name, &mesh.vertices, kept.into_iter(), &mesh.labels)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn single_inside_sample_gives_closed_octahedron_like_surface() {
        let mut values = vec![1.0f32; 27];
        values[13] = -1.0;
        let g = ScalarGrid::new([3, 3, 3], values, DMat4::IDENTITY).unwrap();
        let m = extract_isosurface(&g, 0.0).unwrap();
        assert!(m.check().is_watertight(), "{:?}", m.check());
        assert!(m.volume() > 0.0);
    }

    #[test]
    fn rejects_wrong_value_count() {
        assert!(ScalarGrid::new([2, 2, 2], vec![0.0; 7], DMat4::IDENTITY).is_err());
    }
}
