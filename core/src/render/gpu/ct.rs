//! CT DRRs in a compute shader (`ct.wgsl`): exact Siddon and trilinear, one invocation per pixel, any
//! number of views of one detector size per dispatch.
//!
//! The μ grid is the CPU renderer's ([`VolumeRenderer`]: HU converted, the mask applied), cut to its clip
//! box (the whole grid, or a label's bounding box: a masked level uploads only its box) and held in an
//! `r32float` 3-D texture read with `textureLoad` (exact voxel values; no sampler, whose filtering would
//! round the weights). A texture rather than a storage buffer because its tiled layout keeps the voxels
//! of a ray's neighbours close whatever the ray's direction, and because a 512² × 133 CT (139 MB of f32)
//! is over the 128 MiB storage binding that WebGPU guarantees, while a 3-D texture up to 2048 voxels a
//! side is within its defaults.
//!
//! The ray of pixel (u, v) is the CPU renderer's: from the source through the pixel centre, its direction
//! normalised in world millimetres and mapped to index space by the CT's affine. The shader works in f32
//! (WGSL has none wider); how it keeps the error near f32's resolution is written at the top of
//! `ct.wgsl`, and the tests hold it to the CPU's f64 renderer (1e-5 relative).

use std::sync::{Arc, Mutex, PoisonError};

use bytemuck::{Pod, Zeroable};
use glam::{DMat3, DVec3};

use super::{
    GpuContext, buffer_binding, compute_entry, compute_pipeline, storage_init, uniform_init,
};
use crate::geometry::View;
use crate::io::ImageF32;
use crate::render::volume::{VolumeDetails, VolumeMethod, VolumeRenderer, footprint};
use crate::{Error, Result};

/// One view's rays (`View` in ct.wgsl): rows of `Rᵀ K⁻¹`; rows of its index-space image `Mi` and of the
/// pixel → mid-plane point map `A`, each split hi + lo ([`split`]); the box centre's depth.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ViewRays {
    mw: [[f32; 4]; 3],
    mi_hi: [[f32; 4]; 3],
    mi_lo: [[f32; 4]; 3],
    a_hi: [[f32; 4]; 3],
    a_lo: [[f32; 4]; 3],
    depth: [f32; 4],
}

/// `v` as `hi + lo` in f32: `hi` keeps 12 significant bits, so its product with a whole number below
/// 4096 (a pixel coordinate) is exact in f32, and `lo` the next 24 (ct.wgsl's `dot_df`).
fn split(v: f64) -> (f32, f32) {
    let hi = f32::from_bits((v as f32).to_bits() & !0xfff);
    (hi, (v - f64::from(hi)) as f32)
}

/// `Globals` in ct.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Globals {
    dims: [u32; 4],
    /// Width, height, and a 0 the shader's `opaque` needs to be a run-time value.
    image: [u32; 4],
    /// First column and row, width and height of the pixels traced.
    window: [u32; 4],
    h_max: [f32; 4],
}

/// Pixels per workgroup side (`@workgroup_size(8, 8, 1)` in ct.wgsl).
const WORKGROUP: u32 = 8;

/// A CT prepared on the GPU: its clip box's μ in a 3-D texture and the compute pipeline of its method.
pub struct GpuCtRenderer {
    ctx: Arc<GpuContext>,
    method: VolumeMethod,
    details: VolumeDetails,
    /// The clip box: its first voxel in the CT's grid and its size.
    lo: [usize; 3],
    dims: [u32; 3],
    world_to_index: glam::DMat4,
    step_mm: f64,
    volume: wgpu::TextureView,
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    /// The last render's output and read-back buffers, reused by the next render of the same size (a
    /// registration or `--repeat` renders one size again and again); held for the whole render, so
    /// renders from several threads take turns, as they would on the one queue.
    buffers: Mutex<Option<OutBuffers>>,
}

/// A render's output (storage) and read-back (mappable) buffers, `bytes` long each.
struct OutBuffers {
    bytes: u64,
    out: wgpu::Buffer,
    staging: wgpu::Buffer,
}

impl std::fmt::Debug for GpuCtRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuCtRenderer")
            .field("method", &self.method)
            .field("box", &self.dims)
            .field("adapter", &self.ctx.adapter_name())
            .finish()
    }
}

