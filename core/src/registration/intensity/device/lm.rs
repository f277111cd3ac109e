//! Levenberg–Marquardt's products over residuals on the GPU (`lm.wgsl`): the forward-difference
//! Jacobian of six evaluations recorded in one submission, the normal equations `JᵀJ` and `−Jᵀr` as
//! partial sums per chunk of rows (added on the host in chunk order, in f64: the result does not depend
//! on how the GPU scheduled the work), and Broyden's rank-one update along a step.

use bytemuck::{Pod, Zeroable};

use super::grid;
use super::level::{DeviceLevel, DeviceResidual};
use super::lm_kernels::LmKernels;
use crate::Result;
use crate::geometry::View;
use crate::render::gpu::{self, uniform_init};

/// `Params` in lm.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    counts: [u32; 4],
    step: [f32; 4],
    delta: [[f32; 4]; 2],
    d: [[f32; 4]; 2],
}

/// Rows per chunk of the normal equations (as the CPU's `CHUNK`).
const CHUNK: u32 = 4096;

/// A Jacobian on the GPU: six values per residual, row by row.
pub struct DeviceJacobian {
    buffer: wgpu::Buffer,
}

/// Six f64 as two vec4<f32>.
fn six(v: &[f64; 6]) -> [[f32; 4]; 2] {
    [
        [v[0] as f32, v[1] as f32, v[2] as f32, v[3] as f32],
        [v[4] as f32, v[5] as f32, 0.0, 0.0],
    ]
}

impl DeviceLevel<'_> {
    /// Records one `lm.wgsl` pass of `entry` over `groups` with `params` and the four buffers.
    fn lm_pass(
        &self,
        what: &str,
        entry: fn(&LmKernels) -> &wgpu::ComputePipeline,
        groups: [u32; 3],
        params: &Params,
        buffers: [&wgpu::Buffer; 4],
        read: Option<(&wgpu::Buffer, &wgpu::Buffer, u64)>,
    ) -> Result<()> {
        let k = &*self.lm;
        let device = &self.ctx.device;
        self.ctx.checked(what, || {
            let uniform = uniform_init(device, "lm params", bytemuck::bytes_of(params));
            let mut entries = vec![wgpu::BindGroupEntry {
                binding: 0,
                resource: uniform.as_entire_binding(),
            }];
            entries.extend(
                (1u32..)
                    .zip(buffers)
                    .map(|(binding, b)| wgpu::BindGroupEntry {
                        binding,
                        resource: b.as_entire_binding(),
                    }),
            );
            let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("lm"),
                layout: &k.layout,
                entries: &entries,
            });
            let mut encoder = device.create_command_encoder(&Default::default());
            {
                let mut pass = encoder.begin_compute_pass(&Default::default());
                pass.set_pipeline(entry(k));
                pass.set_bind_group(0, &bind, &[]);
                pass.dispatch_workgroups(groups[0], groups[1], groups[2]);
            }
            if let Some((from, to, bytes)) = read {
                encoder.copy_buffer_to_buffer(from, 0, to, 0, bytes);
            }
            self.ctx.queue.submit([encoder.finish()]);
        })
    }

    fn params(&self, stride: u64, step: f32, delta: &[f64; 6], d: &[f64; 6]) -> Params {
        Params {
            counts: [self.residuals() as u32, stride as u32, CHUNK, 0],
            step: [step, 0.0, 0.0, 0.0],
            delta: six(delta),
            d: six(d),
        }
    }

    /// The forward-difference Jacobian of step `h` at the residual `r`, from `columns` (the moved views of
    /// the six poses `p + h e_k`), rendered and compared in one submission.
    pub fn jacobian(
        &self,
        columns: &[Vec<View>],
        r: &DeviceResidual,
        h: f64,
    ) -> Result<DeviceJacobian> {
        let (cols, stride) = self.evaluate_columns(columns)?;
        let jac = self.residual_buffer("jacobian", 6 * self.residuals());
        let params = self.params(stride, (1.0 / h) as f32, &[0.0; 6], &[0.0; 6]);
        let g = grid(self.residuals(), self.ctx.max_workgroups());
        self.lm_pass(
            "forming the Jacobian",
            |k| &k.jacobian,
            g,
            &params,
            [&r.buffer, &cols, &jac, &self.unused],
            None,
        )?;
        Ok(DeviceJacobian { buffer: jac })
    }

    /// `JᵀJ` and `−Jᵀr`.
    pub fn normal_equations(
        &self,
        j: &DeviceJacobian,
        r: &DeviceResidual,
    ) -> Result<([[f64; 6]; 6], [f64; 6])> {
        let n = self.residuals();
        let chunks = n.div_ceil(u64::from(CHUNK)).max(1);
        let bytes = 4 * 27 * chunks;
        let partials = self.residual_buffer("normal equations", 27 * chunks);
        let staging = self
            .ctx
            .checked("allocating the normal equations' read-back", || {
                gpu::buffer(
                    &self.ctx.device,
                    "normal equations read back",
                    bytes,
                    wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                )
            })?;
        let params = self.params(0, 0.0, &[0.0; 6], &[0.0; 6]);
        let max = u64::from(self.ctx.max_workgroups());
        let groups = [chunks.min(max) as u32, chunks.div_ceil(max) as u32, 1];
        self.lm_pass(
            "forming the normal equations",
            |k| &k.normal,
            groups,
            &params,
            [&r.buffer, &self.unused, &j.buffer, &partials],
            Some((&partials, &staging, bytes)),
        )?;
        let parts: Vec<f32> = self.ctx.read_back(&staging, "the normal equations")?;
        let mut acc = [0.0f64; 27];
        for part in parts.chunks_exact(27) {
            for (a, &x) in acc.iter_mut().zip(part) {
                *a += f64::from(x);
            }
        }
        // `acc` holds the upper triangle row by row: entry (p, q ≥ p) at p·(11 − p)/2 + q.
        let jtj = std::array::from_fn(|p| {
            std::array::from_fn(|q| {
                let (a, b) = (p.min(q), p.max(q));
                acc[a * (11 - a) / 2 + b]
            })
        });
        Ok((jtj, std::array::from_fn(|p| acc[21 + p])))
    }

    /// Broyden's update of `j` along `delta`, which changed the residual from `r` to `rq`.
    pub fn secant_update(
        &self,
        j: &mut DeviceJacobian,
        delta: &[f64; 6],
        r: &DeviceResidual,
        rq: &DeviceResidual,
    ) -> Result<()> {
        let dd: f64 = delta.iter().map(|x| x * x).sum();
        if dd <= 0.0 {
            return Ok(());
        }
        let params = self.params(0, 0.0, delta, &delta.map(|x| x / dd));
        let g = grid(self.residuals(), self.ctx.max_workgroups());
        self.lm_pass(
            "updating the Jacobian",
            |k| &k.secant,
            g,
            &params,
            [&r.buffer, &rq.buffer, &j.buffer, &self.unused],
            None,
        )
    }
}
