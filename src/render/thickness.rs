//! Thickness DRRs: per pixel, `Σ_m μ_m · L_m` with `L_m` the path length of the pixel's ray inside mesh m.
//!
//! Rays start at the source and pass through pixel centres (`dir ∝ Rᵀ K⁻¹ [u, v, 1]ᵀ`). With a ray-tracing
//! backend, pixels are traced in 4 × 4 tiles (two 4 × 2 packets each), in parallel over rows of tiles; a
//! tile that no projected triangle's bounding box touches cannot see the mesh and is skipped. The raster
//! backend instead finds each band of rows' hits by rasterising the triangles binned to it. Either way a
//! pixel's hits go through the same f64 pairing. Rays whose crossings do not pair up (a hit lost at an
//! edge or vertex) are retraced with a sub-pixel-small offset; failing that, their value is capped by the
//! mesh's longest chord. Both counts are reported.

use std::sync::OnceLock;
use std::time::Instant;

use glam::{DMat3, DVec3};
use rayon::prelude::*;
use serde::Serialize;

use super::bvh::BvhTracer;
use super::embree::{EmbreeScene, EmbreeTracer};
use super::pairing::{Crossing, RayIntegral, integrate, integrate_crossings};
use super::raster::{BandScratch, RasterView};
use super::scene::RenderScene;
use super::tracer::{HitTracer, PACKET, RawHit, RayPacket};
use crate::Result;
use crate::anatomy::Structure;
use crate::geometry::View;
use crate::io::ImageF32;

/// Side of the square pixel tiles used for culling and scheduling.
pub const TILE: u32 = 4;

/// Sub-pixel offsets (pixels) tried in turn when a ray's crossings do not pair up.
const REPAIR_OFFSETS: [(f64, f64); 4] = [
    (1.3e-4, 0.7e-4),
    (-0.9e-4, 1.1e-4),
    (0.6e-4, -1.4e-4),
    (-1.2e-4, -0.8e-4),
];

/// Counters of one render.
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct RenderStats {
    pub rays_traced: u64,
    pub rays_culled: u64,
    pub hits: u64,
    pub rays_repaired: u64,
    pub rays_unrepaired: u64,
    pub render_ms: f64,
}

impl RenderStats {
    fn add(mut self, o: RenderStats) -> RenderStats {
        self.rays_traced += o.rays_traced;
        self.rays_culled += o.rays_culled;
        self.hits += o.hits;
        self.rays_repaired += o.rays_repaired;
        self.rays_unrepaired += o.rays_unrepaired;
        self
    }
}

/// Everything a thickness render produces.
#[derive(Debug, Clone)]
pub struct ThicknessDrr {
    /// Line integral `Σ μ L` (μ in mm⁻¹, so unitless; with μ = 1 it is thickness in mm).
    pub line_integral: ImageF32,
    /// Camera-frame depth (mm) of the first surface the ray enters, 0 outside the silhouette (when asked
    /// for).
    pub depth: Option<ImageF32>,
    /// Silhouettes per object and per structure (when asked for).
    pub masks: Option<Masks>,
    pub objects: Vec<String>,
    pub stats: RenderStats,
}

/// Per-pixel silhouette bits of a render.
#[derive(Debug, Clone, PartialEq)]
pub struct Masks {
    /// Per pixel, bit `i` set when the ray passes through object `i` (see [`ThicknessDrr::objects`]).
    pub object_bits: Vec<u64>,
    /// Per pixel, bit `s` set when the ray crosses a triangle labelled with [`Structure`] `s` of a mesh it
    /// passes through.
    pub structure_bits: Vec<u32>,
}

impl Masks {
    /// Silhouette of one object.
    pub fn object(&self, object: usize) -> Vec<bool> {
        self.object_bits
            .iter()
            .map(|b| b >> object & 1 == 1)
            .collect()
    }

    /// Silhouette of every object together.
    pub fn union(&self) -> Vec<bool> {
        self.object_bits.iter().map(|&b| b != 0).collect()
    }

    /// Silhouette of one structure over all objects.
    pub fn structure(&self, s: Structure) -> Vec<bool> {
        self.structure_bits
            .iter()
            .map(|b| b >> s as u32 & 1 == 1)
            .collect()
    }
}

impl ThicknessDrr {
    /// The silhouettes, or an error when the render was not asked for them.
    pub fn masks(&self) -> Result<&Masks> {
        self.masks.as_ref().ok_or_else(|| {
            crate::Error::invalid("render options", "silhouette masks were not requested")
        })
    }

