//! Thickness DRRs: per pixel, `Σ_m μ_m · L_m` with `L_m` the path length of the pixel's ray inside mesh m.
//!
//! Rays start at the source and pass through pixel centres (`dir ∝ Rᵀ K⁻¹ [u, v, 1]ᵀ`). Pixels are traced in
//! 4 × 4 tiles (two 4 × 2 packets each), in parallel over rows of tiles; a tile that no projected
//! triangle's bounding box touches cannot see the mesh and is skipped. Rays whose crossings do not pair up (a hit lost at an edge or vertex)
//! are retraced with a sub-pixel-small offset; failing that, their value is capped by the mesh's
//! longest chord. Both counts are reported.

use std::time::Instant;

use glam::{DMat3, DVec3};
use rayon::prelude::*;
use serde::Serialize;

use super::embree::EmbreeScene;
use super::pairing::{Crossing, RayIntegral, integrate};
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
    /// Camera-frame depth (mm) of the first surface; 0 where the ray hits nothing.
    pub depth: ImageF32,
    /// Per pixel, bit `i` set when the ray passes through object `i` (see `objects`).
    pub object_bits: Vec<u64>,
    /// Per pixel, bit `s` set when the ray crosses a triangle labelled with [`Structure`] `s` of a mesh it
    /// passes through.
    pub structure_bits: Vec<u32>,
    pub objects: Vec<String>,
    pub stats: RenderStats,
}

impl ThicknessDrr {
    /// Silhouette of one object.
    pub fn object_mask(&self, object: usize) -> Vec<bool> {
        self.object_bits
            .iter()
            .map(|b| b >> object & 1 == 1)
            .collect()
    }

    /// Silhouette of every object together.
    pub fn union_mask(&self) -> Vec<bool> {
        self.object_bits.iter().map(|&b| b != 0).collect()
    }

    /// Silhouette of one structure over all objects.
    pub fn structure_mask(&self, s: Structure) -> Vec<bool> {
        self.structure_bits
            .iter()
            .map(|b| b >> s as u32 & 1 == 1)
            .collect()
    }
}

/// Options of a thickness render.
#[derive(Debug, Clone, Copy)]
pub struct ThicknessOptions {
    /// Skip tiles no triangle projects into (no effect on the result, only on speed).
    pub cull: bool,
}

impl Default for ThicknessOptions {
    fn default() -> Self {
        ThicknessOptions { cull: true }
    }
}

