//! A CT target's volume DRR on the study's backend: the CPU's Siddon or trilinear integral, or with
//! `geometry.backend = "gpu"` the same integral in the GPU's compute shader (`render::gpu`, within ~1e-5
//! of the CPU's), its adapter named in the reference DRRs' sidecars.

use crate::Result;
use crate::geometry::View;
use crate::io::ImageF32;
use crate::render::Backend;
use crate::render::volume::VolumeRenderer;

/// The volume renderer of a CT target (masked to its labels) and, on the gpu backend, its GPU copy.
pub struct StudyVolume {
    /// The CPU renderer: its method and details, and the intensity registration's moving DRR.
    pub cpu: VolumeRenderer,
    #[cfg(feature = "gpu")]
    gpu: Option<crate::render::gpu::GpuCtRenderer>,
}

impl StudyVolume {
    /// `cpu` on `backend`: uploaded to the GPU for `gpu`, else rendered by the CPU.
    pub fn new(cpu: VolumeRenderer, backend: Backend) -> Result<Self> {
        #[cfg(feature = "gpu")]
        {
            let gpu = match backend {
                Backend::Gpu => {
                    let ctx = crate::render::gpu::GpuContext::shared()?;
                    Some(crate::render::gpu::GpuCtRenderer::new(ctx, &cpu)?)
                }
                _ => None,
            };
            Ok(StudyVolume { cpu, gpu })
        }
        #[cfg(not(feature = "gpu"))]
        {
            if backend == Backend::Gpu {
                return Err(crate::Error::invalid(
                    "geometry.backend",
                    "gpu: this spinedrr was built without its gpu feature",
                ));
            }
            Ok(StudyVolume { cpu })
        }
    }

    /// The volume DRR of `view`.
    pub fn render(&self, view: &View) -> Result<ImageF32> {
        #[cfg(feature = "gpu")]
        if let Some(g) = &self.gpu {
            return g.render(view);
        }
        Ok(self.cpu.render(view))
    }

    /// The GPU adapter the DRRs render on, else `None`.
    pub fn gpu_adapter(&self) -> Option<String> {
        #[cfg(feature = "gpu")]
        if let Some(g) = &self.gpu {
            return Some(g.adapter_name());
        }
        None
    }
}
