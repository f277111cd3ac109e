//! What a renderer sees: meshes with attenuation coefficients, grouped into named objects.

use std::sync::Arc;

use glam::DVec3;

use crate::anatomy::TriMesh;
use crate::{Error, Result};

/// Most objects a render can keep separate silhouettes for (one bit each).
pub const MAX_OBJECTS: usize = 64;

/// At most this many meshes in one scene (a ray's crossings name their mesh in 16 bits).
pub const MAX_MESHES: usize = u16::MAX as usize + 1;

/// A closed surface with linear attenuation `mu_per_mm`. Nested surfaces use differential μ: a cancellous
/// core inside a cortical shell gets `μ_cancellous − μ_cortical`.
#[derive(Debug, Clone)]
pub struct SceneMesh {
    pub mesh: Arc<TriMesh>,
    pub mu_per_mm: f64,
    /// The object (e.g. vertebra level) this surface belongs to, for silhouettes.
    pub object: String,
}

/// The plane of a triangle, `n · x = d` with unit outward `n`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Plane {
    pub n: DVec3,
    pub d: f64,
}

/// Meshes plus the per-triangle data every backend shares.
#[derive(Debug, Clone)]
pub struct RenderScene {
    pub meshes: Vec<SceneMesh>,
    pub objects: Vec<String>,
    pub(crate) object_of_mesh: Vec<usize>,
    pub(crate) planes: Vec<Vec<Plane>>,
    /// Longest possible chord through each mesh (bounding-box diagonal, mm).
    pub(crate) max_chord: Vec<f64>,
    /// Meshes that are not closed (rendered anyway; thickness may be wrong near holes).
    pub open_meshes: Vec<String>,
    /// Per mesh: an implant, which displaces every other mesh where it is (empty: none is).
    pub(crate) implants: Vec<bool>,
}

impl RenderScene {
    /// Validates the meshes and precomputes triangle planes.
    pub fn new(meshes: Vec<SceneMesh>) -> Result<Self> {
        if meshes.is_empty() {
            return Err(Error::invalid("scene", "no meshes to render"));
        }
        if meshes.len() > MAX_MESHES {
            return Err(Error::invalid(
                "scene",
                format!(
                    "{} meshes; at most {MAX_MESHES} can be rendered together",
                    meshes.len()
                ),
            ));
        }
        let mut objects: Vec<String> = Vec::new();
        let mut object_of_mesh = Vec::with_capacity(meshes.len());
        let mut planes = Vec::with_capacity(meshes.len());
        let mut max_chord = Vec::with_capacity(meshes.len());
        let mut open_meshes = Vec::new();
        for m in &meshes {
            m.mesh.validate(&format!("mesh '{}'", m.mesh.name))?;
            if !m.mu_per_mm.is_finite() {
                return Err(Error::invalid(
                    format!("mu of mesh '{}'", m.mesh.name),
                    "must be finite",
                ));
            }
            if !m.mesh.check().is_watertight() {
                open_meshes.push(m.mesh.name.clone());
            }
            let idx = match objects.iter().position(|o| *o == m.object) {
                Some(i) => i,
                None => {
                    objects.push(m.object.clone());
                    objects.len() - 1
                }
            };
            object_of_mesh.push(idx);
            planes.push(
                (0..m.mesh.triangles.len())
                    .map(|i| {
                        let [a, b, c] = m.mesh.corners(i);
                        let n = (b - a).cross(c - a).normalize_or_zero();
                        Plane { n, d: n.dot(a) }
                    })
                    .collect(),
            );
            max_chord.push(m.mesh.max_chord());
        }
        if objects.len() > MAX_OBJECTS {
            return Err(Error::invalid(
                "scene",
                format!(
                    "{} objects; at most {MAX_OBJECTS} can be told apart in silhouettes",
                    objects.len()
                ),
            ));
        }
        Ok(RenderScene {
            meshes,
            objects,
            object_of_mesh,
            planes,
            max_chord,
            open_meshes,
            implants: Vec::new(),
        })
    }

    /// The same scene with `implants[i]` marking mesh `i` as an implant: along every ray, the length of
    /// every other mesh inside any implant is not counted (the implant displaces what it occupies), so an
    /// implant's own μ is absolute, not differential.
    pub fn with_implants(mut self, implants: Vec<bool>) -> Result<Self> {
        if implants.len() != self.meshes.len() {
            return Err(Error::invalid(
                "implants",
                format!("{} flags for {} meshes", implants.len(), self.meshes.len()),
            ));
        }
        self.implants = if implants.iter().any(|&b| b) {
            implants
        } else {
            Vec::new()
        };
        Ok(self)
    }

    /// Whether any mesh is an implant.
    pub fn has_implants(&self) -> bool {
        !self.implants.is_empty()
    }

    /// Total triangle count.
    pub fn triangle_count(&self) -> usize {
        self.meshes.iter().map(|m| m.mesh.triangles.len()).sum()
    }

    /// One warning per mesh that is not closed and consistently wound, saying which it is (what
    /// `render` and `study` print).
    pub fn open_mesh_warnings(&self) -> Vec<String> {
        self.meshes
            .iter()
            .filter(|m| self.open_meshes.contains(&m.mesh.name))
            .map(|m| {
                let c = m.mesh.check();
                format!(
                    "mesh '{}' is not closed or not consistently wound ({} boundary edges, {} edges \
                     shared by more than two triangles, {} edges wound the same way by both triangles); \
                     path lengths near those edges are unreliable",
                    m.mesh.name, c.boundary_edges, c.nonmanifold_edges, c.misoriented_edges
                )
            })
            .collect()
    }

    /// Axis-aligned bounds of all meshes.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        self.meshes.iter().filter_map(|m| m.mesh.bounds()).fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), (a, b)| (lo.min(a), hi.max(b)),
        )
    }
}

/// Makes a closed, consistently wound mesh that is inside out face outward ([`TriMesh::orient_outward`]);
/// returns the warning to show when it did (`what` names the mesh, e.g. its file).
pub fn orient_outward_warning(mesh: &mut TriMesh, what: &str) -> Option<String> {
    let volume = mesh.volume();
    mesh.orient_outward().then(|| {
        format!(
            "mesh {what} is inside out (closed, consistently wound, signed volume {volume:.1} mm³ < 0): \
             its triangles were flipped to face outward"
        )
    })
}
