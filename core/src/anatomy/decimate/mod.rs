//! Mesh decimation. `short_edges` simplifies a surface whose true shape is known (an SDF) by collapsing
//! short edges and projecting back onto it (the phantom); the rest of this module decimates arbitrary
//! surfaces (segmentations) by quadric-error-metric edge collapse (Garland & Heckbert 1997) that keeps a closed
//! mesh closed, manifold and consistently oriented.
//!
//! Every vertex starts with the area-weighted quadric `Σ_t A_t·[n_t d_t]ᵀ[n_t d_t]` of its triangles'
//! planes ([`quadric::Quadric`]). Edges sit in a binary min-heap keyed by the error of the collapse
//! target (the quadric minimiser `−A⁻¹b`, or the best of the endpoints and the midpoint when `A` is
//! singular). Heap entries carry the version stamps of both endpoints; a stale entry is skipped when
//! popped (lazy deletion). A collapse `v → u` is rejected when it would
//! * break the **link condition** (Dey et al. 1999): the common neighbours of `u` and `v` must be exactly
//!   the two vertices opposite the edge, otherwise the result has a non-manifold edge or a fin;
//! * **flip** a surviving triangle (its normal turning by more than `max_normal_deg`, or at all for a
//!   near-degenerate triangle whose old normal is noise);
//! * create a **sliver**: a triangle of quality `q = 4√3·area / Σ edge²` (1 for equilateral) below
//!   `min_quality`, unless the neighbourhood already held a triangle that bad.
//!
//! Vertices on boundary, non-manifold or misoriented edges are locked, so open input keeps its rims.
//! Surviving triangles keep their structure label.

mod distance;
mod quadric;
mod short_edges;
mod topology;

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use glam::DVec3;

use super::TriMesh;
use crate::{Error, Result};
use topology::Topology;

pub use distance::{Deviation, SurfaceDistance, deviation};
pub use quadric::Quadric;
pub use short_edges::{collapse_short_edges, project_to_zero};

/// Options of [`decimate_with`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DecimateOptions {
    /// Stop once the mesh has at most this many triangles (0: no triangle target).
    pub target_triangles: usize,
    /// Skip collapses whose RMS distance to the merged planes, `√(Q(p)/Σw)`, exceeds this (mm).
    pub max_error_mm: f64,
    /// Reject collapses creating a triangle of quality below this (see the module documentation).
    pub min_quality: f64,
    /// Reject collapses turning a triangle's normal by more than this (degrees).
    pub max_normal_deg: f64,
}

impl Default for DecimateOptions {
    fn default() -> Self {
        DecimateOptions {
            target_triangles: 0,
            max_error_mm: f64::INFINITY,
            min_quality: 0.1,
            max_normal_deg: 60.0,
        }
    }
}

/// What a decimation did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DecimateStats {
    pub triangles_in: usize,
    pub triangles_out: usize,
    pub collapses: usize,
    /// Largest RMS plane distance of a performed collapse (mm).
    pub max_collapse_error_mm: f64,
}

/// Decimates `mesh` to at most `target_triangles` triangles (fewer only by the last collapse's two;
/// more when no valid collapse is left).
pub fn decimate(mesh: &TriMesh, target_triangles: usize) -> Result<TriMesh> {
    if target_triangles < 4 {
        return Err(Error::invalid(
            "target_triangles",
            format!("{target_triangles} is below 4 (a tetrahedron)"),
        ));
    }
    let opts = DecimateOptions {
        target_triangles,
        ..DecimateOptions::default()
    };
    Ok(decimate_with(mesh, &opts)?.0)
}

/// Decimates `mesh` as far as collapses with an RMS plane distance ≤ `max_error_mm` allow.
pub fn decimate_to_error(mesh: &TriMesh, max_error_mm: f64) -> Result<TriMesh> {
    if !(max_error_mm.is_finite() && max_error_mm >= 0.0) {
        return Err(Error::invalid(
            "max_error_mm",
            format!("{max_error_mm} must be a finite non-negative distance"),
        ));
    }
    let opts = DecimateOptions {
        target_triangles: 4,
        max_error_mm,
        ..DecimateOptions::default()
    };
    Ok(decimate_with(mesh, &opts)?.0)
}

