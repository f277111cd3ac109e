//! What a level on the GPU renders its moving images from ([`Source`]): a CT through the CT shader, or
//! meshes through the mesh shader with the host's few pixels scattered in. Either way the images land in
//! the level's ray buffer, view after view, and never come back to the host.

use std::sync::Arc;

use crate::geometry::View;
use crate::render::ThicknessRenderer;
use crate::render::gpu::{GpuContext, GpuCtRenderer};
use crate::{Error, Result};

/// The moving DRR of a level evaluated on the GPU.
pub enum Source<'a> {
    /// A CT: every view in one dispatch of the CT shader, recorded in the level's encoder.
    Ct(&'a GpuCtRenderer),
    /// Meshes on the gpu backend: each view summed by the mesh shader and finished there, the pixels
    /// the sums cannot give evaluated on the host and written into the image on the GPU
    /// (`ThicknessRenderer::line_integral_onto_gpu`); with `summed` false (the sums did not equal the
    /// paired render at the start: a mesh that intersects itself) the CPU's paired render, uploaded.
    Mesh {
        renderer: Arc<ThicknessRenderer>,
        summed: bool,
    },
}

impl Source<'_> {
    /// The device the images are rendered on.
    pub fn context(&self) -> Result<&Arc<GpuContext>> {
        match self {
            Source::Ct(r) => Ok(r.context()),
            Source::Mesh { renderer, .. } => renderer.gpu_context().ok_or_else(|| {
                Error::Internal("a GPU level of meshes without the gpu backend".into())
            }),
        }
    }

    /// Renders `moved` into `raw` from byte 0, view after view. A CT's rays are recorded in `encoder`;
    /// meshes render in submissions of their own (the host finishes a few pixels between the GPU's
    /// passes), so what `encoder` holds so far (which may read `raw`) is submitted first and `encoder`
    /// starts anew.
    pub fn render(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        moved: &[View],
        raw: &wgpu::Buffer,
    ) -> Result<()> {
        match self {
            Source::Ct(r) => r.encode_views(encoder, moved, raw, 0),
            Source::Mesh { renderer, summed } => {
                let pending = std::mem::replace(
                    encoder,
                    ctx.device.create_command_encoder(&Default::default()),
                );
                ctx.checked("submitting a registration level's earlier poses", || {
                    ctx.queue.submit([pending.finish()]);
                })?;
                let mut offset = 0;
                for view in moved {
                    renderer.line_integral_onto_gpu(view, raw, offset, *summed)?;
                    offset +=
                        4 * u64::from(view.intrinsics.width) * u64::from(view.intrinsics.height);
                }
                Ok(())
            }
        }
    }
}
