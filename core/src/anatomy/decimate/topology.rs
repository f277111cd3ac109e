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

    /// The two live triangles incident to both `a` and `b`, in the order of `a`'s list, when there are
    /// exactly two (an interior edge of a closed manifold); `None` otherwise.
    pub fn edge_pair(&self, a: u32, b: u32) -> Option<[u32; 2]> {
        let mut it = self
            .incident(a)
            .filter(|&t| self.tris[t as usize].contains(&b));
        let pair = [it.next()?, it.next()?];
        it.next().is_none().then_some(pair)
    }

    /// The vertices sharing a live triangle with `v`, ascending, without `v`.
    pub fn neighbours(&self, v: u32) -> Vec<u32> {
        let mut n = Vec::new();
        self.neighbours_into(v, &mut n);
        n
    }

    /// [`Self::neighbours`] into `out` (cleared first; its capacity is reused).
    pub fn neighbours_into(&self, v: u32, out: &mut Vec<u32>) {
        out.clear();
        out.extend(
            self.incident(v)
                .flat_map(|t| self.tris[t as usize])
                .filter(|&w| w != v),
        );
        out.sort_unstable();
        out.dedup();
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
