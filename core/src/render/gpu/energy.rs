//! A spectral DRR's energy sum on the GPU (`energy.wgsl`): the CPU kernel's log-sum-exp
//! ([`crate::spectral::EnergyKernel`]) per pixel. A CT's channels are rendered by their
//! [`GpuCtRenderer`]s into its buffer, so one f32 per pixel comes back instead of one per channel and the
//! host does no per-pixel work; a mesh DRR's channels, finished on the host, are uploaded to it.

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Instant;

use bytemuck::{Pod, Zeroable};

use super::{
    GpuContext, GpuCtRenderer, UNIFORM, WRITE, bind_buffers, buffer, buffer_layout,
    compute_pipeline, storage_init, uniform_init,
};
use crate::geometry::View;
use crate::io::ImageF32;
use crate::spectral::EnergyKernel;
use crate::{Error, Result};

/// `Params` in energy.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    /// Pixels, channels, padded bins, the channel stride in the maps (values).
    counts: [u32; 4],
}

/// The energy kernel's tables on the GPU and the shader that sums them.
pub struct GpuEnergySum {
    ctx: Arc<GpuContext>,
    channels: usize,
    padded: usize,
    table: wgpu::Buffer,
    neg_log_w: wgpu::Buffer,
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    /// The maps, output and read-back buffers of the last render's size, reused.
    buffers: Mutex<Option<Buffers>>,
}

struct Buffers {
    pixels: u64,
    /// Values from one channel's map to the next's (a multiple of 64).
    stride: u64,
    maps: wgpu::Buffer,
    out: wgpu::Buffer,
    staging: wgpu::Buffer,
}

/// A finished spectral DRR and the times of its two steps (ms).
pub struct GpuSpectralDrr {
    pub line_integral: ImageF32,
    pub channels_ms: f64,
    pub energy_sum_ms: f64,
}

