//! The mutable connectivity both edge-collapse simplifiers work on: triangles with an alive flag and each
//! vertex's incident triangles.

/// Triangles (vertex indices), whether each is still alive, and the triangles incident to each vertex.
/// A vertex's list may hold dead triangles until the vertex is next touched; [`Topology::incident`]
/// filters them.
pub(super) struct Topology {
    pub tris: Vec<[u32; 3]>,
    pub tri_alive: Vec<bool>,
    pub vert_tris: Vec<Vec<u32>>,
}

impl Topology {
    /// The connectivity of `tris` over `n` vertices; only the triangles marked alive are listed at their
    /// vertices.
    pub fn new(tris: Vec<[u32; 3]>, tri_alive: Vec<bool>, n: usize) -> Self {
        let mut vert_tris: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (i, t) in tris.iter().enumerate() {
            if tri_alive[i] {
                for &v in t {
                    vert_tris[v as usize].push(i as u32);
                }
            }
        }
        Topology {
            tris,
            tri_alive,
            vert_tris,
        }
    }

    /// The live triangles incident to `v`.
    pub fn incident(&self, v: u32) -> impl Iterator<Item = u32> + '_ {
        self.vert_tris[v as usize]
            .iter()
            .copied()
            .filter(|&t| self.tri_alive[t as usize])
    }

    /// The live triangles incident to both `a` and `b` (two for an interior edge of a closed manifold).
    pub fn edge_triangles(&self, a: u32, b: u32) -> Vec<u32> {
        self.incident(a)
            .filter(|&t| self.tris[t as usize].contains(&b))
            .collect()
    }

    /// The vertices sharing a live triangle with `v`, ascending, without `v`.
    pub fn neighbours(&self, v: u32) -> Vec<u32> {
        let mut n: Vec<u32> = self
            .incident(v)
            .flat_map(|t| self.tris[t as usize])
            .filter(|&w| w != v)
            .collect();
        n.sort_unstable();
        n.dedup();
        n
    }

    /// The live triangles with their original index (for labels), in order.
    pub fn live(&self) -> impl Iterator<Item = (usize, [u32; 3])> + '_ {
        self.tris
            .iter()
            .enumerate()
            .filter(|&(i, _)| self.tri_alive[i])
            .map(|(i, t)| (i, *t))
    }
}
