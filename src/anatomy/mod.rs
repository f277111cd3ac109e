//! Anatomy: triangle meshes, mesh files, the parametric lumbar phantom and landmarks.

mod mesh;

pub use mesh::{MeshCheck, Structure, TriMesh};
