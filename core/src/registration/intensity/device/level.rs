//! One resolution level's evaluation on the GPU (`level.wgsl`): the moving DRRs of every view (a CT's in
//! one dispatch of the CT shader, meshes' view by view: [`Source`]), box-averaged to the level, smoothed,
//! turned into features and compared
//! block by block with the fixed images' normalised features. The residual stays on the GPU; each
//! block's weighted correlation and squared residual (two f32 per block and view) are all an evaluation
//! reads back.

use std::sync::{Arc, Mutex, PoisonError};

use bytemuck::{Pod, Zeroable};

use super::grid;
use super::lm_kernels::LmKernels;
use super::source::Source;
use crate::geometry::View;
use crate::registration::intensity::similarity::{FixedFeatures, feature_sources};
use crate::render::gpu::{
    self, GpuContext, UNIFORM, WRITE, buffer_layout, compute_pipeline, storage_init, uniform_init,
};
use crate::{Error, Result};

/// The poses a Jacobian's forward differences evaluate.
pub(super) const COLUMNS: u64 = 6;

/// `Params` in level.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    size: [u32; 4],
    counts: [u32; 4],
    scale: [f32; 4],
    poses: [u32; 4],
}

/// `Block` in level.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Block {
    start: u32,
    len: u32,
    sw: f32,
    eps: f32,
}

/// A residual on the GPU: every view's `r_v / √V`, stacked as on the CPU.
pub struct DeviceResidual {
    pub(super) buffer: wgpu::Buffer,
}

/// What one level of one problem needs on the GPU (see the module docs).
pub struct DeviceLevel<'a> {
    pub(super) ctx: Arc<GpuContext>,
    source: Source<'a>,
    /// Level width and height, rays per level pixel along each axis, views, features per view, blocks
    /// per view.
    w: u32,
    h: u32,
    ss: u32,
    views: u32,
    features: u32,
    blocks: u32,
    /// The Gaussian's radius (0: no smoothing).
    radius: u32,
    kernels: Arc<LevelKernels>,
    pub(super) lm: Arc<LmKernels>,
    /// The parameters of one pose's evaluation, and of a Jacobian's six at once ([`COLUMNS`]).
    uniform: wgpu::Buffer,
    uniform_columns: wgpu::Buffer,
    /// The scratch buffers hold [`COLUMNS`] poses' views (one dispatch renders a Jacobian's six poses),
    /// unless that would pass the adapter's binding limit (then they are evaluated one after another).
    batch_columns: bool,
    /// A 16-byte buffer bound where an `lm.wgsl` pass leaves a binding unused.
    pub(super) unused: wgpu::Buffer,
    /// raw, img, tmp, feat, src, blocks, fixed, sums, taps (bindings 1–7, 9, 10).
    scratch: Mutex<Scratch>,
}

/// The compiled `level.wgsl` and its bind group layout (one per device: [`GpuContext::cached`]).
struct LevelKernels {
    layout: wgpu::BindGroupLayout,
    bin: wgpu::ComputePipeline,
    blur_rows: wgpu::ComputePipeline,
    blur_cols: wgpu::ComputePipeline,
    features: wgpu::ComputePipeline,
    block_sums: wgpu::ComputePipeline,
}

struct Scratch {
    raw: wgpu::Buffer,
    img: wgpu::Buffer,
    tmp: wgpu::Buffer,
    feat: wgpu::Buffer,
    src: wgpu::Buffer,
    blocks: wgpu::Buffer,
    fixed: wgpu::Buffer,
    sums: wgpu::Buffer,
    staging: wgpu::Buffer,
    taps: wgpu::Buffer,
}

/// The per-view results of one evaluation: `Σ_k w_k ⟨m̂_k, f̂_k⟩` and `‖r_v‖²`.
pub struct ViewSums {
    pub similarity: Vec<f64>,
    pub squared: Vec<f64>,
}