/// Decimation with explicit options; returns the mesh and statistics.
pub fn decimate_with(mesh: &TriMesh, opts: &DecimateOptions) -> Result<(TriMesh, DecimateStats)> {
    mesh.validate("mesh")?;
    if !(opts.min_quality.is_finite() && (0.0..1.0).contains(&opts.min_quality)) {
        return Err(Error::invalid(
            "min_quality",
            format!("{} is outside [0, 1)", opts.min_quality),
        ));
    }
    if !(opts.max_normal_deg > 0.0 && opts.max_normal_deg <= 180.0) {
        return Err(Error::invalid(
            "max_normal_deg",
            format!("{} is outside (0, 180]", opts.max_normal_deg),
        ));
    }
    let mut c = Collapser::new(mesh, opts);
    let triangles_in = c.live_tris;
    c.run();
    let collapses = c.collapses;
    let max_err = c.max_err;
    let out = c.into_mesh(mesh);
    let stats = DecimateStats {
        triangles_in,
        triangles_out: out.triangles.len(),
        collapses,
        max_collapse_error_mm: max_err,
    };
    Ok((out, stats))
}

/// A heap entry: collapse `v` into `u` at `target`.
struct Candidate {
    cost: f64,
    u: u32,
    v: u32,
    stamps: (u32, u32),
    target: DVec3,
}

impl PartialEq for Candidate {
    fn eq(&self, o: &Self) -> bool {
        self.cost.total_cmp(&o.cost) == Ordering::Equal
    }
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Candidate {
    /// Reversed, so `BinaryHeap` pops the cheapest collapse first.
    fn cmp(&self, o: &Self) -> Ordering {
        o.cost.total_cmp(&self.cost)
    }
}

struct Collapser {
    pos: Vec<DVec3>,
    quad: Vec<Quadric>,
    stamp: Vec<u32>,
    locked: Vec<bool>,
    vertex_alive: Vec<bool>,
    topo: Topology,
    heap: BinaryHeap<Candidate>,
    live_tris: usize,
    collapses: usize,
    max_err: f64,
    opts: DecimateOptions,
    cos_max: f64,
}

/// Triangle quality `4√3·area / (|e0|² + |e1|² + |e2|²)`: 1 for equilateral, 0 for degenerate.
fn quality(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let s = (b - a).length_squared() + (c - b).length_squared() + (a - c).length_squared();
    if s <= 0.0 {
        return 0.0;
    }
    2.0 * 3f64.sqrt() * (b - a).cross(c - a).length() / s
}

impl Collapser {
    fn new(mesh: &TriMesh, opts: &DecimateOptions) -> Collapser {
        let n = mesh.vertices.len();
        let tris: Vec<[u32; 3]> = mesh.triangles.clone();
        let tri_alive: Vec<bool> = tris
            .iter()
            .map(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
            .collect();
        let mut quad = vec![Quadric::default(); n];
        for (i, t) in tris.iter().enumerate() {
            if !tri_alive[i] {
                continue;
            }
            let [a, b, c] = mesh.corners(i);
            let cr = (b - a).cross(c - a);
            let area = 0.5 * cr.length();
            let q = match cr.try_normalize() {
                Some(nrm) => Quadric::plane(nrm, a, area),
                None => Quadric::default(),
            };
            for &v in t {
                quad[v as usize] += q;
            }
        }
        let locked = locked_vertices(&tris, &tri_alive, n);
        let live_tris = tri_alive.iter().filter(|&&a| a).count();
        let mut c = Collapser {
            pos: mesh.vertices.clone(),
            quad,
            stamp: vec![0; n],
            locked,
            vertex_alive: vec![true; n],
            topo: Topology::new(tris, tri_alive, n),
            heap: BinaryHeap::with_capacity(live_tris * 3 / 2),
            live_tris,
            collapses: 0,
            max_err: 0.0,
            opts: *opts,
            cos_max: opts.max_normal_deg.to_radians().cos(),
        };
        c.push_all_edges();
        c
    }

    fn push_all_edges(&mut self) {
        for i in 0..self.topo.tris.len() {
            if !self.topo.tri_alive[i] {
                continue;
            }
            let t = self.topo.tris[i];
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                if a < b {
                    self.push_edge(a, b);
                }
            }
        }
    }

