//! Anatomy: triangle meshes, mesh files, the parametric lumbar phantom and landmarks.

pub mod auto_landmarks;
pub mod ct;
pub mod decimate;
pub mod isosurface;
pub mod labels;
pub mod landmarks;
mod level;
pub mod markups;
mod mesh;
pub mod meshio;
pub mod morphometry;
pub mod morphometry_realism;
pub mod phantom;
pub mod phantom_cache;
pub mod screw;
pub mod sdf;
pub mod structure_split;
pub mod synthetic_ct;
mod tissue;
pub mod vertebra;

pub use auto_landmarks::auto_landmarks;
pub use decimate::{decimate, decimate_to_error};
pub use isosurface::{
    Inside, MAX_GRID_SAMPLES, ScalarGrid, check_grid_size, extract_isosurface,
    extract_isosurface_with,
};
pub use landmarks::Landmarks;
pub use markups::{read_landmarks, read_landmarks_with, write_landmarks};
pub use mesh::{MeshCheck, Structure, TriMesh};
pub use meshio::{MeshFormat, parse_mesh, read_mesh, write_mesh, write_mesh_as};
pub use morphometry::{Morphometry, MorphometryTable, ShapeParams};
pub use phantom::{
    Phantom, PhantomOptions, Tissue, VertebraModel, build_phantom, build_phantom_with,
};
pub use phantom_cache::MeshCache;
pub use tissue::{MU_WATER_PER_MM, mu_from_hu, tissue_hu, tissue_mu};
pub use vertebra::{Level, VertebraShape, parse_levels};
