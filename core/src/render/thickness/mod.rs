//! Thickness DRRs: per pixel, `Σ_m μ_m · L_m` with `L_m` the path length of the pixel's ray inside mesh m.
//!
//! Rays start at the source and pass through pixel centres (`dir ∝ Rᵀ K⁻¹ [u, v, 1]ᵀ`). With a ray-tracing
//! backend, pixels are traced in 4 × 4 tiles (two 4 × 2 packets each), in parallel over rows of tiles; a
//! tile that no projected triangle's bounding box touches cannot see the mesh and is skipped (`tiles`).
//! The raster backend instead finds each band of rows' hits by rasterising the triangles binned to it.
//! Either way a pixel's hits go through the same f64 pairing. Rays whose crossings do not pair up (a hit
//! lost at an edge or vertex) are retraced with a sub-pixel-small offset; failing that, their value is
//! capped by the mesh's longest chord (`repair`). Both counts are reported.
//!
//! Which tracer a renderer uses (and the raster's fallback tracer) is chosen by [`super::Backend`].

mod gpu;
mod output;
mod rays;
mod repair;
pub(crate) mod tiles;

use std::sync::OnceLock;
use std::time::Instant;

use glam::DVec3;
use rayon::prelude::*;

pub(crate) use self::gpu::GpuRaster;
use self::gpu::Outputs;
use self::output::bands;
pub use self::output::{Masks, RenderStats, ThicknessDetails, ThicknessDrr, ThicknessOptions};
use self::rays::{Scratch, integrate_lane, trace_single};
use self::tiles::{Camera, TILE, TilePlan};
use super::pairing::{RayIntegral, integrate_crossings};
use super::raster::{BandScratch, RasterView, SumScratch};
use super::scene::RenderScene;
use super::tracer::HitTracer;
use crate::Result;
use crate::geometry::View;
use crate::io::ImageF32;

/// Builds the tracer a rasterising renderer falls back to for single rays and unprojectable views.
pub(crate) type FallbackTracer = fn(&RenderScene) -> Box<dyn HitTracer>;

/// Checks `view`'s intrinsics and makes `out` a zeroed image of its size, reusing its buffer.
fn zeroed_for(view: &View, out: &mut ImageF32) -> Result<()> {
    view.intrinsics.validate()?;
    let (w, h) = (view.intrinsics.width, view.intrinsics.height);
    out.width = w;
    out.height = h;
    out.data.clear();
    out.data.resize(w as usize * h as usize, 0.0);
    Ok(())
}

/// A scene plus a backend, built once and rendered from any number of views.
pub struct ThicknessRenderer {
    scene: RenderScene,
    gather: Gather,
}

/// How a renderer finds the triangles each ray crosses.
enum Gather {
    /// Rays traced in packets through a backend.
    Trace(Box<dyn HitTracer>),
    /// Pixels rasterised per view (see [`super::raster`]); single rays (repairs, [`ThicknessRenderer::trace_ray`])
    /// and views with a vertex at or behind the source plane (which cannot be projected) are traced with
    /// the fallback tracer, built on first use.
    Raster {
        fallback: FallbackTracer,
        tracer: OnceLock<Box<dyn HitTracer>>,
        /// The gpu backend: views are summed on the GPU (see [`gpu`]) instead of paired on the CPU,
        /// except in [`ThicknessRenderer::render_line_integral_into`], which pairs.
        gpu: Option<Box<GpuRaster>>,
    },
}

/// One view's way of finding hits, shared by the band workers.
enum BandSource<'a> {
    Trace {
        tracer: &'a dyn HitTracer,
        plan: TilePlan,
    },
    Raster(RasterView<'a>),
}

/// Rows per band of the raster backend: a triangle spanning two bands is set up twice.
const RASTER_BAND_ROWS: usize = 16;

