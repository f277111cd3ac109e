//! The one place a thickness renderer's ray-finding backend is chosen, including the tracer a
//! rasterising renderer falls back to.

use super::bvh::BvhTracer;
use super::embree::EmbreeTracer;
use super::scene::RenderScene;
use super::thickness::ThicknessRenderer;
use super::tracer::HitTracer;
use crate::{Error, Result};

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
    /// Compute shaders through wgpu (Vulkan, Metal, DX12; Mesa's lavapipe where there is no GPU): CT
    /// DRRs (`render --ct`), and mesh DRRs as the raster's signed-depth sums (closed meshes only, no
    /// implants; a mesh that intersects itself counts twice where it overlaps), the few pixels a sum
    /// cannot give (unbalanced, near an edge) evaluated with the raster's edge functions on the CPU.
    Gpu,
}

impl Backend {
    /// The backend named `name` as `--backend` and the study's `backend` key spell it (`raster`,
    /// `embree`, `bvh`, `gpu`).
    pub fn parse(name: &str) -> Result<Backend> {
        use clap::ValueEnum;
        Backend::from_str(name, false).map_err(|_| {
            let accepted: Vec<String> = Backend::value_variants()
                .iter()
                .filter_map(|b| b.to_possible_value().map(|v| v.get_name().to_string()))
                .collect();
            Error::invalid(
                "backend",
                format!(
                    "unknown backend '{name}' (accepted: {})",
                    accepted.join(", ")
                ),
            )
        })
    }

    /// The backend's name as `--backend` spells it.
    pub fn name(self) -> String {
        use clap::ValueEnum;
        self.to_possible_value()
            .map_or_else(|| format!("{self:?}"), |v| v.get_name().to_string())
    }

    /// Builds a renderer for `scene` with this backend.
    pub fn renderer(self, scene: RenderScene) -> Result<ThicknessRenderer> {
        let tracer: Box<dyn HitTracer> = match self {
            Backend::Embree => Box::new(EmbreeTracer::new(&scene)?),
            Backend::Bvh => Box::new(BvhTracer::new(&scene)),
            Backend::Raster => return Ok(ThicknessRenderer::raster(scene, raster_fallback)),
            Backend::Gpu => return gpu_renderer(scene),
        };
        Ok(ThicknessRenderer::new(scene, tracer))
    }
}

/// What the raster traces when it cannot rasterise (single rays, views with a vertex at or behind the
/// source plane): Embree, or the reference BVH if Embree cannot take the scene.
fn raster_fallback(scene: &RenderScene) -> Box<dyn HitTracer> {
    match EmbreeTracer::new(scene) {
        Ok(embree) => Box::new(embree),
        Err(_) => Box::new(BvhTracer::new(scene)),
    }
}

/// A gpu-backend renderer of `scene`: refused for open meshes, whose signed sums mean nothing. An
/// implant's pixels (pairing cuts it out of the bone it displaces; a sum cannot) are paired on the host.
#[cfg(feature = "gpu")]
fn gpu_renderer(scene: RenderScene) -> Result<ThicknessRenderer> {
    use super::gpu::{GpuContext, GpuMeshRenderer};
    use super::thickness::GpuRaster;
    if let Some(open) = scene.open_meshes.first() {
        return Err(Error::invalid(
            "backend",
            format!(
                "gpu sums signed depths, which needs closed meshes, and mesh '{open}' is open (or \
                 not consistently wound): render it with raster, embree or bvh, which pair crossings"
            ),
        ));
    }
    let gpu = GpuMeshRenderer::new(GpuContext::shared()?, &scene)?;
    Ok(ThicknessRenderer::gpu(
        scene,
        GpuRaster(gpu),
        raster_fallback,
    ))
}

#[cfg(not(feature = "gpu"))]
fn gpu_renderer(_: RenderScene) -> Result<ThicknessRenderer> {
    Err(Error::invalid(
        "backend",
        "gpu: this spinedrr was built without the gpu feature (cargo build --features gpu)",
    ))
}
