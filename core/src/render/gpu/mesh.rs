//! Mesh DRRs in a compute shader (`mesh.wgsl`): the raster's signed-depth sum
//! (`render::raster::summed`), one invocation per triangle, fixed-point sums added with atomics.
//!
//! The scene's triangles, meshes and μ are uploaded once; per view the vertices are projected in f64 with
//! the CPU raster's formula (camera frame, then K) into pixel positions as hi + lo f32s with their depths
//! — on the GPU when it computes in f64 (`project.rs`), else by the host, which uploads them —, and the
//! shader adds every covered pixel's `± μ · depth` together with two
//! balance counters (`Σ s`, `Σ s · mesh`, `s = ±1`). The result, a [`GpuFrame`], is turned into a DRR by
//! the thickness renderer, which evaluates on the CPU the few pixels the sums cannot give (crossings
//! that did not balance, centres near an edge). A third pass finishes every other pixel on the GPU (sum ×
//! the ray's length per unit depth; with masks or depth also its silhouettes and nearest depth from its
//! slots), so one f32 (or five words) per pixel and the list of the host's pixels come back instead of
//! every pixel's sums (measured at 1024², L1–L5 in LAT on lavapipe: the host's share of a line-integral
//! render 16–32 ms → ~1 ms). How the shader's f32 arithmetic keeps the
//! CPU's coverage and depth is written at the top of `mesh.wgsl`.
//!
//! The sums are integers in units of `1 / scale` (μ·mm): exact and the same whatever order the GPU adds
//! them in. `scale` is a power of two chosen per view so that no pixel's total can overflow: a ray's
//! depth chords through one mesh add up to at most the mesh's depth extent in that view.

use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use bytemuck::{Pod, Zeroable};

pub(crate) use super::mesh_frame::GpuFrame;
use super::mesh_frame::{FrameBuffers, FrameSizes};
use super::mesh_frame::{WORDS_ALL, WORDS_SUM};
use super::mesh_view::{SceneLayout, ViewSetup};
use super::project::Projector;
use super::{
    GpuContext, READ, UNIFORM, WRITE, bind_buffers, buffer_layout, compute_pipeline, storage_init,
    uniform_init,
};
use crate::geometry::View;
use crate::render::pairing::MIN_SILHOUETTE_CHORD_MM;
use crate::render::raster::PixelDirs;
use crate::render::scene::RenderScene;
use crate::{Error, Result};

/// Invocations per workgroup (`@workgroup_size(64, 1, 1)` in mesh.wgsl).
const WORKGROUP: u32 = 64;

/// Entries of `collect`'s list of (pixel, triangle) pairs the host evaluates (8 bytes each), and of
/// `finish`'s list of the host's pixels, at first: a view that needs more renders again with lists of
/// what it wanted (kept for the next view), and falls back to the CPU raster only past what one buffer
/// of the adapter holds.
const LIST_CAPACITY: u32 = 1 << 17;

/// `Globals` in mesh.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Globals {
    /// Width, height, triangles, words per pixel.
    image: [u32; 4],
    /// The fixed-point scales of the sum (x) and of the chords (y).
    scale: [f32; 4],
    /// The capacity of the lists (x), and the chords (y..=z, i32 in units of `scale[1]`) whose pixels the
    /// host evaluates.
    list: [u32; 4],
    /// The rows of `K⁻¹` giving a pixel's ray direction (`finish`).
    ray_x: [f32; 4],
    ray_y: [f32; 4],
}

/// A scene's triangles on the GPU and the compute pipeline that sums them.
pub struct GpuMeshRenderer {
    ctx: Arc<GpuContext>,
    triangles: u32,
    /// Where each mesh's vertices start, and their boxes.
    scene_layout: SceneLayout,
    /// First global triangle of each mesh.
    triangle_start: Vec<usize>,
    tris: wgpu::Buffer,
    meshes: wgpu::Buffer,
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    collect: wgpu::ComputePipeline,
    finish: wgpu::ComputePipeline,
    /// Projects the vertices on the GPU (an adapter with `SHADER_F64`); else the host projects them.
    pub(super) project: Option<Projector>,
    /// The entries of the lists of pixels for the host (grown when a view needs more).
    capacity: AtomicU32,
    /// The vertex, accumulator and read-back buffers, reused by the next render of the same size; held
    /// for a whole render, so renders from several threads take turns.
    buffers: Mutex<Option<FrameBuffers>>,
}