    /// The depth map, or an error when the render was not asked for it.
    pub fn depth(&self) -> Result<&ImageF32> {
        self.depth.as_ref().ok_or_else(|| {
            crate::Error::invalid("render options", "the depth map was not requested")
        })
    }
}

/// Options of a thickness render: which outputs beside the line integral, and culling.
#[derive(Debug, Clone, Copy)]
pub struct ThicknessOptions {
    /// Skip tiles no triangle projects into (no effect on the result, only on speed; the raster visits
    /// only covered pixels anyway).
    pub cull: bool,
    /// Compute silhouette masks (object and structure bits per pixel).
    pub masks: bool,
    /// Compute the first-hit depth map.
    pub depth: bool,
}

impl Default for ThicknessOptions {
    /// Every output, with culling.
    fn default() -> Self {
        ThicknessOptions {
            cull: true,
            masks: true,
            depth: true,
        }
    }
}

impl ThicknessOptions {
    /// The line integral alone (the DRR), with culling.
    pub fn image_only() -> Self {
        ThicknessOptions {
            masks: false,
            depth: false,
            ..Self::default()
        }
    }

    /// The line integral and silhouette masks, no depth map.
    pub fn with_masks() -> Self {
        ThicknessOptions {
            depth: false,
            ..Self::default()
        }
    }
}

/// Splits `v` into `n` bands of `band` elements, or `n` `None`s when `v` is empty (an output not asked for).
fn bands<T>(v: &mut [T], band: usize, n: usize) -> Vec<Option<&mut [T]>> {
    if v.is_empty() {
        (0..n).map(|_| None).collect()
    } else {
        v.chunks_mut(band).map(Some).collect()
    }
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
    /// Embree (the reference BVH if Embree cannot take the scene), built on first use.
    Raster(OnceLock<Box<dyn HitTracer + Send>>),
}

/// One view's way of finding hits, shared by the band workers.
enum BandSource<'a> {
    Trace {
        tracer: &'a dyn HitTracer,
        tiles_x: usize,
        coverage: Option<Vec<bool>>,
    },
    Raster(RasterView<'a>),
}

/// Rows per band of the raster backend: a triangle spanning two bands is set up twice.
const RASTER_BAND_ROWS: usize = 16;

thread_local! {
    /// Per-thread buffers of the raster bands.
    static RASTER_SCRATCH: std::cell::RefCell<BandScratch> = std::cell::RefCell::default();
}

/// Per-view constants of ray generation.
struct Camera {
    source: DVec3,
    pixel_to_dir: DMat3,
    axis_z: DVec3,
    width: u32,
    height: u32,
}

impl Camera {
    fn new(view: &View) -> Self {
        Camera {
            source: view.source_world(),
            pixel_to_dir: view.pixel_to_world_dir(),
            axis_z: view.world_to_camera.rotation.transpose().z_axis,
            width: view.intrinsics.width,
            height: view.intrinsics.height,
        }
    }

    #[inline]
    fn dir(&self, u: f64, v: f64) -> DVec3 {
        (self.pixel_to_dir * DVec3::new(u, v, 1.0)).normalize()
    }
}

/// The pixels `(u, row in band)` of a tile spanning columns `u0..u1` and `rows` rows, row-major: traced in
/// packets of [`PACKET`] lanes (two 4 × 2 blocks per 4 × 4 tile).
fn tile_pixels(u0: usize, u1: usize, rows: usize) -> Vec<(usize, usize)> {
    (0..rows)
        .flat_map(|r| (u0..u1).map(move |u| (u, r)))
        .collect()
}

/// Per-thread buffers.
struct Scratch {
    hits: [Vec<RawHit>; PACKET],
    crossings: Vec<Crossing>,
}

impl Scratch {
    fn new() -> Self {
        Scratch {
            hits: std::array::from_fn(|_| Vec::with_capacity(32)),
            crossings: Vec::with_capacity(64),
        }
    }
}

impl ThicknessRenderer {
    pub fn new(scene: RenderScene, tracer: Box<dyn HitTracer>) -> Self {
        ThicknessRenderer {
            scene,
            gather: Gather::Trace(tracer),
        }
    }

    /// A renderer that rasterises each view instead of tracing rays (nothing to build up front).
    pub fn raster(scene: RenderScene) -> Self {
        ThicknessRenderer {
            scene,
            gather: Gather::Raster(OnceLock::new()),
        }
    }

