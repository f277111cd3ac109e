//! The host's pixel values written into an image that stays on the GPU (`scatter.wgsl`): a mesh DRR
//! rendered for a registration level on the GPU comes back only as its list of host pixels, whose values
//! the host computes and sends up again (see [`super::GpuMeshRenderer::rasterise_onto`]).

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};

use super::{GpuContext, READ, UNIFORM, WRITE, bind_buffers, buffer_layout, compute_pipeline};
use crate::{Error, Result};

/// Invocations per workgroup (`@workgroup_size(64, 1, 1)` in scatter.wgsl).
const WORKGROUP: u32 = 64;

/// `Params` in scatter.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    p: [u32; 4],
}

/// The compiled shader (one per device: [`GpuContext::cached`]).
struct Kernel {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
}

/// Writes `values` ((pixel index, value) pairs) into the f32 image that starts at byte `offset` of
/// `image` (a multiple of 4), after whatever the queue holds, and submits it.
pub(crate) fn scatter(
    ctx: &Arc<GpuContext>,
    image: &wgpu::Buffer,
    offset: u64,
    values: &[(u32, f32)],
) -> Result<()> {
    if values.is_empty() {
        return Ok(());
    }
    if !offset.is_multiple_of(4) || offset / 4 > u64::from(u32::MAX) {
        return Err(Error::Internal(format!(
            "scatter into an image at byte {offset}"
        )));
    }
    let kernel = ctx.cached("the host pixels' scatter shader", |device| {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("scatter.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("scatter.wgsl").into()),
        });
        let (layout, pl) = buffer_layout(device, "scatter", &[UNIFORM, READ, WRITE]);
        Kernel {
            pipeline: compute_pipeline(device, &pl, &module, "scatter"),
            layout,
        }
    })?;
    let n = values.len() as u32;
    let groups = n.div_ceil(WORKGROUP);
    let x = groups.min(ctx.max_workgroups());
    let grid = [x, groups.div_ceil(x)];
    let pairs: Vec<[u32; 2]> = values.iter().map(|&(i, v)| [i, v.to_bits()]).collect();
    let params = Params {
        p: [(offset / 4) as u32, n, x * WORKGROUP, 0],
    };
    let device = &ctx.device;
    ctx.checked("writing the host's pixels into a GPU image", || {
        let uniform = super::uniform_init(device, "scatter params", bytemuck::bytes_of(&params));
        let pixels = super::storage_init(device, "host pixels", bytemuck::cast_slice(&pairs));
        let bind = bind_buffers(
            device,
            "scatter",
            &kernel.layout,
            &[&uniform, &pixels, image],
        );
        let mut encoder = device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&kernel.pipeline);
            pass.set_bind_group(0, &bind, &[]);
            pass.dispatch_workgroups(grid[0], grid[1], 1);
        }
        ctx.queue.submit([encoder.finish()]);
    })
}
