//! Indexed triangle meshes with a per-triangle structure label.

use std::collections::HashMap;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::geometry::RigidTransform;
use crate::{Error, Result};

/// The anatomical structure a triangle belongs to (stored as `u8` per triangle).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[repr(u8)]
pub enum Structure {
    Unlabelled = 0,
    Body = 1,
    PedicleLeft = 2,
    PedicleRight = 3,
    Lamina = 4,
    Spinous = 5,
    Transverse = 6,
    Articular = 7,
    SuperiorEndplate = 8,
    InferiorEndplate = 9,
    SoftTissue = 10,
}

impl Structure {
    pub const ALL: [Structure; 11] = [
        Structure::Unlabelled,
        Structure::Body,
        Structure::PedicleLeft,
        Structure::PedicleRight,
        Structure::Lamina,
        Structure::Spinous,
        Structure::Transverse,
        Structure::Articular,
        Structure::SuperiorEndplate,
        Structure::InferiorEndplate,
        Structure::SoftTissue,
    ];

    /// Snake-case name used in file names and tables.
    pub fn name(self) -> &'static str {
        match self {
            Structure::Unlabelled => "unlabelled",
            Structure::Body => "body",
            Structure::PedicleLeft => "pedicle_left",
            Structure::PedicleRight => "pedicle_right",
            Structure::Lamina => "lamina",
            Structure::Spinous => "spinous",
            Structure::Transverse => "transverse",
            Structure::Articular => "articular",
            Structure::SuperiorEndplate => "superior_endplate",
            Structure::InferiorEndplate => "inferior_endplate",
            Structure::SoftTissue => "soft_tissue",
        }
    }

    pub fn from_u8(v: u8) -> Option<Structure> {
        Self::ALL.get(v as usize).copied()
    }
}

/// An indexed triangle mesh in millimetres. Triangles are counter-clockwise seen from outside, so
/// `(v1 − v0) × (v2 − v0)` points outward.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TriMesh {
    pub name: String,
    pub vertices: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
    /// One [`Structure`] code per triangle, or empty when unlabelled.
    pub labels: Vec<u8>,
}

/// Result of a topology check.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MeshCheck {
    /// Edges used by exactly one triangle (holes).
    pub boundary_edges: usize,
    /// Edges used by more than two triangles.
    pub nonmanifold_edges: usize,
    /// Edges whose two triangles traverse them in the same direction (inconsistent orientation).
    pub misoriented_edges: usize,
    /// Triangles with zero area or repeated vertices.
    pub degenerate_triangles: usize,
}

impl MeshCheck {
    /// Closed, manifold and consistently oriented.
    pub fn is_watertight(&self) -> bool {
        self.boundary_edges == 0 && self.nonmanifold_edges == 0 && self.misoriented_edges == 0
    }
}

impl TriMesh {
    pub fn new(name: impl Into<String>, vertices: Vec<DVec3>, triangles: Vec<[u32; 3]>) -> Self {
        TriMesh {
            name: name.into(),
            vertices,
            triangles,
            labels: Vec::new(),
        }
    }