    /// The backend that traces single rays (for repairs and [`Self::trace_ray`]).
    fn ray_tracer(&self) -> &dyn HitTracer {
        match &self.gather {
            Gather::Trace(t) => t.as_ref(),
            Gather::Raster(tracer) => tracer
                .get_or_init(|| match EmbreeTracer::new(&self.scene) {
                    Ok(embree) => Box::new(embree),
                    Err(_) => Box::new(BvhTracer::new(&self.scene)),
                })
                .as_ref(),
        }
    }

    pub fn scene(&self) -> &RenderScene {
        &self.scene
    }

    pub fn backend_name(&self) -> &'static str {
        match &self.gather {
            Gather::Trace(t) => t.name(),
            Gather::Raster(_) => "raster",
        }
    }

    /// BVH build time of the backend (ms).
    pub fn build_ms(&self) -> f64 {
        match &self.gather {
            Gather::Trace(t) => t.build_ms(),
            Gather::Raster(_) => 0.0,
        }
    }

    /// Renders the scene from `view` (its intrinsics may be perturbed; rays follow them).
    pub fn render(&self, view: &View, opts: &ThicknessOptions) -> Result<ThicknessDrr> {
        view.intrinsics.validate()?;
        let start = Instant::now();
        let cam = Camera::new(view);
        let (w, h) = (cam.width as usize, cam.height as usize);
        // How each band of rows finds its rays' hits.
        // A raster view when this renderer rasterises and the view can be projected (no vertex at or
        // behind the source plane); otherwise the pixels are traced.
        let raster = match &self.gather {
            Gather::Raster(_) => RasterView::new(&self.scene, view, RASTER_BAND_ROWS),
            Gather::Trace(_) => None,
        };
        let source = match raster {
            Some(raster) => BandSource::Raster(raster),
            None => {
                let (tiles_x, coverage) = self.plan(view, opts);
                BandSource::Trace {
                    tracer: self.ray_tracer(),
                    tiles_x,
                    coverage,
                }
            }
        };
        let band_rows = match &source {
            BandSource::Trace { .. } => TILE as usize,
            BandSource::Raster(r) => r.band_rows(),
        };

        // Zeroed by the allocator: fresh pages cost nothing until a traced pixel touches them.
        let n = w * h;
        let mut li = vec![0f32; n];
        let mut depth = if opts.depth {
            vec![0f32; n]
        } else {
            Vec::new()
        };
        let mut obj = if opts.masks {
            vec![0u64; n]
        } else {
            Vec::new()
        };
        let mut st = if opts.masks {
            vec![0u32; n]
        } else {
            Vec::new()
        };
        let band = w * band_rows;
        let n_bands = h.div_ceil(band_rows);
        let stats = li
            .par_chunks_mut(band)
            .zip(bands(&mut depth, band, n_bands))
            .zip(bands(&mut obj, band, n_bands))
            .zip(bands(&mut st, band, n_bands))
            .enumerate()
            .map(|(b, (((li, mut depth), mut obj), mut st))| {
                let v0 = b * band_rows;
                let rows = li.len() / w;
                let mut stats = RenderStats::default();
                let mut culled = 0u64;
                // Writes the outputs of pixel (u, row r of the band) from its integral; `depth_per_t`
                // turns the integral's `first_t` into camera depth.
                let mut emit = |u: usize, r: usize, mut ray: RayIntegral, depth_per_t: f64| {
                    if !ray.valid {
                        ray = self.repair(&cam, u as f64, (v0 + r) as f64, ray, &mut stats);
                    }
                    stats.rays_traced += 1;
                    stats.hits += u64::from(ray.hits);
                    let i = r * w + u;
                    li[i] = ray.line_integral as f32;
                    if let Some(d) = depth.as_deref_mut()
                        && ray.first_t.is_finite()
                    {
                        d[i] = (ray.first_t * depth_per_t) as f32;
                    }
                    if let (Some(o), Some(s)) = (obj.as_deref_mut(), st.as_deref_mut()) {
                        o[i] = ray.object_bits;
                        s[i] = ray.structure_bits;
                    }
                };
                match &source {
                    BandSource::Trace {
                        tracer,
                        tiles_x,
                        coverage,
                    } => {
                        let mut scratch = Scratch::new();
                        for tx in 0..*tiles_x {
                            let u0 = tx * TILE as usize;
                            let u1 = (u0 + TILE as usize).min(w);
                            if let Some(cov) = coverage
                                && !cov[b * tiles_x + tx]
                            {
                                culled += ((u1 - u0) * rows) as u64;
                                continue;
                            }
                            let pixels = tile_pixels(u0, u1, rows);
                            for chunk in pixels.chunks(PACKET) {
                                let mut packet = RayPacket::default();
                                for &(u, r) in chunk {
                                    packet.push(cam.source, cam.dir(u as f64, (v0 + r) as f64));
                                }
                                tracer.trace_all(&packet, &mut scratch.hits);
                                for (lane, &(u, r)) in chunk.iter().enumerate() {
                                    let dir = packet.dir[lane];
                                    let ray = integrate(
                                        &self.scene,
                                        cam.source,
                                        dir,
                                        &scratch.hits[lane],
                                        &mut scratch.crossings,
                                    );
                                    emit(u, r, ray, dir.dot(cam.axis_z));
                                }
                            }
                        }
                    }
                    BandSource::Raster(raster) => {
                        RASTER_SCRATCH.with_borrow_mut(|band_scratch| {
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
                            culled += (rows * w - traced) as u64;
                        });
                    }
                }
                stats.rays_culled += culled;
                stats
            })
            .reduce(RenderStats::default, RenderStats::add);

        let stats = RenderStats {
            render_ms: start.elapsed().as_secs_f64() * 1e3,
            ..stats
        };
        Ok(ThicknessDrr {
            line_integral: ImageF32 {
                width: cam.width,
                height: cam.height,
                data: li,
            },
            depth: opts.depth.then_some(ImageF32 {
                width: cam.width,
                height: cam.height,
                data: depth,
            }),
            masks: opts.masks.then_some(Masks {
                object_bits: obj,
                structure_bits: st,
            }),
            objects: self.scene.objects.clone(),
            stats,
        })
    }

    /// The benchmark floor: Embree's own closest-hit query for exactly the pixels `render` would trace
    /// (same tiles, same culling, same packets), returning the first-hit distance image and its time (ms).
    /// `floor` must be built from this renderer's scene without hit recording.
    pub fn first_hit_floor(
        &self,
        floor: &EmbreeScene,
        view: &View,
        opts: &ThicknessOptions,
    ) -> (ImageF32, f64) {
        let start = Instant::now();
        let cam = Camera::new(view);
        let (tiles_x, coverage) = self.plan(view, opts);
        let (w, h) = (cam.width as usize, cam.height as usize);
        let mut t_img = vec![0f32; w * h];
        t_img
            .par_chunks_mut(w * TILE as usize)
            .enumerate()
            .for_each(|(ty, band)| {
                let rows = band.len() / w;
                let mut t = [0f32; PACKET];
                for tx in 0..tiles_x {
                    if coverage.as_ref().is_some_and(|c| !c[ty * tiles_x + tx]) {
                        continue;
                    }
                    let u0 = tx * TILE as usize;
                    let u1 = (u0 + TILE as usize).min(w);
                    let v0 = ty * TILE as usize;
                    let pixels = tile_pixels(u0, u1, rows);
                    for chunk in pixels.chunks(PACKET) {
                        let mut packet = RayPacket::default();
                        for &(u, r) in chunk {
                            packet.push(cam.source, cam.dir(u as f64, (v0 + r) as f64));
                        }
                        floor.first_hit(&packet, &mut t);
                        for (lane, &(u, r)) in chunk.iter().enumerate() {
                            band[r * w + u] = t[lane];
                        }
                    }
                }
            });
        let img = ImageF32 {
            width: cam.width,
            height: cam.height,
            data: t_img,
        };
        (img, start.elapsed().as_secs_f64() * 1e3)
    }

    /// Traces one ray (world frame, unit `dir`) and returns its line integral and whether its crossings
    /// paired up without repair. For tools and tests that aim rays at chosen points.
    pub fn trace_ray(&self, origin: DVec3, dir: DVec3) -> (f64, bool) {
        let mut scratch = Scratch::new();
        let mut p = RayPacket::default();
        p.push(origin, dir.normalize());
        self.ray_tracer().trace_all(&p, &mut scratch.hits);
        let ray = integrate(
            &self.scene,
            p.origin[0],
            p.dir[0],
            &scratch.hits[0],
            &mut scratch.crossings,
        );
        (ray.line_integral, ray.valid)
    }

    /// Retraces a ray whose crossings did not pair up with tiny sub-pixel offsets; if none pairs up, keeps
    /// the first result with each mesh's contribution capped by its longest chord.
    fn repair(
        &self,
        cam: &Camera,
        u: f64,
        v: f64,
        first: RayIntegral,
        stats: &mut RenderStats,
    ) -> RayIntegral {
        let mut scratch = Scratch::new();
        for (du, dv) in REPAIR_OFFSETS {
            let mut p = RayPacket::default();
            p.push(cam.source, cam.dir(u + du, v + dv));
            self.ray_tracer().trace_all(&p, &mut scratch.hits);
            let ray = integrate(
                &self.scene,
                p.origin[0],
                p.dir[0],
                &scratch.hits[0],
                &mut scratch.crossings,
            );
            if ray.valid {
                stats.rays_repaired += 1;
                return ray;
            }
        }
        stats.rays_unrepaired += 1;
        let cap: f64 = self
            .scene
            .meshes
            .iter()
            .zip(&self.scene.max_chord)
            .map(|(m, c)| m.mu_per_mm.abs() * c)
            .sum();
        RayIntegral {
            line_integral: first.line_integral.clamp(-cap, cap),
            ..first
        }
    }

    /// The number of tile columns of `view` and the tiles to trace (`None`: all).
    fn plan(&self, view: &View, opts: &ThicknessOptions) -> (usize, Option<Vec<bool>>) {
        let tiles_x = (view.intrinsics.width as usize).div_ceil(TILE as usize);
        let coverage = if opts.cull {
            self.tile_coverage(view, tiles_x)
        } else {
            None
        };
        (tiles_x, coverage)
    }

    /// Marks the tiles touched by the projected bounding box of any triangle (plus one pixel of margin:
    /// the ray through a pixel centre next to the box may still graze it). `None` (no culling) when a
    /// vertex lies at or behind the source plane, where projection is not a bound. Vertices and triangles
    /// are processed in parallel; each worker marks its own map and the maps are OR-ed.
    fn tile_coverage(&self, view: &View, tiles_x: usize) -> Option<Vec<bool>> {
        let k = &view.intrinsics;
        let tiles_y = (k.height as usize).div_ceil(TILE as usize);
        let inv_t = 1.0 / TILE as f64;
        let n_tiles = tiles_x * tiles_y;
        let mut cov = vec![false; n_tiles];
        for m in &self.scene.meshes {
            let mesh = &m.mesh;
            // Per vertex, the (unclamped) tile range of its one-pixel neighbourhood.
            let ranges: Option<Vec<[i32; 4]>> = mesh
                .vertices
                .par_iter()
                .with_min_len(4096)
                .map(|&p| {
                    let c = view.world_to_camera.apply(p);
                    if c.z.is_nan() || c.z <= 1e-6 {
                        return None;
                    }
                    let q = k.project_camera(c);
                    Some([
                        floor_i32((q.x - 1.0) * inv_t),
                        floor_i32((q.y - 1.0) * inv_t),
                        floor_i32((q.x + 1.0) * inv_t),
                        floor_i32((q.y + 1.0) * inv_t),
                    ])
                })
                .collect();
            let ranges = ranges?;
            let (tx_max, ty_max) = (tiles_x as i32 - 1, tiles_y as i32 - 1);
            let mark = |mut map: Vec<bool>, tris: &[[u32; 3]]| {
                for tri in tris {
                    let [a, b, c] = tri.map(|i| ranges[i as usize]);
                    let x0 = a[0].min(b[0]).min(c[0]).max(0);
                    let y0 = a[1].min(b[1]).min(c[1]).max(0);
                    let x1 = a[2].max(b[2]).max(c[2]).min(tx_max);
                    let y1 = a[3].max(b[3]).max(c[3]).min(ty_max);
                    for ty in y0..=y1 {
                        let row = ty as usize * tiles_x;
                        if x0 <= x1 {
                            map[row + x0 as usize..=row + x1 as usize].fill(true);
                        }
                    }
                }
                map
            };
            let mesh_cov = mesh
                .triangles
                .par_chunks(8192)
                .fold(|| vec![false; n_tiles], mark)
                .reduce_with(|mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(x, &y)| *x |= y);
                    a
                });
            if let Some(mc) = mesh_cov {
                cov.iter_mut().zip(&mc).for_each(|(x, &y)| *x |= y);
            }
        }
        Some(cov)
    }
}

/// `floor(x)` as an integer, saturating (avoids a libm call on targets without SSE4.1 rounding).
#[inline]
fn floor_i32(x: f64) -> i32 {
    let i = x as i32;
    if (i as f64) > x { i - 1 } else { i }
}