    /// Plans the collapse of edge `(a, b)` and pushes it unless a vertex is locked.
    fn push_edge(&mut self, a: u32, b: u32) {
        let (ia, ib) = (a as usize, b as usize);
        if self.locked[ia] || self.locked[ib] {
            return;
        }
        let q = self.quad[ia] + self.quad[ib];
        let (pa, pb) = (self.pos[ia], self.pos[ib]);
        let mid = 0.5 * (pa + pb);
        let len = (pb - pa).length();
        let mut best = (q.error(mid), mid);
        for p in [pa, pb] {
            let e = q.error(p);
            if e < best.0 {
                best = (e, p);
            }
        }
        // The minimiser, unless it flies off (near-singular A): keep targets within an edge length.
        if let Some(p) = q.minimiser().filter(|p| (*p - mid).length() <= len) {
            let e = q.error(p);
            if e <= best.0 {
                best = (e, p);
            }
        }
        let rms = if q.weight > 0.0 {
            (best.0 / q.weight).sqrt()
        } else {
            0.0
        };
        if rms > self.opts.max_error_mm {
            return;
        }
        self.heap.push(Candidate {
            cost: best.0,
            u: a,
            v: b,
            stamps: (self.stamp[ia], self.stamp[ib]),
            target: best.1,
        });
    }

    fn run(&mut self) {
        loop {
            let before = self.collapses;
            while self.live_tris > self.opts.target_triangles.max(4) {
                let Some(c) = self.heap.pop() else { break };
                let (u, v) = (c.u as usize, c.v as usize);
                if !self.vertex_alive[u]
                    || !self.vertex_alive[v]
                    || (self.stamp[u], self.stamp[v]) != c.stamps
                {
                    continue;
                }
                if self.collapse_allowed(c.u, c.v, c.target) {
                    self.collapse(c.u, c.v, c.target);
                }
            }
            // Rejected collapses are dropped; a neighbour's collapse may have made them valid since,
            // so rebuild the heap once per round while rounds still make progress.
            if self.live_tris <= self.opts.target_triangles.max(4) || self.collapses == before {
                break;
            }
            self.heap.clear();
            self.push_all_edges();
        }
    }

    /// Link condition, flip and sliver tests for collapsing `v` into `u` at `p`.
    fn collapse_allowed(&self, u: u32, v: u32, p: DVec3) -> bool {
        let Some(shared) = self.topo.edge_pair(u, v) else {
            return false;
        };
        let (nu, nv) = (self.topo.neighbours(u), self.topo.neighbours(v));
        let common = nu.iter().filter(|w| nv.binary_search(w).is_ok()).count();
        if common != 2 {
            return false;
        }
        let mut old_min_q = f64::INFINITY;
        let mut new_min_q = f64::INFINITY;
        for t in self.topo.incident(u).chain(self.topo.incident(v)) {
            let tri = self.topo.tris[t as usize];
            let [a, b, c] = tri.map(|i| self.pos[i as usize]);
            let q_old = quality(a, b, c);
            old_min_q = old_min_q.min(q_old);
            if shared.contains(&t) {
                continue;
            }
            let moved = tri.map(|i| {
                if i == u || i == v {
                    p
                } else {
                    self.pos[i as usize]
                }
            });
            let n_old = (b - a).cross(c - a);
            let n_new = (moved[1] - moved[0]).cross(moved[2] - moved[0]);
            let q_new = quality(moved[0], moved[1], moved[2]);
            new_min_q = new_min_q.min(q_new);
            let (lo, ln) = (n_old.length(), n_new.length());
            if ln <= 0.0 {
                return false;
            }
            let cos = if lo > 0.0 {
                n_old.dot(n_new) / (lo * ln)
            } else {
                1.0
            };
            let limit = if q_old >= 0.05 { self.cos_max } else { 0.0 };
            if cos < limit {
                return false;
            }
        }
        new_min_q >= self.opts.min_quality || new_min_q >= old_min_q
    }