impl<'a> DeviceLevel<'a> {
    /// The level of `views` (the moving DRR's views, `ss` times finer than the level; their fixed
    /// features and the moving normalisation's ε), smoothed by `smooth_px`, or `None` when the views
    /// differ in size (one dispatch renders one detector size: the CPU evaluates such a level).
    pub fn new(
        source: Source<'a>,
        views: &[(&View, &FixedFeatures, &[f64])],
        ss: u32,
        smooth_px: f64,
        level_size: (u32, u32),
    ) -> Result<Option<Self>> {
        let Some(&(first, fixed0, _)) = views.first() else {
            return Ok(None);
        };
        let size = (first.intrinsics.width, first.intrinsics.height);
        if views
            .iter()
            .any(|(v, _, _)| (v.intrinsics.width, v.intrinsics.height) != size)
        {
            return Ok(None);
        }
        let (w, h) = level_size;
        let sim = fixed0.sim;
        let src = feature_sources(sim, w, h)?;
        let f = src.len();
        let nb = fixed0.layout.blocks.len();
        if views
            .iter()
            .any(|(_, fx, _)| fx.layout.len != f || fx.layout.blocks.len() != nb)
        {
            return Err(Error::Internal(
                "the views' fixed features differ in layout".into(),
            ));
        }
        let mut blocks = Vec::with_capacity(views.len() * nb);
        let mut fixed = Vec::with_capacity(views.len() * f);
        for (_, fx, eps) in views {
            for (k, &(start, len)) in fx.layout.blocks.iter().enumerate() {
                blocks.push(Block {
                    start: start as u32,
                    len: len as u32,
                    sw: fx.layout.weights[k].sqrt() as f32,
                    eps: eps[k] as f32,
                });
            }
            fixed.extend(fx.normalised.iter().map(|&x| x as f32));
        }
        // Each tap as hi + lo (level.wgsl's `dot_add`).
        let taps: Vec<f32> = if smooth_px > 0.0 {
            crate::io::gaussian_taps(smooth_px)
                .into_iter()
                .flat_map(|t| {
                    let hi = t as f32;
                    [hi, (t - f64::from(hi)) as f32]
                })
                .collect()
        } else {
            vec![1.0, 0.0]
        };
        let ctx = Arc::clone(source.context()?);
        // The largest buffer `poses` poses' views need: their rays, or their features.
        let largest = |poses: u64| {
            let n_views = views.len() as u64 * poses;
            let raw_px = u64::from(w) * u64::from(h) * n_views * u64::from(ss) * u64::from(ss);
            4 * raw_px.max(f as u64 * n_views)
        };
        let batch_columns = largest(COLUMNS) <= ctx.max_storage_binding();
        let n_views = views.len() as u64 * if batch_columns { COLUMNS } else { 1 };
        let level_px = u64::from(w) * u64::from(h) * n_views;
        let raw_px = level_px * u64::from(ss) * u64::from(ss);
        let feat_n = f as u64 * n_views;
        let largest = largest(1);
        if largest > ctx.max_storage_binding() {
            return Err(Error::invalid(
                "levels",
                format!(
                    "a level of {} view(s) of {w}×{h} px ({ss}×{ss} rays each) needs {largest} bytes in \
                     one buffer, more than GPU adapter {} binds: use coarser levels or the CPU backend",
                    views.len(),
                    ctx.adapter_name()
                ),
            ));
        }
        let kernels = ctx.cached("the registration level's shader", |device| {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("level.wgsl"),
                source: wgpu::ShaderSource::Wgsl(include_str!("level.wgsl").into()),
            });
            let mut kinds = vec![UNIFORM];
            kinds.extend([WRITE; 10]);
            let (layout, pl) = buffer_layout(device, "registration level", &kinds);
            let pipe = |e| compute_pipeline(device, &pl, &module, e);
            LevelKernels {
                bin: pipe("bin"),
                blur_rows: pipe("blur_rows"),
                blur_cols: pipe("blur_cols"),
                features: pipe("features"),
                block_sums: pipe("block_sums"),
                layout,
            }
        })?;
        let lm = ctx.cached("the registration's LM shader", LmKernels::new)?;
        let device = &ctx.device;
        let (scratch, uniform, unused) =
            ctx.checked("preparing the registration level on the GPU", || {
                let buffer = |label, bytes, usage| gpu::buffer(device, label, bytes, usage);
                let storage = wgpu::BufferUsages::STORAGE;
                let sums_bytes = 8 * n_views * nb as u64;
                let scratch = Scratch {
                    raw: buffer(
                        "level rays",
                        4 * raw_px,
                        storage | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC,
                    ),
                    img: buffer(
                        "level image",
                        4 * level_px,
                        storage | wgpu::BufferUsages::COPY_DST,
                    ),
                    tmp: buffer("level smoothing", 4 * level_px, storage),
                    feat: buffer("level features", 4 * feat_n, storage),
                    src: storage_init(device, "feature sources", bytemuck::cast_slice(&src)),
                    blocks: storage_init(device, "blocks", bytemuck::cast_slice(&blocks)),
                    fixed: storage_init(device, "fixed features", bytemuck::cast_slice(&fixed)),
                    sums: buffer(
                        "block sums",
                        sums_bytes,
                        storage | wgpu::BufferUsages::COPY_SRC,
                    ),
                    staging: buffer(
                        "block sums read back",
                        sums_bytes,
                        wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                    ),
                    taps: storage_init(device, "gaussian taps", bytemuck::cast_slice(&taps)),
                };
                let params = |poses: u32| Params {
                    size: [w, h, ss, views.len() as u32 * poses],
                    counts: [f as u32, nb as u32, (taps.len() / 4) as u32, 0],
                    scale: [
                        (1.0 / (views.len() as f64).sqrt()) as f32,
                        (1.0 / f64::from(ss * ss)) as f32,
                        0.0,
                        0.0,
                    ],
                    poses: [views.len() as u32, 0, 0, 0],
                };
                let uniform = |poses| {
                    uniform_init(device, "level params", bytemuck::bytes_of(&params(poses)))
                };
                let uniform = (uniform(1), uniform(COLUMNS as u32));
                let unused = buffer("unused", 16, storage);
                (scratch, uniform, unused)
            })?;
        Ok(Some(DeviceLevel {
            ctx,
            source,
            w,
            h,
            ss,
            views: views.len() as u32,
            features: f as u32,
            blocks: nb as u32,
            radius: if smooth_px > 0.0 {
                (taps.len() / 4) as u32
            } else {
                0
            },
            kernels,
            lm,
            uniform: uniform.0,
            uniform_columns: uniform.1,
            batch_columns,
            unused,
            scratch: Mutex::new(scratch),
        }))
    }

    /// Evaluates a Jacobian's poses one after another, as a level too large to hold them at once does.
    pub fn columns_one_by_one(&mut self) {
        self.batch_columns = false;
    }

    /// Residuals per evaluation (every view's features).
    pub fn residuals(&self) -> u64 {
        u64::from(self.features) * u64::from(self.views)
    }

    /// A buffer of `values` residual values.
    pub(super) fn residual_buffer(&self, label: &str, values: u64) -> wgpu::Buffer {
        gpu::buffer(
            &self.ctx.device,
            label,
            4 * values,
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        )
    }

    /// Records the evaluation of the moved views `moved` (the views `new` was given seen from one pose, or
    /// from [`COLUMNS`] poses one after another) into `encoder`, its residual into `residual` from byte
    /// `offset` (the poses' residuals one after another).
    fn encode(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        scratch: &Scratch,
        moved: &[View],
        residual: &wgpu::Buffer,
        offset: u64,
    ) -> Result<()> {
        let n_views = moved.len() as u32;
        let uniform = if n_views == self.views {
            &self.uniform
        } else if self.batch_columns && n_views == self.views * COLUMNS as u32 {
            &self.uniform_columns
        } else {
            return Err(Error::Internal(format!(
                "{n_views} views for a level of {} per pose",
                self.views
            )));
        };
        self.source
            .render(&self.ctx, encoder, moved, &scratch.raw)?;
        let device = &self.ctx.device;
        fn whole(b: &wgpu::Buffer, binding: u32) -> wgpu::BindGroupEntry<'_> {
            wgpu::BindGroupEntry {
                binding,
                resource: b.as_entire_binding(),
            }
        }
        self.ctx
            .checked("evaluating a registration level on the GPU", || {
                let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("registration level"),
                    layout: &self.kernels.layout,
                    entries: &[
                        whole(uniform, 0),
                        whole(&scratch.raw, 1),
                        whole(&scratch.img, 2),
                        whole(&scratch.tmp, 3),
                        whole(&scratch.feat, 4),
                        whole(&scratch.src, 5),
                        whole(&scratch.blocks, 6),
                        whole(&scratch.fixed, 7),
                        wgpu::BindGroupEntry {
                            binding: 8,
                            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                                buffer: residual,
                                offset,
                                size: wgpu::BufferSize::new(
                                    4 * u64::from(self.features) * u64::from(n_views),
                                ),
                            }),
                        },
                        whole(&scratch.sums, 9),
                        whole(&scratch.taps, 10),
                    ],
                });
                let max = self.ctx.max_workgroups();
                let pixels = u64::from(self.w) * u64::from(self.h) * u64::from(n_views);
                let mut passes: Vec<(&wgpu::ComputePipeline, [u32; 3])> = Vec::new();
                if self.ss > 1 {
                    passes.push((&self.kernels.bin, grid(pixels, max)));
                }
                if self.radius > 0 {
                    passes.push((&self.kernels.blur_rows, grid(pixels, max)));
                    passes.push((&self.kernels.blur_cols, grid(pixels, max)));
                }
                passes.push((
                    &self.kernels.features,
                    grid(u64::from(self.features) * u64::from(n_views), max),
                ));
                let nb = self.blocks.max(1);
                passes.push((
                    &self.kernels.block_sums,
                    [nb.min(max), nb.div_ceil(max), n_views],
                ));
                if self.ss == 1 {
                    // The rays are the level's pixels.
                    let bytes = 4 * pixels;
                    encoder.copy_buffer_to_buffer(&scratch.raw, 0, &scratch.img, 0, bytes);
                }
                for (pipeline, g) in passes {
                    let mut pass = encoder.begin_compute_pass(&Default::default());
                    pass.set_pipeline(pipeline);
                    pass.set_bind_group(0, &bind, &[]);
                    pass.dispatch_workgroups(g[0], g[1], g[2]);
                }
            })
    }

    /// Evaluates the moved views: the per-view sums, and the residual (kept on the GPU).
    pub fn evaluate(&self, moved: &[View]) -> Result<(ViewSums, DeviceResidual)> {
        let residual = self.residual_buffer("residual", self.residuals());
        let scratch = self.scratch.lock().unwrap_or_else(PoisonError::into_inner);
        let mut encoder = self.ctx.device.create_command_encoder(&Default::default());
        self.encode(&mut encoder, &scratch, moved, &residual, 0)?;
        let bytes = 8 * u64::from(self.views) * u64::from(self.blocks);
        self.ctx.checked("reading the block sums", || {
            encoder.copy_buffer_to_buffer(&scratch.sums, 0, &scratch.staging, 0, bytes);
            self.ctx.queue.submit([encoder.finish()]);
        })?;
        let sums: Vec<f32> = self
            .ctx
            .read_back_first(&scratch.staging, bytes, "the block sums")?;
        let nb = self.blocks as usize;
        let per_view = |k: usize| -> Vec<f64> {
            sums.chunks_exact(2 * nb.max(1))
                .map(|v| v.chunks_exact(2).map(|b| f64::from(b[k])).sum())
                .collect()
        };
        Ok((
            ViewSums {
                similarity: per_view(0),
                squared: per_view(1),
            },
            DeviceResidual { buffer: residual },
        ))
    }

    /// Evaluates `columns` (the moved views of [`COLUMNS`] poses) into one buffer, the poses' residuals
    /// `stride` values apart (returned with it), and submits them; nothing is read back. One dispatch of
    /// the CT shader and of each pass renders and compares all of them where the scratch buffers hold
    /// them, else one pose after another (each residual then starts on a 256-byte boundary, a storage
    /// binding's offset alignment).
    pub(super) fn evaluate_columns(&self, columns: &[Vec<View>]) -> Result<(wgpu::Buffer, u64)> {
        let n = self.residuals();
        let batch = self.batch_columns && columns.len() == COLUMNS as usize;
        let stride = if batch { n } else { n.div_ceil(64) * 64 };
        let out = self.residual_buffer("difference columns", stride * columns.len() as u64);
        let scratch = self.scratch.lock().unwrap_or_else(PoisonError::into_inner);
        let mut encoder = self.ctx.device.create_command_encoder(&Default::default());
        if batch {
            let all: Vec<View> = columns.iter().flatten().cloned().collect();
            self.encode(&mut encoder, &scratch, &all, &out, 0)?;
        } else {
            for (k, moved) in columns.iter().enumerate() {
                self.encode(&mut encoder, &scratch, moved, &out, 4 * stride * k as u64)?;
            }
        }
        self.ctx.checked("evaluating the difference columns", || {
            self.ctx.queue.submit([encoder.finish()]);
        })?;
        Ok((out, stride))
    }

    /// The residual's values (a copy to the host: tests compare them with the CPU's).
    pub fn read_residual(&self, r: &DeviceResidual) -> Result<Vec<f64>> {
        let bytes = 4 * self.residuals();
        let staging = self.ctx.checked("reading a residual", || {
            let staging = gpu::buffer(
                &self.ctx.device,
                "residual read back",
                bytes,
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            );
            let mut encoder = self.ctx.device.create_command_encoder(&Default::default());
            encoder.copy_buffer_to_buffer(&r.buffer, 0, &staging, 0, bytes);
            self.ctx.queue.submit([encoder.finish()]);
            staging
        })?;
        let v: Vec<f32> = self.ctx.read_back_first(&staging, bytes, "a residual")?;
        Ok(v.into_iter().map(f64::from).collect())
    }
}
