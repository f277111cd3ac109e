//! Anatomy: triangle meshes, mesh files, the parametric lumbar phantom and landmarks.

pub mod ct;
pub mod labels;
mod mesh;

pub use mesh::{MeshCheck, Structure, TriMesh};
