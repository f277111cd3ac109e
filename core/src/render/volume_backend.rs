//! A CT volume DRR on a backend: the CPU's Siddon or trilinear integral ([`VolumeRenderer`]), or with
//! [`Backend::Gpu`] the same integral in the GPU's compute shader (`gpu::GpuCtRenderer`, within ~1e-5 of
//! the CPU's). The one place that puts a CT renderer on the GPU for the study's CT targets and a CT
//! anatomy's intensity registration.

use super::Backend;
use super::volume::VolumeRenderer;
use crate::Result;
use crate::geometry::View;
use crate::io::ImageF32;

/// A CT renderer and, on the gpu backend, its copy on the GPU (which then renders).
pub struct VolumeOnBackend {
    /// The CPU renderer: its method and details, and what renders without a GPU copy.
    pub cpu: VolumeRenderer,
    #[cfg(feature = "gpu")]
    gpu: Option<super::gpu::GpuCtRenderer>,
}

impl From<VolumeRenderer> for VolumeOnBackend {
    /// The renderer on the CPU.
    fn from(cpu: VolumeRenderer) -> Self {
        VolumeOnBackend {
            cpu,
            #[cfg(feature = "gpu")]
            gpu: None,
        }
    }
}

impl VolumeOnBackend {
    /// `cpu` on `backend`: uploaded to the process's GPU ([`super::gpu::GpuContext::shared`]) for
    /// [`Backend::Gpu`], rendered by the CPU for any other (the caller refuses those that trace meshes
    /// only).
    pub fn new(cpu: VolumeRenderer, backend: Backend) -> Result<Self> {
        if backend != Backend::Gpu {
            return Ok(cpu.into());
        }
        #[cfg(feature = "gpu")]
        {
            let ctx = super::gpu::GpuContext::shared()?;
            let gpu = Some(super::gpu::GpuCtRenderer::new(ctx, &cpu)?);
            Ok(VolumeOnBackend { cpu, gpu })
        }
        #[cfg(not(feature = "gpu"))]
        Err(crate::Error::invalid(
            "backend",
            "gpu: this spinedrr was built without its gpu feature",
        ))
    }

    /// The volume DRR of `view`.
    pub fn render(&self, view: &View) -> Result<ImageF32> {
        #[cfg(feature = "gpu")]
        if let Some(g) = &self.gpu {
            return g.render(view);
        }
        Ok(self.cpu.render(view))
    }

    /// [`Self::render`] into `out` (the CPU renderer reuses its buffer).
    pub fn render_into(&self, view: &View, out: &mut ImageF32) -> Result<()> {
        #[cfg(feature = "gpu")]
        if let Some(g) = &self.gpu {
            *out = g.render(view)?;
            return Ok(());
        }
        self.cpu.render_into(view, out);
        Ok(())
    }

    /// The GPU copy that renders (the gpu backend), else `None`.
    #[cfg(feature = "gpu")]
    pub fn gpu(&self) -> Option<&super::gpu::GpuCtRenderer> {
        self.gpu.as_ref()
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