    /// Checks indices, finiteness and the label count; `what` names the mesh in errors.
    pub fn validate(&self, what: &str) -> Result<()> {
        if self.triangles.is_empty() {
            return Err(Error::invalid(what, "mesh has no triangles"));
        }
        if let Some(i) = self.vertices.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(what, format!("vertex {i} is not finite")));
        }
        let n = self.vertices.len() as u64;
        if let Some(t) = self
            .triangles
            .iter()
            .position(|t| t.iter().any(|&i| u64::from(i) >= n))
        {
            return Err(Error::invalid(
                what,
                format!("triangle {t} indexes a vertex beyond the {n} vertices"),
            ));
        }
        if !self.labels.is_empty() && self.labels.len() != self.triangles.len() {
            return Err(Error::invalid(
                what,
                "label count differs from triangle count",
            ));
        }
        Ok(())
    }

    /// The three corners of triangle `i`.
    #[inline]
    pub fn corners(&self, i: usize) -> [DVec3; 3] {
        let [a, b, c] = self.triangles[i];
        [
            self.vertices[a as usize],
            self.vertices[b as usize],
            self.vertices[c as usize],
        ]
    }

    /// Structure of triangle `i` (Unlabelled when the mesh has no labels).
    pub fn label(&self, i: usize) -> Structure {
        self.labels
            .get(i)
            .and_then(|&l| Structure::from_u8(l))
            .unwrap_or(Structure::Unlabelled)
    }

    /// Axis-aligned bounds `(min, max)`; `None` for a mesh without vertices.
    pub fn bounds(&self) -> Option<(DVec3, DVec3)> {
        let first = *self.vertices.first()?;
        Some(
            self.vertices
                .iter()
                .fold((first, first), |(lo, hi), &v| (lo.min(v), hi.max(v))),
        )
    }

    /// Enclosed volume by the divergence theorem, `Σ v0 · (v1 × v2) / 6` (mm³; positive when outward).
    pub fn volume(&self) -> f64 {
        (0..self.triangles.len())
            .map(|i| {
                let [a, b, c] = self.corners(i);
                a.dot(b.cross(c))
            })
            .sum::<f64>()
            / 6.0
    }

    /// Surface area (mm²).
    pub fn area(&self) -> f64 {
        (0..self.triangles.len())
            .map(|i| {
                let [a, b, c] = self.corners(i);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    }

    /// Edge-based topology check.
    pub fn check(&self) -> MeshCheck {
        let mut edges: HashMap<(u32, u32), (u32, u32)> =
            HashMap::with_capacity(self.triangles.len() * 3 / 2);
        let mut out = MeshCheck::default();
        for (i, t) in self.triangles.iter().enumerate() {
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                out.degenerate_triangles += 1;
                continue;
            }
            let [a, b, c] = self.corners(i);
            if (b - a).cross(c - a).length_squared() == 0.0 {
                out.degenerate_triangles += 1;
            }
            for k in 0..3 {
                let (p, q) = (t[k], t[(k + 1) % 3]);
                let e = edges.entry((p.min(q), p.max(q))).or_insert((0, 0));
                if p < q { e.0 += 1 } else { e.1 += 1 }
            }
        }
        for &(fwd, back) in edges.values() {
            match fwd + back {
                1 => out.boundary_edges += 1,
                2 if fwd != 1 => out.misoriented_edges += 1,
                2 => {}
                _ => out.nonmanifold_edges += 1,
            }
        }
        out
    }

    /// Applies a rigid transform to every vertex.
    pub fn transform(&mut self, t: &RigidTransform) {
        for v in &mut self.vertices {
            *v = t.apply(*v);
        }
    }

    /// Flips every triangle's orientation.
    pub fn flip(&mut self) {
        for t in &mut self.triangles {
            t.swap(1, 2);
        }
    }

    /// Makes a closed, consistently wound mesh that is inside out (negative [`Self::volume`]) outward by
    /// flipping every triangle; returns whether it did. An open or inconsistently wound mesh has no
    /// orientation to fix and is left as it is. (The test is on the whole mesh: a closed mesh with one
    /// inside-out component among larger outward ones keeps it.)
    pub fn orient_outward(&mut self) -> bool {
        let flip = self.check().is_watertight() && self.volume() < 0.0;
        if flip {
            self.flip();
        }
        flip
    }

    /// Generalised winding number of the mesh about `p`: `Σ Ω_t / 4π` over the triangles' signed solid
    /// angles (Van Oosterom & Strackee 1983, `tan(Ω/2) = a·(b×c) / (|a||b||c| + (a·b)|c| + (b·c)|a| +
    /// (c·a)|b|)` with corners relative to `p`). 1 inside a closed outward mesh, 0 outside, −1 inside an
    /// inside-out one; near ±½ on the surface and fractional for an open mesh.
    pub fn winding_number(&self, p: DVec3) -> f64 {
        let omega: f64 = (0..self.triangles.len())
            .map(|i| {
                let [a, b, c] = self.corners(i).map(|v| v - p);
                let (la, lb, lc) = (a.length(), b.length(), c.length());
                let num = a.dot(b.cross(c));
                let den = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
                2.0 * num.atan2(den)
            })
            .sum();
        omega / (4.0 * std::f64::consts::PI)
    }

    /// Appends another mesh (indices offset; labels kept when both are labelled or padded as Unlabelled).
    pub fn append(&mut self, other: &TriMesh) {
        let off = self.vertices.len() as u32;
        if !self.labels.is_empty() || !other.labels.is_empty() {
            self.labels.resize(self.triangles.len(), 0);
        }
        self.vertices.extend_from_slice(&other.vertices);
        self.triangles.extend(
            other
                .triangles
                .iter()
                .map(|t| [t[0] + off, t[1] + off, t[2] + off]),
        );
        if !self.labels.is_empty() {
            if other.labels.is_empty() {
                self.labels.resize(self.triangles.len(), 0);
            } else {
                self.labels.extend_from_slice(&other.labels);
            }
        }
    }

    /// A mesh of the given triangles (with their original index, for the label) over `vertices`, keeping
    /// only the vertices they use, renumbered in order of first use.
    pub fn compacted(
        name: &str,
        vertices: &[DVec3],
        triangles: impl Iterator<Item = (usize, [u32; 3])>,
        labels: &[u8],
    ) -> TriMesh {
        let mut remap = vec![u32::MAX; vertices.len()];
        let mut out = TriMesh::new(name, Vec::new(), Vec::new());
        for (i, t) in triangles {
            let tri = t.map(|v| {
                if remap[v as usize] == u32::MAX {
                    remap[v as usize] = out.vertices.len() as u32;
                    out.vertices.push(vertices[v as usize]);
                }
                remap[v as usize]
            });
            out.triangles.push(tri);
            if !labels.is_empty() {
                out.labels.push(labels[i]);
            }
        }
        out
    }

    /// The longest chord any ray can have through this mesh is at most its bounding-box diagonal.
    pub fn max_chord(&self) -> f64 {
        self.bounds()
            .map(|(lo, hi)| (hi - lo).length())
            .unwrap_or(0.0)
    }

    /// An axis-aligned box `[lo, hi]` as 12 outward triangles.
    pub fn cuboid(name: &str, lo: DVec3, hi: DVec3) -> TriMesh {
        let v = |x: bool, y: bool, z: bool| {
            DVec3::new(
                if x { hi.x } else { lo.x },
                if y { hi.y } else { lo.y },
                if z { hi.z } else { lo.z },
            )
        };
        let vertices = vec![
            v(false, false, false),
            v(true, false, false),
            v(true, true, false),
            v(false, true, false),
            v(false, false, true),
            v(true, false, true),
            v(true, true, true),
            v(false, true, true),
        ];
        let triangles = vec![
            [0, 2, 1],
            [0, 3, 2], // z = lo (normal −z)
            [4, 5, 6],
            [4, 6, 7], // z = hi
            [0, 1, 5],
            [0, 5, 4], // y = lo
            [3, 7, 6],
            [3, 6, 2], // y = hi
            [0, 4, 7],
            [0, 7, 3], // x = lo
            [1, 2, 6],
            [1, 6, 5], // x = hi
        ];
        TriMesh::new(name, vertices, triangles)
    }

    /// A geodesic sphere: an icosahedron subdivided `levels` times, vertices on the sphere.
    pub fn icosphere(name: &str, centre: DVec3, radius: f64, levels: u32) -> TriMesh {
        let p = (1.0 + 5f64.sqrt()) / 2.0;
        let mut verts: Vec<DVec3> = [
            (-1.0, p, 0.0),
            (1.0, p, 0.0),
            (-1.0, -p, 0.0),
            (1.0, -p, 0.0),
            (0.0, -1.0, p),
            (0.0, 1.0, p),
            (0.0, -1.0, -p),
            (0.0, 1.0, -p),
            (p, 0.0, -1.0),
            (p, 0.0, 1.0),
            (-p, 0.0, -1.0),
            (-p, 0.0, 1.0),
        ]
        .iter()
        .map(|&(x, y, z)| DVec3::new(x, y, z).normalize())
        .collect();
        let mut tris: Vec<[u32; 3]> = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        for _ in 0..levels {
            let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
            let mut next = Vec::with_capacity(tris.len() * 4);
            let mut midpoint = |a: u32, b: u32, verts: &mut Vec<DVec3>| -> u32 {
                *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    verts.push((verts[a as usize] + verts[b as usize]).normalize());
                    verts.len() as u32 - 1
                })
            };
            for [a, b, c] in tris {
                let ab = midpoint(a, b, &mut verts);
                let bc = midpoint(b, c, &mut verts);
                let ca = midpoint(c, a, &mut verts);
                next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
            }
            tris = next;
        }
        let vertices = verts.into_iter().map(|v| centre + v * radius).collect();
        TriMesh::new(name, vertices, tris)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cuboid_is_closed_with_exact_volume() {
        let m = TriMesh::cuboid("b", DVec3::new(-1.0, -2.0, -3.0), DVec3::new(4.0, 5.0, 6.0));
        assert!(m.check().is_watertight());
        assert!((m.volume() - 5.0 * 7.0 * 9.0).abs() < 1e-9);
    }

    #[test]
    fn icosphere_is_closed_and_outward() {
        let m = TriMesh::icosphere("s", DVec3::new(1.0, 2.0, 3.0), 10.0, 4);
        assert!(m.check().is_watertight(), "{:?}", m.check());
        let exact = 4.0 / 3.0 * std::f64::consts::PI * 1000.0;
        assert!(m.volume() > 0.99 * exact && m.volume() < exact);
    }

    #[test]
    fn check_finds_holes_and_flips() {
        let mut m = TriMesh::cuboid("b", DVec3::ZERO, DVec3::ONE);
        m.triangles[0].swap(1, 2);
        assert_eq!(m.check().misoriented_edges, 3);
        m.triangles.pop();
        assert!(m.check().boundary_edges > 0);
    }

    #[test]
    fn inside_out_mesh_is_reoriented_and_winding_numbers_count_it() {
        let outward = TriMesh::cuboid("b", DVec3::splat(-1.0), DVec3::splat(1.0));
        let mut m = outward.clone();
        m.flip();
        assert_eq!(m.winding_number(DVec3::ZERO).round(), -1.0);
        assert!(m.orient_outward());
        assert_eq!(m, outward);
        assert!(!m.orient_outward());
        assert!((m.winding_number(DVec3::new(0.3, -0.2, 0.9)) - 1.0).abs() < 1e-9);
        assert!(m.winding_number(DVec3::new(3.0, 0.0, 0.0)).abs() < 1e-9);
        // Open: no orientation to fix.
        let mut open = outward.clone();
        open.flip();
        open.triangles.pop();
        assert!(!open.orient_outward());
    }
}