thread_local! {
    /// Per-thread buffers of the raster bands.
    static RASTER_SCRATCH: std::cell::RefCell<BandScratch> = std::cell::RefCell::default();
    /// Per-thread buffers of summed raster bands and their unbalanced pixels.
    static SUM_SCRATCH: std::cell::RefCell<(SumScratch, Vec<(usize, usize)>)> =
        std::cell::RefCell::default();
}

/// One band of rows of every output, written by one worker; outputs not asked for are `None`.
struct BandOut<'a> {
    line_integral: &'a mut [f32],
    depth: Option<&'a mut [f32]>,
    object_bits: Option<&'a mut [u64]>,
    structure_bits: Option<&'a mut [u32]>,
}

impl BandOut<'_> {
    /// Writes pixel `i` of the band from its integral; `depth_per_t` turns the ray distance `first_t`
    /// into camera depth.
    #[inline]
    fn write(&mut self, i: usize, ray: &RayIntegral, depth_per_t: f64) {
        self.line_integral[i] = ray.line_integral as f32;
        if let Some(d) = self.depth.as_deref_mut()
            && ray.first_t.is_finite()
        {
            d[i] = (ray.first_t * depth_per_t) as f32;
        }
        if let (Some(o), Some(s)) = (
            self.object_bits.as_deref_mut(),
            self.structure_bits.as_deref_mut(),
        ) {
            o[i] = ray.object_bits;
            s[i] = ray.structure_bits;
        }
    }
}

impl ThicknessRenderer {
    /// A renderer that traces every ray with `tracer`.
    pub fn new(scene: RenderScene, tracer: Box<dyn HitTracer>) -> Self {
        ThicknessRenderer {
            scene,
            gather: Gather::Trace(tracer),
        }
    }

    /// A renderer that rasterises each view instead of tracing rays (nothing to build up front); what it
    /// cannot rasterise it traces with the tracer `fallback` builds, on first use.
    pub(crate) fn raster(scene: RenderScene, fallback: FallbackTracer) -> Self {
        ThicknessRenderer {
            scene,
            gather: Gather::Raster {
                fallback,
                tracer: OnceLock::new(),
                gpu: None,
            },
        }
    }

    /// A renderer that sums each view on the GPU with `gpu` (built for `scene`, whose meshes are closed)
    /// and rasterises on the CPU what it pairs; what neither can take it traces with `fallback`.
    #[cfg_attr(not(feature = "gpu"), allow(dead_code))]
    pub(crate) fn gpu(scene: RenderScene, gpu: GpuRaster, fallback: FallbackTracer) -> Self {
        ThicknessRenderer {
            scene,
            gather: Gather::Raster {
                fallback,
                tracer: OnceLock::new(),
                gpu: Some(Box::new(gpu)),
            },
        }
    }

    /// The GPU adapter the renders run on (the gpu backend), else `None`.
    pub fn gpu_adapter(&self) -> Option<String> {
        match &self.gather {
            Gather::Raster { gpu: Some(g), .. } => Some(g.adapter_name()),
            _ => None,
        }
    }

    /// The backend that traces single rays (for repairs and [`Self::trace_ray`]).
    fn ray_tracer(&self) -> &dyn HitTracer {
        match &self.gather {
            Gather::Trace(t) => t.as_ref(),
            Gather::Raster {
                fallback, tracer, ..
            } => tracer.get_or_init(|| fallback(&self.scene)).as_ref(),
        }
    }

    pub fn scene(&self) -> &RenderScene {
        &self.scene
    }

    /// The backend this renderer was built with.
    pub fn backend(&self) -> super::Backend {
        use super::Backend;
        match &self.gather {
            Gather::Trace(t) if t.name() == "embree" => Backend::Embree,
            Gather::Trace(_) => Backend::Bvh,
            Gather::Raster { gpu: Some(_), .. } => Backend::Gpu,
            Gather::Raster { .. } => Backend::Raster,
        }
    }

