//! The compiled `lm.wgsl` (one per device, shared by every registration level through
//! `GpuContext::cached`).

use crate::render::gpu::{UNIFORM, WRITE, buffer_layout, compute_pipeline};

/// The compiled `lm.wgsl` and its bind group layout.
pub(crate) struct LmKernels {
    pub(super) layout: wgpu::BindGroupLayout,
    pub(super) jacobian: wgpu::ComputePipeline,
    pub(super) secant: wgpu::ComputePipeline,
    pub(super) normal: wgpu::ComputePipeline,
}

impl LmKernels {
    pub(super) fn new(device: &wgpu::Device) -> Self {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("lm.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("lm.wgsl").into()),
        });
        let (layout, pl) = buffer_layout(device, "lm", &[UNIFORM, WRITE, WRITE, WRITE, WRITE]);
        let pipe = |e| compute_pipeline(device, &pl, &module, e);
        LmKernels {
            jacobian: pipe("jacobian"),
            secant: pipe("secant"),
            normal: pipe("normal"),
            layout,
        }
    }
}