impl GpuEnergySum {
    /// Uploads `kernel`'s tables and compiles the shader.
    pub fn new(ctx: Arc<GpuContext>, kernel: &EnergyKernel) -> Result<Self> {
        let (channels, padded, table, neg_log_w) = kernel.layout();
        let device = &ctx.device;
        let (table, neg_log_w, layout, pipeline) = ctx.checked(
            "uploading the energy kernel and compiling its shader",
            || {
                let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some("energy.wgsl"),
                    source: wgpu::ShaderSource::Wgsl(include_str!("energy.wgsl").into()),
                });
                let (layout, pl) =
                    buffer_layout(device, "energy sum", &[UNIFORM, WRITE, WRITE, WRITE, WRITE]);
                let pipeline = compute_pipeline(device, &pl, &module, "energy_sum");
                (
                    storage_init(device, "energy table", bytemuck::cast_slice(table)),
                    storage_init(device, "energy weights", bytemuck::cast_slice(neg_log_w)),
                    layout,
                    pipeline,
                )
            },
        )?;
        Ok(GpuEnergySum {
            ctx,
            channels,
            padded,
            table,
            neg_log_w,
            layout,
            pipeline,
            buffers: Mutex::new(None),
        })
    }

    /// The spectral DRR of `view` from the channel renderers `channels` (one per kernel channel, in its
    /// order): the channels rendered (one submission, timed to its end), then summed over the energies
    /// and read back (the second time).
    pub fn render(&self, channels: &[GpuCtRenderer], view: &View) -> Result<GpuSpectralDrr> {
        if channels.len() != self.channels {
            return Err(Error::Internal(format!(
                "{} channel renderers for an energy kernel of {} channels",
                channels.len(),
                self.channels
            )));
        }
        let t0 = Instant::now();
        let (w, h) = (view.intrinsics.width, view.intrinsics.height);
        let mut slot = self.buffers(w, h)?;
        let Some(bufs) = slot.as_ref() else {
            return Err(Error::Internal("no spectral buffers".into()));
        };
        let mut encoder = self.ctx.device.create_command_encoder(&Default::default());
        for (c, r) in channels.iter().enumerate() {
            r.encode_views(
                &mut encoder,
                std::slice::from_ref(view),
                &bufs.maps,
                4 * bufs.stride * c as u64,
            )?;
        }
        self.ctx.checked("rendering the spectral channels", || {
            self.ctx.queue.submit([encoder.finish()]);
        })?;
        self.ctx.wait("rendering the spectral channels")?;
        let channels_ms = t0.elapsed().as_secs_f64() * 1e3;
        let t1 = Instant::now();
        let line_integral = self.finish(&mut slot, w, h)?;
        Ok(GpuSpectralDrr {
            line_integral,
            channels_ms,
            energy_sum_ms: t1.elapsed().as_secs_f64() * 1e3,
        })
    }

    /// The energy sum of channel maps rendered elsewhere (a spectral mesh DRR's, finished on the host),
    /// uploaded, summed on the GPU and read back.
    pub fn sum_maps(&self, maps: &[ImageF32]) -> Result<ImageF32> {
        let Some(first) = maps.first() else {
            return Err(Error::Internal("no channel maps".into()));
        };
        let (w, h) = (first.width, first.height);
        if maps.len() != self.channels || maps.iter().any(|m| (m.width, m.height) != (w, h)) {
            return Err(Error::Internal(format!(
                "{} channel maps (of one size) for an energy kernel of {} channels",
                maps.len(),
                self.channels
            )));
        }
        let mut slot = self.buffers(w, h)?;
        let Some(bufs) = slot.as_ref() else {
            return Err(Error::Internal("no spectral buffers".into()));
        };
        self.ctx.checked("uploading the channel maps", || {
            for (c, m) in maps.iter().enumerate() {
                self.ctx.queue.write_buffer(
                    &bufs.maps,
                    4 * bufs.stride * c as u64,
                    bytemuck::cast_slice(&m.data),
                );
            }
        })?;
        self.finish(&mut slot, w, h)
    }

    /// The buffers of a `w × h` render (the last render's when of that size).
    fn buffers(&self, w: u32, h: u32) -> Result<std::sync::MutexGuard<'_, Option<Buffers>>> {
        let pixels = u64::from(w) * u64::from(h);
        // Each channel's map starts on a 256-byte boundary (a storage binding's offset alignment).
        let stride = pixels.div_ceil(64) * 64;
        let device = &self.ctx.device;
        let mut slot = self.buffers.lock().unwrap_or_else(PoisonError::into_inner);
        if slot.as_ref().is_some_and(|b| b.pixels != pixels) {
            *slot = None;
        }
        if slot.is_none() {
            let maps_bytes = 4 * stride * self.channels as u64;
            if maps_bytes > self.ctx.max_storage_binding() {
                return Err(Error::invalid(
                    "view",
                    format!(
                        "{} channel maps of {w}×{h} px are more than GPU adapter {} binds in one \
                         buffer: render on the CPU",
                        self.channels,
                        self.ctx.adapter_name()
                    ),
                ));
            }
            let storage = wgpu::BufferUsages::STORAGE;
            *slot = Some(
                self.ctx
                    .checked("allocating the spectral DRR's buffers", || Buffers {
                        pixels,
                        stride,
                        maps: buffer(
                            device,
                            "channel maps",
                            maps_bytes,
                            storage | wgpu::BufferUsages::COPY_DST,
                        ),
                        out: buffer(
                            device,
                            "spectral DRR",
                            4 * pixels,
                            storage | wgpu::BufferUsages::COPY_SRC,
                        ),
                        staging: buffer(
                            device,
                            "spectral DRR read back",
                            4 * pixels,
                            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                        ),
                    })?,
            );
        }
        Ok(slot)
    }

    /// Sums the energies of the maps in `slot`'s buffers and reads the `w × h` image back.
    fn finish(&self, slot: &mut Option<Buffers>, w: u32, h: u32) -> Result<ImageF32> {
        let Some(bufs) = slot.as_ref() else {
            return Err(Error::Internal("no spectral buffers".into()));
        };
        let pixels = bufs.pixels;
        let params = Params {
            counts: [
                pixels as u32,
                self.channels as u32,
                self.padded as u32,
                bufs.stride as u32,
            ],
        };
        let groups = pixels.div_ceil(256).max(1);
        let max = u64::from(self.ctx.max_workgroups());
        let grid = [groups.min(max) as u32, groups.div_ceil(max) as u32];
        let device = &self.ctx.device;
        self.ctx.checked("summing the energies", || {
            let uniform = uniform_init(device, "energy params", bytemuck::bytes_of(&params));
            let bind = bind_buffers(
                device,
                "energy sum",
                &self.layout,
                &[
                    &uniform,
                    &bufs.maps,
                    &self.table,
                    &self.neg_log_w,
                    &bufs.out,
                ],
            );
            let mut encoder = device.create_command_encoder(&Default::default());
            {
                let mut pass = encoder.begin_compute_pass(&Default::default());
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &bind, &[]);
                pass.dispatch_workgroups(grid[0], grid[1], 1);
            }
            encoder.copy_buffer_to_buffer(&bufs.out, 0, &bufs.staging, 0, 4 * pixels);
            self.ctx.queue.submit([encoder.finish()]);
        })?;
        let data = self
            .ctx
            .read_back_first::<f32>(&bufs.staging, 4 * pixels, "the spectral DRR");
        if data.is_err() {
            // A buffer left mapped (or lost with the device) is not reused.
            *slot = None;
        }
        Ok(ImageF32 {
            width: w,
            height: h,
            data: data?,
        })
    }
}