    pub fn backend_name(&self) -> &'static str {
        match &self.gather {
            Gather::Trace(t) => t.name(),
            Gather::Raster { gpu: Some(_), .. } => "gpu",
            Gather::Raster { .. } => "raster",
        }
    }

    /// The sidecar record of a render of `anatomy` (its description) that `stats` came from.
    pub fn details(&self, stats: RenderStats, anatomy: serde_json::Value) -> ThicknessDetails {
        ThicknessDetails {
            renderer: "thickness",
            backend: self.backend_name(),
            gpu_adapter: self.gpu_adapter(),
            anatomy,
            stats,
        }
    }

    /// BVH build time of the backend (ms).
    pub fn build_ms(&self) -> f64 {
        match &self.gather {
            Gather::Trace(t) => t.build_ms(),
            Gather::Raster { .. } => 0.0,
        }
    }

    /// Renders the scene from `view` (its intrinsics may be perturbed; rays follow them).
    pub fn render(&self, view: &View, opts: &ThicknessOptions) -> Result<ThicknessDrr> {
        view.intrinsics.validate()?;
        let (w, h) = (view.intrinsics.width, view.intrinsics.height);
        // Zeroed by the allocator: fresh pages cost nothing until a traced pixel touches them.
        let n = w as usize * h as usize;
        let mut li = vec![0f32; n];
        let mut depth = vec![0f32; if opts.depth { n } else { 0 }];
        let mut obj = vec![0u64; if opts.masks { n } else { 0 }];
        let mut st = vec![0u32; if opts.masks { n } else { 0 }];
        let outs = Outputs {
            li: &mut li,
            depth: &mut depth,
            obj: &mut obj,
            st: &mut st,
        };
        let stats = self.render_buffers(view, opts, outs, true)?;
        let image = |data| ImageF32 {
            width: w,
            height: h,
            data,
        };
        Ok(ThicknessDrr {
            line_integral: image(li),
            depth: opts.depth.then(|| image(depth)),
            masks: opts.masks.then_some(Masks {
                object_bits: obj,
                structure_bits: st,
            }),
            objects: self.scene.objects.clone(),
            stats,
        })
    }

    /// Renders the line integral alone from `view` into `out`, reusing its buffer (resized to the view,
    /// zeroed, no allocation when it is already large enough): the path of loops that render the same
    /// scene many times (intensity registration).
    pub fn render_line_integral_into(
        &self,
        view: &View,
        out: &mut ImageF32,
    ) -> Result<RenderStats> {
        self.line_integral_into(view, out, false)
    }

    /// The line integral alone into `out` (resized and zeroed); with `gpu`, a gpu-backend renderer sums
    /// it on the GPU (see [`Self::render_buffers`]).
    fn line_integral_into(
        &self,
        view: &View,
        out: &mut ImageF32,
        gpu: bool,
    ) -> Result<RenderStats> {
        zeroed_for(view, out)?;
        let outs = Outputs {
            li: &mut out.data,
            depth: &mut [],
            obj: &mut [],
            st: &mut [],
        };
        self.render_buffers(view, &ThicknessOptions::image_only(), outs, gpu)
    }

    /// [`Self::render_line_integral_into`] by signed sums of the rasterised crossings instead of paired
    /// ones (see `raster::summed`): several times faster, and the same image wherever a ray's crossings
    /// alternate entry and exit, which they do in closed meshes that do not intersect themselves. Rays
    /// that lost or doubled a crossing at a vertex are traced and paired as in the paired render. A
    /// scene with an open mesh or an implant (which displaces what it occupies: a sum cannot tell), a
    /// renderer that traces, or a view that cannot be projected falls back to the paired render (the gpu
    /// backend pairs an implant's pixels on the host). A self-intersecting mesh is summed where it overlaps itself (counted twice):
    /// callers that cannot rule that out compare one summed render with a paired one first.
    pub fn render_line_integral_summed_into(
        &self,
        view: &View,
        out: &mut ImageF32,
    ) -> Result<RenderStats> {
        if let Gather::Raster { gpu: Some(_), .. } = &self.gather {
            return self.line_integral_into(view, out, true);
        }
        let start = Instant::now();
        let raster = match &self.gather {
            Gather::Raster { .. }
                if self.scene.open_meshes.is_empty() && !self.scene.has_implants() =>
            {
                view.intrinsics.validate()?;
                RasterView::new(&self.scene, view, RASTER_BAND_ROWS)
            }
            _ => None,
        };
        let Some(raster) = raster else {
            return self.render_line_integral_into(view, out);
        };
        zeroed_for(view, out)?;
        let cam = Camera::new(view);
        let rows = raster.band_rows();
        let w = out.width as usize;
        let stats = out
            .data
            .par_chunks_mut(w * rows)
            .enumerate()
            .map(|(b, li)| {
                SUM_SCRATCH.with_borrow_mut(|(scratch, unbalanced)| {
                    unbalanced.clear();
                    let covered = raster.band_line_integral(b, scratch, li, unbalanced);
                    let mut stats = RenderStats {
                        rays_traced: covered + unbalanced.len() as u64,
                        rays_culled: li.len() as u64 - covered - unbalanced.len() as u64,
                        ..RenderStats::default()
                    };
                    for &(u, r) in unbalanced.iter() {
                        let pixel = (u as f64, (b * rows + r) as f64);
                        let mut ray = trace_single(
                            self.ray_tracer(),
                            &self.scene,
                            cam.source,
                            cam.dir(pixel.0, pixel.1),
                            &mut Scratch::new(),
                        );
                        if !ray.valid {
                            ray = repair::repair(
                                self.ray_tracer(),
                                &self.scene,
                                &cam,
                                pixel,
                                ray,
                                &mut stats,
                            );
                        }
                        stats.hits += u64::from(ray.hits);
                        li[r * w + u] = ray.line_integral as f32;
                    }
                    stats
                })
            })
            .reduce(RenderStats::default, RenderStats::add);
        Ok(RenderStats {
            render_ms: start.elapsed().as_secs_f64() * 1e3,
            ..stats
        })
    }

    /// Renders into zeroed buffers of the view's size (`depth`, `obj`, `st` empty unless `opts` asks
    /// for them); with `gpu`, a gpu-backend renderer sums the view on the GPU (otherwise, and for a view
    /// the GPU cannot project, it pairs on the CPU).
    fn render_buffers(
        &self,
        view: &View,
        opts: &ThicknessOptions,
        outs: Outputs,
        gpu: bool,
    ) -> Result<RenderStats> {
        let Outputs { li, depth, obj, st } = outs;
        if let (true, Gather::Raster { gpu: Some(g), .. }) = (gpu, &self.gather) {
            let outs = Outputs {
                li: &mut *li,
                depth: &mut *depth,
                obj: &mut *obj,
                st: &mut *st,
            };
            if let Some(stats) = g.render(self, view, opts, outs)? {
                return Ok(stats);
            }
        }
        let start = Instant::now();
        let cam = Camera::new(view);
        let (w, h) = (cam.width as usize, cam.height as usize);
        // A raster view when this renderer rasterises and the view can be projected (no vertex at or
        // behind the source plane); otherwise the pixels are traced.
        let raster = match &self.gather {
            Gather::Raster { .. } => RasterView::new(&self.scene, view, RASTER_BAND_ROWS),
            Gather::Trace(_) => None,
        };
        let source = match raster {
            Some(raster) => BandSource::Raster(raster),
            None => BandSource::Trace {
                tracer: self.ray_tracer(),
                plan: TilePlan::new(&self.scene, view, opts.cull),
            },
        };
        let band_rows = match &source {
            BandSource::Trace { .. } => TILE as usize,
            BandSource::Raster(r) => r.band_rows(),
        };
        let band = w * band_rows;
        let n_bands = h.div_ceil(band_rows);
        let stats = li
            .par_chunks_mut(band)
            .zip(bands(depth, band, n_bands))
            .zip(bands(obj, band, n_bands))
            .zip(bands(st, band, n_bands))
            .enumerate()
            .map(|(b, (((li, depth), obj), st))| {
                let out = BandOut {
                    line_integral: li,
                    depth,
                    object_bits: obj,
                    structure_bits: st,
                };
                self.render_band(&source, &cam, b, band_rows, out, opts)
            })
            .reduce(RenderStats::default, RenderStats::add);
        Ok(RenderStats {
            render_ms: start.elapsed().as_secs_f64() * 1e3,
            ..stats
        })
    }

    /// Renders band `b` (rows `b · band_rows ..`) into `out` and returns its counters.
    fn render_band(
        &self,
        source: &BandSource,
        cam: &Camera,
        b: usize,
        band_rows: usize,
        mut out: BandOut,
        opts: &ThicknessOptions,
    ) -> RenderStats {
        let w = cam.width as usize;
        let v0 = b * band_rows;
        let rows = out.line_integral.len() / w;
        let mut stats = RenderStats::default();
        // Writes the outputs of pixel (u, row r of the band) from its integral, repairing it first when
        // its crossings did not pair up.
        let mut emit = |u: usize, r: usize, mut ray: RayIntegral, depth_per_t: f64| {
            if !ray.valid {
                let pixel = (u as f64, (v0 + r) as f64);
                ray = repair::repair(self.ray_tracer(), &self.scene, cam, pixel, ray, &mut stats);
            }
            stats.rays_traced += 1;
            stats.hits += u64::from(ray.hits);
            out.write(r * w + u, &ray, depth_per_t);
        };
        let culled = match source {
            BandSource::Trace { tracer, plan } => {
                let mut scratch = Scratch::new();
                plan.for_each_packet(cam, b, rows, |packet, pixels| {
                    tracer.trace_all(packet, &mut scratch.hits);
                    for (lane, &(u, r)) in pixels.iter().enumerate() {
                        let ray = integrate_lane(&self.scene, packet, lane, &mut scratch);
                        emit(u, r, ray, packet.dir[lane].dot(cam.axis_z));
                    }
                })
            }
            BandSource::Raster(raster) => RASTER_SCRATCH.with_borrow_mut(|band_scratch| {
                let mut traced = 0;
                raster.band_hits(b, band_scratch, |u, r, crossings| {
                    traced += 1;
                    // Depth to distance along the ray.
                    let path = raster.path_per_depth(u as f64, (v0 + r) as f64);
                    for c in crossings.iter_mut() {
                        c.t *= path;
                    }
                    let ray = integrate_crossings(&self.scene, crossings, opts.masks);
                    emit(u, r, ray, 1.0 / path);
                });
                (rows * w - traced) as u64
            }),
        };
        stats.rays_culled += culled;
        stats
    }

    /// The union of the scene's inside intervals along one ray (world frame, unit `dir`; sorted, disjoint,
    /// mm from `origin`) and whether every mesh's crossings paired up: where an implant is along the ray.
    pub fn trace_intervals(&self, origin: DVec3, dir: DVec3) -> (Vec<(f64, f64)>, bool) {
        let mut packet = crate::render::tracer::RayPacket::default();
        packet.push(origin, dir);
        let mut hits: [Vec<crate::render::tracer::RawHit>; crate::render::tracer::PACKET] =
            Default::default();
        self.ray_tracer().trace_all(&packet, &mut hits);
        crate::render::pairing::union_intervals(&self.scene, origin, dir, &hits[0], &mut Vec::new())
    }

    /// Traces one ray (world frame, unit `dir`) and returns its line integral and whether its crossings
    /// paired up without repair. For tools and tests that aim rays at chosen points.
    pub fn trace_ray(&self, origin: DVec3, dir: DVec3) -> (f64, bool) {
        let ray = trace_single(
            self.ray_tracer(),
            &self.scene,
            origin,
            dir.normalize(),
            &mut Scratch::new(),
        );
        (ray.line_integral, ray.valid)
    }
}