impl GpuCtRenderer {
    /// Uploads `cpu`'s μ (its clip box) and compiles the shader of its method.
    pub fn new(ctx: Arc<GpuContext>, cpu: &VolumeRenderer) -> Result<GpuCtRenderer> {
        let (lo, hi) = (cpu.lo, cpu.hi);
        let size = [0, 1, 2].map(|a| hi[a] + 1 - lo[a]);
        let edge = ctx.max_texture_3d() as usize;
        if let Some(a) = (0..3).find(|&a| size[a] > edge) {
            return Err(Error::invalid(
                "ct",
                format!(
                    "the CT's {} voxels along axis {a} are more than the {edge} a 3-D texture of GPU \
                     adapter {} may hold: render it with the CPU backend, or crop it",
                    size[a],
                    ctx.adapter_name()
                ),
            ));
        }
        // The clip box's μ, x fastest.
        let [nx, ny, _] = cpu.dims;
        let mut boxed = Vec::with_capacity(size.iter().product());
        for k in lo[2]..=hi[2] {
            for j in lo[1]..=hi[1] {
                let row = lo[0] + nx * (j + ny * k);
                boxed.extend_from_slice(&cpu.mu[row..row + size[0]]);
            }
        }
        let dims = size.map(|n| n as u32);
        let extent = wgpu::Extent3d {
            width: dims[0],
            height: dims[1],
            depth_or_array_layers: dims[2],
        };
        let method = cpu.method();
        let device = &ctx.device;
        let (volume, layout, pipeline) =
            ctx.checked("uploading the CT and compiling its shader", || {
                let texture = device.create_texture(&wgpu::TextureDescriptor {
                    label: Some("ct μ"),
                    size: extent,
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D3,
                    format: wgpu::TextureFormat::R32Float,
                    usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                    view_formats: &[],
                });
                ctx.queue.write_texture(
                    wgpu::TexelCopyTextureInfo {
                        texture: &texture,
                        mip_level: 0,
                        origin: wgpu::Origin3d::ZERO,
                        aspect: wgpu::TextureAspect::All,
                    },
                    bytemuck::cast_slice(&boxed),
                    wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(4 * dims[0]),
                        rows_per_image: Some(dims[1]),
                    },
                    extent,
                );
                let volume = texture.create_view(&wgpu::TextureViewDescriptor::default());
                let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some("ct.wgsl"),
                    source: wgpu::ShaderSource::Wgsl(include_str!("ct.wgsl").into()),
                });
                let (entry, buffer) = (compute_entry, buffer_binding);
                let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some("ct"),
                    entries: &[
                        entry(0, buffer(wgpu::BufferBindingType::Uniform)),
                        entry(
                            1,
                            buffer(wgpu::BufferBindingType::Storage { read_only: true }),
                        ),
                        entry(
                            2,
                            wgpu::BindingType::Texture {
                                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                                view_dimension: wgpu::TextureViewDimension::D3,
                                multisampled: false,
                            },
                        ),
                        entry(
                            3,
                            buffer(wgpu::BufferBindingType::Storage { read_only: false }),
                        ),
                    ],
                });
                let pipeline_layout =
                    device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                        label: Some("ct"),
                        bind_group_layouts: &[Some(&layout)],
                        immediate_size: 0,
                    });
                let entry_point = match method {
                    VolumeMethod::Siddon => "siddon",
                    VolumeMethod::Trilinear => "trilinear",
                };
                let pipeline = compute_pipeline(device, &pipeline_layout, &module, entry_point);
                (volume, layout, pipeline)
            })?;
        Ok(GpuCtRenderer {
            details: cpu.details(),
            ctx,
            method,
            lo,
            dims,
            world_to_index: cpu.world_to_index,
            step_mm: cpu.step_mm(),
            volume,
            layout,
            pipeline,
            buffers: Mutex::new(None),
        })
    }

    /// The sidecar record: the CPU renderer's, with the same method, μ_water and step.
    pub fn details(&self) -> VolumeDetails {
        self.details.clone()
    }

    /// The adapter the renders run on.
    pub fn adapter_name(&self) -> String {
        self.ctx.adapter_name()
    }

    /// The DRR of `view` (see [`VolumeRenderer::render`]: the same rays, the same integral).
    pub fn render(&self, view: &View) -> Result<ImageF32> {
        let mut images = self.render_views(std::slice::from_ref(view))?;
        Ok(images.remove(0))
    }

    /// The DRRs of `views`, which must share one detector size, in one dispatch.
    pub fn render_views(&self, views: &[View]) -> Result<Vec<ImageF32>> {
        let Some(first) = views.first() else {
            return Ok(Vec::new());
        };
        let (w, h) = (first.intrinsics.width, first.intrinsics.height);
        let pixels = u64::from(w) * u64::from(h);
        let out_bytes = 4 * pixels * views.len() as u64;
        let device = &self.ctx.device;
        let mut slot = self.buffers.lock().unwrap_or_else(PoisonError::into_inner);
        if slot.as_ref().is_some_and(|b| b.bytes != out_bytes) {
            *slot = None;
        }
        let bufs =
            match &mut *slot {
                Some(b) => b,
                empty => empty.insert(self.ctx.checked("allocating the DRRs' buffers", || {
                    OutBuffers {
                        bytes: out_bytes,
                        out: device.create_buffer(&wgpu::BufferDescriptor {
                            label: Some("ct DRRs"),
                            size: out_bytes,
                            usage: wgpu::BufferUsages::STORAGE
                                | wgpu::BufferUsages::COPY_SRC
                                | wgpu::BufferUsages::COPY_DST,
                            mapped_at_creation: false,
                        }),
                        staging: device.create_buffer(&wgpu::BufferDescriptor {
                            label: Some("ct DRRs read back"),
                            size: out_bytes,
                            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                            mapped_at_creation: false,
                        }),
                    }
                })?),
            };
        let (out, staging) = (&bufs.out, &bufs.staging);
        let mut encoder = device.create_command_encoder(&Default::default());
        self.encode_views(&mut encoder, views, out, 0)?;
        self.ctx.checked("rendering CT DRRs", || {
            encoder.copy_buffer_to_buffer(out, 0, staging, 0, out_bytes);
            self.ctx.queue.submit([encoder.finish()]);
        })?;
        let data = self.ctx.read_back::<f32>(staging, "the CT DRRs");
        if data.is_err() {
            // A buffer left mapped (or lost with the device) is not reused.
            *slot = None;
        }
        let data = data?;
        Ok(data
            .chunks_exact(pixels as usize)
            .map(|c| ImageF32 {
                width: w,
                height: h,
                data: c.to_vec(),
            })
            .collect())
    }

    /// Records into `encoder` the DRRs of `views` (one detector size) into `out` from byte `offset` (a
    /// multiple of 256; 4 bytes per pixel per view from there, view `k`'s pixels, rows first, from pixel
    /// `k·w·h`), nothing read back: the registration loop's renders and a spectral DRR's channels stay
    /// on the GPU.
    pub(crate) fn encode_views(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        views: &[View],
        out: &wgpu::Buffer,
        offset: u64,
    ) -> Result<()> {
        let Some(first) = views.first() else {
            return Ok(());
        };
        let (w, h) = (first.intrinsics.width, first.intrinsics.height);
        if let Some(v) = views
            .iter()
            .find(|v| (v.intrinsics.width, v.intrinsics.height) != (w, h))
        {
            return Err(Error::invalid(
                "views",
                format!(
                    "view '{}' is {}×{} px and view '{}' {w}×{h}: one GPU dispatch renders views of one \
                     detector size",
                    v.name, v.intrinsics.width, v.intrinsics.height, first.name
                ),
            ));
        }
        let n = views.len() as u32;
        let out_bytes = 4 * u64::from(w) * u64::from(h) * u64::from(n);
        // Only the pixels whose rays can meet the box are traced (as on the CPU): the union of the views'
        // footprints; a masked level's box covers a small part of the detector.
        let hi = [0, 1, 2].map(|a| self.lo[a] + self.dims[a] as usize - 1);
        let window = views
            .iter()
            .filter_map(|v| footprint(&self.world_to_index, self.lo, hi, v))
            .reduce(|a, b| (a.0.min(b.0), a.1.max(b.1), a.2.min(b.2), a.3.max(b.3)));
        let Some((u0, u1, v0, v1)) = window else {
            encoder.clear_buffer(out, offset, Some(out_bytes));
            return Ok(());
        };
        let window = [u0, v0, u1 + 1 - u0, v1 + 1 - v0].map(|x| x as u32);
        let groups = [
            window[2].div_ceil(WORKGROUP),
            window[3].div_ceil(WORKGROUP),
            n,
        ];
        let max_groups = self.ctx.max_workgroups();
        if out_bytes > self.ctx.max_storage_binding()
            || offset + out_bytes > out.size()
            || groups.iter().any(|&g| g > max_groups)
        {
            return Err(Error::invalid(
                "views",
                format!(
                    "{n} view(s) of {w}×{h} px are more than one dispatch of GPU adapter {} takes \
                     ({} bytes of output at most, {max_groups} workgroups a side): render fewer views at \
                     a time",
                    self.ctx.adapter_name(),
                    self.ctx
                        .max_storage_binding()
                        .min(out.size().saturating_sub(offset))
                ),
            ));
        }
        let rays: Vec<ViewRays> = views.iter().map(|v| self.view_rays(v)).collect();
        let globals = Globals {
            dims: [self.dims[0], self.dims[1], self.dims[2], n],
            image: [w, h, 0, 0],
            window,
            h_max: [self.step_mm as f32, 0.0, 0.0, 0.0],
        };
        let device = &self.ctx.device;
        self.ctx.checked("rendering CT DRRs", || {
            let uniform = uniform_init(device, "ct globals", bytemuck::bytes_of(&globals));
            let view_buffer = storage_init(device, "ct views", bytemuck::cast_slice(&rays));
            let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("ct"),
                layout: &self.layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: uniform.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: view_buffer.as_entire_binding(),
                    },
                    wgpu::BindGroupEntry {
                        binding: 2,
                        resource: wgpu::BindingResource::TextureView(&self.volume),
                    },
                    wgpu::BindGroupEntry {
                        binding: 3,
                        resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                            buffer: out,
                            offset,
                            size: wgpu::BufferSize::new(out_bytes),
                        }),
                    },
                ],
            });
            // The pixels outside the footprint stay 0 (a reused buffer holds the last render).
            encoder.clear_buffer(out, offset, Some(out_bytes));
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &bind, &[]);
            pass.dispatch_workgroups(groups[0], groups[1], groups[2]);
        })
    }

    /// The context the renderer's buffers live in.
    pub(crate) fn context(&self) -> &Arc<GpuContext> {
        &self.ctx
    }

    /// The shader's description of `view`'s rays in the clip box's index coordinates. The ray of pixel
    /// p = (u, v, 1) meets the plane through the box centre C parallel to the detector (camera depth
    /// z_c) at world point S + z_c·Rᵀ K⁻¹ p (K⁻¹ p has depth 1), so in box index coordinates at
    /// A·p = W·S − lo + z_c·Mi·p: affine in p. The source's large coordinates cancel here, in f64.
    fn view_rays(&self, view: &View) -> ViewRays {
        let mw = view.pixel_to_world_dir();
        let mi = DMat3::from_mat4(self.world_to_index) * mw;
        let lo = DVec3::from_array(self.lo.map(|v| v as f64));
        let size = DVec3::from_array(self.dims.map(f64::from));
        let centre = self
            .world_to_index
            .inverse()
            .transform_point3(lo + 0.5 * (size - 1.0));
        let z_c = view.depth(centre);
        let src = self.world_to_index.transform_point3(view.source_world()) - lo;
        let mut a = mi * z_c;
        a.z_axis += src;
        // Rows of `m`, each entry mapped by `part`.
        let rows = |m: DMat3, part: &dyn Fn(f64) -> f32| {
            [0, 1, 2].map(|r| {
                let row = m.row(r);
                [part(row.x), part(row.y), part(row.z), 0.0]
            })
        };
        let (hi, lo) = (|v| split(v).0, |v| split(v).1);
        ViewRays {
            mw: rows(mw, &|v| v as f32),
            mi_hi: rows(mi, &hi),
            mi_lo: rows(mi, &lo),
            a_hi: rows(a, &hi),
            a_lo: rows(a, &lo),
            depth: [z_c as f32, 0.0, 0.0, 0.0],
        }
    }
}