impl std::fmt::Debug for GpuMeshRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuMeshRenderer")
            .field("triangles", &self.triangles)
            .field("adapter", &self.ctx.adapter_name())
            .finish()
    }
}

impl GpuMeshRenderer {
    /// Uploads `scene`'s triangles and μ and compiles the shader.
    pub fn new(ctx: Arc<GpuContext>, scene: &RenderScene) -> Result<GpuMeshRenderer> {
        let mut vertex_start = Vec::with_capacity(scene.meshes.len());
        let mut triangle_start = Vec::with_capacity(scene.meshes.len());
        let mut vertices = 0usize;
        let mut tris: Vec<[u32; 4]> = Vec::with_capacity(scene.triangle_count());
        for (g, m) in scene.meshes.iter().enumerate() {
            vertex_start.push(vertices);
            triangle_start.push(tris.len());
            let first = vertices as u32;
            // An implant's pixels are paired by the host (mesh.wgsl's `rasterise`).
            let implant = u32::from(scene.implants.get(g).copied().unwrap_or(false));
            for (k, t) in m.mesh.triangles.iter().enumerate() {
                let label = u32::from(m.mesh.label(k) as u8);
                tris.push([
                    first + t[0],
                    first + t[1],
                    first + t[2],
                    g as u32 | label << 16 | implant << 24,
                ]);
            }
            vertices += m.mesh.vertices.len();
        }
        // Two vec4s per vertex; indices are u32 in the shader.
        if vertices > (u32::MAX / 2) as usize || tris.len() > u32::MAX as usize {
            return Err(Error::invalid(
                "scene",
                format!(
                    "{vertices} vertices and {} triangles are more than the gpu backend indexes",
                    tris.len()
                ),
            ));
        }
        let meshes: Vec<[u32; 2]> = scene
            .meshes
            .iter()
            .enumerate()
            .map(|(g, m)| {
                [
                    (m.mu_per_mm as f32).to_bits(),
                    scene.object_of_mesh[g] as u32,
                ]
            })
            .collect();
        let too_big = [
            32 * vertices as u64,
            16 * tris.len() as u64,
            8 * meshes.len() as u64,
        ]
        .into_iter()
        .any(|b| b > ctx.max_storage_binding());
        if too_big {
            return Err(Error::invalid(
                "scene",
                format!(
                    "{vertices} vertices are more than one buffer of GPU adapter {} holds ({} bytes): \
                     render with the raster backend",
                    ctx.adapter_name(),
                    ctx.max_storage_binding()
                ),
            ));
        }
        let device = &ctx.device;
        let (tris_buf, meshes_buf, layout, pipeline) =
            ctx.checked("uploading the meshes and compiling their shader", || {
                // A scene of empty meshes uploads one unused entry.
                let tris_buf = storage_init(device, "mesh triangles", bytemuck::cast_slice(&tris));
                let meshes_buf = storage_init(device, "meshes", bytemuck::cast_slice(&meshes));
                let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some("mesh.wgsl"),
                    source: wgpu::ShaderSource::Wgsl(include_str!("mesh.wgsl").into()),
                });
                let (layout, pipeline_layout) = buffer_layout(
                    device,
                    "mesh",
                    &[UNIFORM, READ, READ, READ, WRITE, WRITE, WRITE, WRITE, WRITE],
                );
                let pipeline = |entry| compute_pipeline(device, &pipeline_layout, &module, entry);
                let pipelines = (
                    pipeline("rasterise"),
                    pipeline("collect"),
                    pipeline("finish"),
                );
                (tris_buf, meshes_buf, layout, pipelines)
            })?;
        let (pipeline, collect, finish) = pipeline;
        // The f64 projection in a scope of its own: a driver that advertises SHADER_F64 but cannot
        // compile the shader (reported of some) leaves the projection to the host instead of failing.
        let project = if ctx.has_f64() {
            ctx.checked("compiling the f64 projection shader", || {
                Projector::new(&ctx, scene)
            })
            .ok()
        } else {
            None
        };
        Ok(GpuMeshRenderer {
            ctx,
            triangles: tris.len() as u32,
            scene_layout: SceneLayout {
                vertex_start,
                vertices,
                bounds: scene.meshes.iter().map(|m| m.mesh.bounds()).collect(),
            },
            triangle_start,
            tris: tris_buf,
            meshes: meshes_buf,
            layout,
            pipeline,
            collect,
            finish,
            project,
            capacity: AtomicU32::new(LIST_CAPACITY),
            buffers: Mutex::new(None),
        })
    }

    /// Global triangle `t`'s mesh and its index in the mesh.
    pub(crate) fn locate(&self, t: u32) -> (usize, usize) {
        let t = t as usize;
        let g = self.triangle_start.partition_point(|&s| s <= t) - 1;
        (g, t - self.triangle_start[g])
    }

    /// The device the renders run on.
    pub(crate) fn context(&self) -> &Arc<GpuContext> {
        &self.ctx
    }

    /// The adapter the renders run on.
    pub fn adapter_name(&self) -> String {
        self.ctx.adapter_name()
    }

    /// Sums `scene` (the scene this renderer was built from) as seen from `view` and finishes every
    /// pixel it can on the GPU (`finish` in mesh.wgsl): its line integral and, with `full`, its
    /// silhouettes and nearest depth; only those and the pixels left to the host, with their candidate
    /// triangles, come back ([`GpuFrame`]). `None` when a vertex lies at or behind the source plane (no
    /// finite projection: the CPU raster traces such a view, and so does the caller) or when the
    /// host's pixels need more list entries than one buffer of the adapter holds: the caller renders
    /// the view on the CPU.
    pub(crate) fn rasterise(
        &self,
        scene: &RenderScene,
        view: &View,
        full: bool,
    ) -> Result<Option<GpuFrame>> {
        self.frame(scene, view, full, None)
    }

    /// [`Self::rasterise`]'s line integral (no depth or silhouettes) left on the GPU: the finished image
    /// (0 at the host's pixels) is copied into `image` from byte `offset` (a buffer with `COPY_DST`) and
    /// only the lists come back ([`GpuFrame::finished`]'s image is empty); the host's values go up with
    /// [`super::scatter::scatter`].
    pub(crate) fn rasterise_onto(
        &self,
        scene: &RenderScene,
        view: &View,
        image: &wgpu::Buffer,
        offset: u64,
    ) -> Result<Option<GpuFrame>> {
        self.frame(scene, view, false, Some((image, offset)))
    }

    /// [`Self::rasterise`], its image read back or (`onto`) copied into a GPU buffer at a byte offset.
    fn frame(
        &self,
        scene: &RenderScene,
        view: &View,
        full: bool,
        onto: Option<(&wgpu::Buffer, u64)>,
    ) -> Result<Option<GpuFrame>> {
        let intr = &view.intrinsics;
        let (w, h) = (intr.width, intr.height);
        let Some(ViewSetup {
            z_ref,
            on_gpu,
            verts,
            scale,
            chord_scale,
            chord_band,
        }) = self.scene_layout.setup(scene, view, self.project.is_some())
        else {
            return Ok(None);
        };
        let stride = if full { WORDS_ALL } else { WORDS_SUM };
        let acc_bytes = 4 * u64::from(w) * u64::from(h) * u64::from(stride);
        let max_groups = self.ctx.max_workgroups();
        let grid_of = |n: u32| {
            let groups = n.div_ceil(WORKGROUP).max(1);
            [groups.min(max_groups), groups.div_ceil(max_groups)]
        };
        let grid = grid_of(self.triangles);
        let pixel_grid = grid_of(w * h);
        if acc_bytes > self.ctx.max_storage_binding()
            || grid[1] > max_groups
            || pixel_grid[1] > max_groups
        {
            return Err(Error::invalid(
                "view",
                format!(
                    "a {w}×{h} px mesh DRR of {} triangles is more than one dispatch of GPU adapter {} \
                     takes ({} bytes of output at most): render it with the raster backend",
                    self.triangles,
                    self.ctx.adapter_name(),
                    self.ctx.max_storage_binding()
                ),
            ));
        }
        let (rx, ry) = PixelDirs::new(intr).rows();
        let row = |r: [f64; 3]| [r[0] as f32, r[1] as f32, r[2] as f32, 0.0];
        // The lists start at LIST_CAPACITY entries and grow to what a view wanted (once per render,
        // kept for the next), as far as one buffer of the adapter holds; beyond that the CPU renders it.
        let max_capacity = ((self.ctx.max_storage_binding() / 4 - 1) / 2).min(u64::from(u32::MAX));
        let mut grown = false;
        let back = loop {
            let capacity = self.capacity.load(Ordering::Relaxed);
            let globals = Globals {
                image: [w, h, self.triangles, stride],
                scale: [
                    scale as f32,
                    chord_scale as f32,
                    MIN_SILHOUETTE_CHORD_MM as f32,
                    0.0,
                ],
                list: [capacity, chord_band[0], chord_band[1], 0],
                ray_x: row(rx),
                ray_y: row(ry),
            };
            let sizes = FrameSizes {
                verts: (32 * self.scene_layout.vertices as u64).max(32),
                acc: acc_bytes,
                list: 4 * (1 + 2 * u64::from(capacity)),
                host: 4 * (4 + u64::from(capacity)),
                image: 4 * u64::from(w) * u64::from(h),
                extra: if full {
                    16 * u64::from(w) * u64::from(h)
                } else {
                    16
                },
            };
            let device = &self.ctx.device;
            let mut slot = self.buffers.lock().unwrap_or_else(PoisonError::into_inner);
            if slot.as_ref().is_some_and(|b| b.sizes != sizes) {
                *slot = None;
            }
            let bufs = match &mut *slot {
                Some(b) => b,
                empty => {
                    empty.insert(self.ctx.checked("allocating the mesh DRR's buffers", || {
                        FrameBuffers::new(device, sizes)
                    })?)
                }
            };
            self.ctx.checked("rendering a mesh DRR", || {
                if !verts.is_empty() {
                    self.ctx
                        .queue
                        .write_buffer(&bufs.verts, 0, bytemuck::cast_slice(&verts));
                }
                let uniform = uniform_init(device, "mesh globals", bytemuck::bytes_of(&globals));
                let bind = bind_buffers(
                    device,
                    "mesh",
                    &self.layout,
                    &[
                        &uniform,
                        &bufs.verts,
                        &self.tris,
                        &self.meshes,
                        &bufs.acc,
                        &bufs.list,
                        &bufs.host,
                        &bufs.image,
                        &bufs.extra,
                    ],
                );
                let mut encoder = device.create_command_encoder(&Default::default());
                // The sums start at 0 (a reused buffer holds the last render).
                encoder.clear_buffer(&bufs.acc, 0, None);
                encoder.clear_buffer(&bufs.list, 0, Some(4));
                encoder.clear_buffer(&bufs.host, 0, Some(16));
                if let (true, Some(p)) = (on_gpu, &self.project) {
                    p.encode(&self.ctx, &mut encoder, view, &z_ref, &bufs.verts);
                }
                // `collect` reads what every invocation of `rasterise` added, and `finish` each pixel's
                // totals.
                let passes = [
                    (&self.pipeline, grid),
                    (&self.collect, grid),
                    (&self.finish, pixel_grid),
                ];
                for (pipeline, grid) in &passes {
                    let mut pass = encoder.begin_compute_pass(&Default::default());
                    pass.set_pipeline(pipeline);
                    pass.set_bind_group(0, &bind, &[]);
                    pass.dispatch_workgroups(grid[0], grid[1], 1);
                }
                bufs.copy_out(&mut encoder, full, onto.is_none());
                if let Some((image, offset)) = onto {
                    encoder.copy_buffer_to_buffer(&bufs.image, 0, image, offset, sizes.image);
                }
                self.ctx.queue.submit([encoder.finish()]);
            })?;
            match bufs.read(&self.ctx, full, capacity, onto.is_none()) {
                Ok(Ok(b)) => break b,
                // More pixels for the host than the lists hold: once, larger lists; then the CPU raster.
                Ok(Err(wanted)) => {
                    let larger = u64::from(wanted).next_power_of_two().min(max_capacity) as u32;
                    if grown || larger < wanted {
                        return Ok(None);
                    }
                    self.capacity.fetch_max(larger, Ordering::Relaxed);
                    grown = true;
                }
                Err(e) => {
                    // A buffer left mapped (or lost with the device) is not reused.
                    *slot = None;
                    return Err(e);
                }
            }
        };
        let mut pairs: Vec<[u32; 2]> = back.pairs.chunks_exact(2).map(|p| [p[0], p[1]]).collect();
        pairs.sort_unstable();
        Ok(Some(GpuFrame {
            finished: back.finished,
            pairs,
        }))
    }
}
