//! Rendering: thickness DRRs of triangle meshes (Embree, the raster or the pure-Rust BVH) and CT volume
//! DRRs.
//!
//! `scene` owns what is rendered (meshes, μ, objects), `backend` which backend finds the rays' hits,
//! `tracer` the ray-tracing backend interface, `embree` and `bvh` the two ray tracers, `raster` the
//! rasteriser of primary rays, `pairing` how a ray's hits become a path length, `thickness` the image loop,
//! `phantom_scene` the phantom's meshes with μ from HU (or materials, for `spectral`), `spectral` the
//! polychromatic DRR of meshes (per-material path lengths, then the energy sum), `spectral_ct` that of a
//! CT (per-material Siddon renders), `volume` the CT renderer (Siddon and trilinear), `volume_backend` a CT renderer on the CPU or the GPU, `gpu` CT DRRs
//! and mesh signed-depth sums in compute shaders (wgpu; the `gpu` feature, on by default).

mod backend;
pub mod bvh;
pub mod embree;
#[cfg(feature = "gpu")]
pub mod gpu;
mod pairing;
mod phantom_scene;
mod raster;
mod scene;
mod spectral;
mod spectral_ct;
mod thickness;
mod tracer;
pub mod volume;
mod volume_backend;

pub use backend::Backend;
pub use phantom_scene::{
    ImplantMeshes, add_pedicle_screws, add_screws, pedicle_screws, phantom_scene,
    phantom_spectral_scene, planned_screw_implants, screw_implants,
};
pub use scene::{MAX_OBJECTS, RenderScene, SceneMesh, orient_outward_warning};
pub use spectral::{
    SpectralDrr, SpectralInput, SpectralMesh, SpectralRenderer, SpectralScene, displace_nested,
    energy_sum,
};
pub use spectral_ct::{SpectralCtRenderer, moved_implants};
pub use thickness::{
    Masks, RenderStats, ThicknessDetails, ThicknessDrr, ThicknessOptions, ThicknessRenderer,
};
pub use tracer::{HitTracer, PACKET, RawHit, RayPacket};
pub use volume_backend::VolumeOnBackend;