    fn collapse(&mut self, u: u32, v: u32, p: DVec3) {
        let (iu, iv) = (u as usize, v as usize);
        let q = self.quad[iu] + self.quad[iv];
        if q.weight > 0.0 {
            self.max_err = self.max_err.max((q.error(p) / q.weight).sqrt());
        }
        let vts = std::mem::take(&mut self.topo.vert_tris[iv]);
        for &t in &vts {
            let ti = t as usize;
            if !self.topo.tri_alive[ti] {
                continue;
            }
            if self.topo.tris[ti].contains(&u) {
                self.topo.tri_alive[ti] = false;
                self.live_tris -= 1;
            } else {
                for x in &mut self.topo.tris[ti] {
                    if *x == v {
                        *x = u;
                    }
                }
            }
        }
        let mut merged = std::mem::take(&mut self.topo.vert_tris[iu]);
        merged.extend(vts);
        merged.retain(|&t| self.topo.tri_alive[t as usize]);
        merged.sort_unstable();
        merged.dedup();
        self.topo.vert_tris[iu] = merged;
        self.pos[iu] = p;
        self.quad[iu] = q;
        self.stamp[iu] = self.stamp[iu].wrapping_add(1);
        self.vertex_alive[iv] = false;
        self.collapses += 1;
        for w in self.topo.neighbours(u) {
            let (a, b) = if u < w { (u, w) } else { (w, u) };
            self.push_edge(a, b);
        }
    }

    /// Compacts live triangles and their vertices into a new mesh with the input's name and labels.
    fn into_mesh(self, original: &TriMesh) -> TriMesh {
        TriMesh::compacted(
            &original.name,
            &self.pos,
            self.topo.live(),
            &original.labels,
        )
    }
}

/// Vertices on an edge that is not shared by exactly two oppositely oriented triangles.
fn locked_vertices(tris: &[[u32; 3]], alive: &[bool], n: usize) -> Vec<bool> {
    let mut edges: Vec<(u32, u32, bool)> = Vec::with_capacity(tris.len() * 3);
    for (i, t) in tris.iter().enumerate() {
        if !alive[i] {
            continue;
        }
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            edges.push((a.min(b), a.max(b), a < b));
        }
    }
    edges.sort_unstable();
    let mut locked = vec![false; n];
    let mut i = 0;
    while i < edges.len() {
        let mut j = i;
        while j < edges.len() && (edges[j].0, edges[j].1) == (edges[i].0, edges[i].1) {
            j += 1;
        }
        let ok = j - i == 2 && edges[i].2 != edges[i + 1].2;
        if !ok {
            locked[edges[i].0 as usize] = true;
            locked[edges[i].1 as usize] = true;
        }
        i = j;
    }
    locked
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quality_of_equilateral_is_one() {
        let h = 3f64.sqrt() / 2.0;
        let q = quality(DVec3::ZERO, DVec3::X, DVec3::new(0.5, h, 0.0));
        assert!((q - 1.0).abs() < 1e-12);
        assert_eq!(quality(DVec3::ZERO, DVec3::X, 2.0 * DVec3::X), 0.0);
    }

    #[test]
    fn open_mesh_keeps_its_rim() {
        let mut m = TriMesh::icosphere("s", DVec3::ZERO, 5.0, 3);
        m.triangles.truncate(m.triangles.len() - 1);
        let before = m.check().boundary_edges;
        let d = decimate(&m, 200).unwrap();
        assert_eq!(d.check().boundary_edges, before);
        assert_eq!(d.check().nonmanifold_edges, 0);
    }
}