/// A scene plus a backend, built once and rendered from any number of views.
pub struct ThicknessRenderer {
    scene: RenderScene,
    tracer: Box<dyn HitTracer>,
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
        ThicknessRenderer { scene, tracer }
    }

    pub fn scene(&self) -> &RenderScene {
        &self.scene
    }

    pub fn backend_name(&self) -> &'static str {
        self.tracer.name()
    }

    /// BVH build time of the backend (ms).
    pub fn build_ms(&self) -> f64 {
        self.tracer.build_ms()
    }

    /// Renders the scene from `view` (its intrinsics may be perturbed; rays follow them).
    pub fn render(&self, view: &View, opts: &ThicknessOptions) -> Result<ThicknessDrr> {
        view.intrinsics.validate()?;
        let start = Instant::now();
        let (cam, tiles_x, coverage) = self.plan(view, opts);
        let (w, h) = (cam.width as usize, cam.height as usize);

        let mut li = vec![0f32; w * h];
        let mut depth = vec![0f32; w * h];
        let mut obj = vec![0u64; w * h];
        let mut st = vec![0u32; w * h];
        let band = w * TILE as usize;
        let stats = li
            .par_chunks_mut(band)
            .zip(depth.par_chunks_mut(band))
            .zip(obj.par_chunks_mut(band))
            .zip(st.par_chunks_mut(band))
            .enumerate()
            .map(|(ty, (((li, depth), obj), st))| {
                let mut scratch = Scratch::new();
                let mut stats = RenderStats::default();
                let rows = li.len() / w;
                for tx in 0..tiles_x {
                    let u0 = tx * TILE as usize;
                    let u1 = (u0 + TILE as usize).min(w);
                    if let Some(cov) = &coverage
                        && !cov[ty * tiles_x + tx]
                    {
                        stats.rays_culled += ((u1 - u0) * rows) as u64;
                        continue;
                    }
                    let pixels = tile_pixels(u0, u1, rows);
                    for chunk in pixels.chunks(PACKET) {
                        let v0 = ty * TILE as usize;
                        let mut packet = RayPacket::default();
                        for &(u, r) in chunk {
                            packet.push(cam.source, cam.dir(u as f64, (v0 + r) as f64));
                        }
                        self.tracer.trace_all(&packet, &mut scratch.hits);
                        for (lane, &(u, r)) in chunk.iter().enumerate() {
                            let dir = packet.dir[lane];
                            let mut ray = integrate(
                                &self.scene,
                                packet.origin[lane],
                                dir,
                                &scratch.hits[lane],
                                &mut scratch.crossings,
                            );
                            if !ray.valid {
                                let v = (v0 + r) as f64;
                                ray = self.repair(&cam, u as f64, v, ray, &mut scratch, &mut stats);
                            }
                            stats.rays_traced += 1;
                            stats.hits += u64::from(ray.hits);
                            let i = r * w + u;
                            li[i] = ray.line_integral as f32;
                            if ray.first_t.is_finite() {
                                depth[i] = (ray.first_t * dir.dot(cam.axis_z)) as f32;
                            }
                            obj[i] = ray.object_bits;
                            st[i] = ray.structure_bits;
                        }
                    }
                }
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
            depth: ImageF32 {
                width: cam.width,
                height: cam.height,
                data: depth,
            },
            object_bits: obj,
            structure_bits: st,
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
        let (cam, tiles_x, coverage) = self.plan(view, opts);
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
        self.tracer.trace_all(&p, &mut scratch.hits);
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
        scratch: &mut Scratch,
        stats: &mut RenderStats,
    ) -> RayIntegral {
        for (du, dv) in REPAIR_OFFSETS {
            let mut p = RayPacket::default();
            p.push(cam.source, cam.dir(u + du, v + dv));
            self.tracer.trace_all(&p, &mut scratch.hits);
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

    /// Ray generation for `view`, the number of tile columns and the tiles to trace (`None`: all).
    fn plan(&self, view: &View, opts: &ThicknessOptions) -> (Camera, usize, Option<Vec<bool>>) {
        let cam = Camera::new(view);
        let tiles_x = (cam.width as usize).div_ceil(TILE as usize);
        let coverage = if opts.cull {
            self.tile_coverage(view, tiles_x)
        } else {
            None
        };
        (cam, tiles_x, coverage)
    }

    /// Marks the tiles touched by the projected bounding box of any triangle. `None` (no culling) when a
    /// vertex lies at or behind the source plane, where projection is not a bound.
    fn tile_coverage(&self, view: &View, tiles_x: usize) -> Option<Vec<bool>> {
        let k = &view.intrinsics;
        let tiles_y = (k.height as usize).div_ceil(TILE as usize);
        let mut cov = vec![false; tiles_x * tiles_y];
        let t = TILE as f64;
        for m in &self.scene.meshes {
            let mesh = &m.mesh;
            let cam: Vec<DVec3> = mesh
                .vertices
                .iter()
                .map(|&p| view.world_to_camera.apply(p))
                .collect();
            if cam.iter().any(|p| p.z <= 1e-6) {
                return None;
            }
            let px: Vec<glam::DVec2> = cam.iter().map(|&p| k.project_camera(p)).collect();
            for tri in &mesh.triangles {
                let [a, b, c] = tri.map(|i| px[i as usize]);
                let lo = a.min(b).min(c);
                let hi = a.max(b).max(c);
                // One pixel of margin: the ray through a pixel centre next to the box may still graze it.
                let x0 = ((lo.x - 1.0) / t).floor().max(0.0);
                let y0 = ((lo.y - 1.0) / t).floor().max(0.0);
                let x1 = ((hi.x + 1.0) / t).floor().min(tiles_x as f64 - 1.0);
                let y1 = ((hi.y + 1.0) / t).floor().min(tiles_y as f64 - 1.0);
                if x1 < x0 || y1 < y0 {
                    continue;
                }
                for ty in y0 as usize..=y1 as usize {
                    cov[ty * tiles_x + x0 as usize..=ty * tiles_x + x1 as usize].fill(true);
                }
            }
        }
        Some(cov)
    }
}
