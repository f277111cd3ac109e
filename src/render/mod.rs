//! Rendering: thickness DRRs of triangle meshes (Embree, the raster or the pure-Rust BVH) and CT volume
//! DRRs.
//!
//! `scene` owns what is rendered (meshes, μ, objects), `tracer` the ray-tracing backend interface, `embree`
//! and `bvh` the two ray tracers, `raster` the rasteriser of primary rays, `pairing` how a ray's hits become
//! a path length, `thickness` the image loop, `volume` the CT renderer (Siddon and trilinear).

pub mod bvh;
pub mod embree;
mod pairing;
mod phantom_scene;
mod raster;
mod scene;
mod thickness;
mod tracer;
pub mod volume;

pub use phantom_scene::{MU_WATER_PER_MM, mu_from_hu, phantom_scene, tissue_mu};
pub use scene::{MAX_OBJECTS, RenderScene, SceneMesh};
pub use thickness::{RenderStats, TILE, ThicknessDrr, ThicknessOptions, ThicknessRenderer};
pub use tracer::{HitTracer, PACKET, RawHit, RayPacket};

use crate::Result;

/// The ray-tracing backend of a thickness render.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// Intel Embree (system library), all hits gathered in one traversal.
    Embree,
    /// The pure-Rust f64 BVH with a watertight triangle test (reference).
    Bvh,
    /// Rasterised primary rays (all rays leave the source): exact edge functions, no acceleration
    /// structure; the fastest for DRRs. A view with a vertex at or behind the source plane is traced
    /// with Embree instead.
    Raster,
}

impl Backend {
    /// Builds a renderer for `scene` with this backend.
    pub fn renderer(self, scene: RenderScene) -> Result<ThicknessRenderer> {
        let tracer: Box<dyn HitTracer> = match self {
            Backend::Embree => Box::new(embree::EmbreeTracer::new(&scene)?),
            Backend::Bvh => Box::new(bvh::BvhTracer::new(&scene)),
            Backend::Raster => return Ok(ThicknessRenderer::raster(scene)),
        };
        Ok(ThicknessRenderer::new(scene, tracer))
    }
}
