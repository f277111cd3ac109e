//! A thickness render on the GPU backend: the GPU's signed-depth sums
//! (`render::gpu::GpuMeshRenderer`) turned into the renderer's outputs, and the few pixels the sums
//! cannot give (crossings that do not balance, a centre near an edge) evaluated on the CPU exactly as
//! the CPU raster evaluates them.
//!
//! Without the `gpu` feature, [`GpuRaster`] has no values, so the renderer's code has no `cfg`.

use crate::Result;
use crate::geometry::View;

use super::output::ThicknessOptions;
use super::{RenderStats, ThicknessRenderer};

/// The GPU side of a renderer built with the gpu backend.
#[cfg(feature = "gpu")]
pub(crate) struct GpuRaster(pub crate::render::gpu::GpuMeshRenderer);

/// The GPU side of a renderer built with the gpu backend (none: the `gpu` feature is off).
#[cfg(not(feature = "gpu"))]
pub(crate) enum GpuRaster {}

/// A render's output buffers (empty when not asked for).
pub(super) struct Outputs<'a> {
    pub li: &'a mut [f32],
    pub depth: &'a mut [f32],
    pub obj: &'a mut [u64],
    pub st: &'a mut [u32],
}

#[cfg(not(feature = "gpu"))]
impl GpuRaster {
    pub(super) fn adapter_name(&self) -> String {
        match *self {}
    }

    pub(super) fn render(
        &self,
        _: &ThicknessRenderer,
        _: &View,
        _: &ThicknessOptions,
        _: Outputs,
    ) -> Result<Option<RenderStats>> {
        match *self {}
    }
}

#[cfg(feature = "gpu")]
impl GpuRaster {
    /// The adapter the renders run on.
    pub(super) fn adapter_name(&self) -> String {
        self.0.adapter_name()
    }

    /// Renders `view` into `out` (zeroed, of the view's size). `None` when the GPU cannot take the view
    /// (a vertex at or behind the source plane, or too many pixels for the host): the caller renders it
    /// on the CPU.
    ///
    /// The pixels the GPU's sums cannot give (unbalanced, or with a centre near an edge: see
    /// `gpu/mesh.wgsl`) come with their candidate triangles; each is evaluated with the CPU raster's
    /// own edge functions and pairing, from the same f64 camera-frame vertices, so it is the CPU
    /// raster's value exactly (repaired like it when its crossings do not pair). A line integral alone
    /// is finished on the GPU and read back as one f32 per pixel, and the host visits only those
    /// pixels; with depth or masks every pixel's words come back and the host finishes each.
    pub(super) fn render(
        &self,
        r: &ThicknessRenderer,
        view: &View,
        opts: &ThicknessOptions,
        out: Outputs,
    ) -> Result<Option<RenderStats>> {
        use rayon::prelude::*;

        use crate::render::pairing::MIN_SILHOUETTE_CHORD_MM;

        let start = std::time::Instant::now();
        let Some(frame) = self.0.rasterise(&r.scene, view, opts.masks || opts.depth)? else {
            return Ok(None);
        };
        let host = HostPixels::new(self, r, view, &frame, opts);
        let w = view.intrinsics.width as usize;
        let stats = if let Some(done) = &frame.finished {
            // The line integral alone: the GPU's image, and the host's pixels evaluated in parallel.
            out.li.copy_from_slice(&done.image);
            let values: Vec<(usize, f32, RenderStats)> = done
                .pixels
                .par_iter()
                .map(|&i| {
                    let i = i as usize;
                    let mut stats = RenderStats::default();
                    let value = host.evaluate(i % w, i / w, &mut stats);
                    (i, value.map_or(0.0, |v| v.line_integral as f32), stats)
                })
                .collect();
            let mut stats = RenderStats {
                rays_traced: u64::from(done.rays),
                hits: done.hits,
                ..RenderStats::default()
            };
            for (i, li, s) in values {
                out.li[i] = li;
                stats = stats.add(s);
            }
            let pixels = (w * view.intrinsics.height as usize) as u64;
            stats.rays_culled = pixels - stats.rays_traced;
            stats
        } else {
            let rows: Vec<_> = out
                .li
                .chunks_mut(w)
                .zip(rows_of(out.depth, w))
                .zip(rows_of(out.obj, w))
                .zip(rows_of(out.st, w))
                .collect();
            rows.into_par_iter()
                .enumerate()
                .map(|(v, (((li, depth), obj), st))| {
                    let mut stats = RenderStats::default();
                    for (u, li) in li.iter_mut().enumerate() {
                        let i = v * w + u;
                        if !frame.touched(i) {
                            stats.rays_culled += 1;
                            continue;
                        }
                        let listed = host.listed(i);
                        if listed.is_empty() && frame.balanced(i) {
                            stats.rays_traced += 1;
                            stats.hits += u64::from(frame.crossings(i));
                            let path = host.dirs.camera_dir(u as f64, v as f64).length();
                            *li = (frame.sum(i) * path) as f32;
                            // A mesh is in the silhouettes when its chord passes the CPU's threshold.
                            let (mut o, mut s, mut first) = (0u64, 0u32, f32::INFINITY);
                            for (g, chord, z, bits) in frame.slots(i) {
                                if chord * path > MIN_SILHOUETTE_CHORD_MM {
                                    o |= 1 << r.scene.object_of_mesh[g];
                                    s |= bits;
                                    first = first.min(z);
                                }
                            }
                            if let Some(d) = depth.get_mut(u)
                                && first.is_finite()
                            {
                                *d = first;
                            }
                            if let (Some(ob), Some(st)) = (obj.get_mut(u), st.get_mut(u)) {
                                (*ob, *st) = (o, s);
                            }
                            continue;
                        }
                        let Some(ray) = host.evaluate(u, v, &mut stats) else {
                            continue;
                        };
                        *li = ray.line_integral as f32;
                        if let Some(d) = depth.get_mut(u)
                            && ray.first_t.is_finite()
                        {
                            *d = (ray.first_t * ray.depth_per_t) as f32;
                        }
                        if let (Some(o), Some(s)) = (obj.get_mut(u), st.get_mut(u)) {
                            (*o, *s) = (ray.object_bits, ray.structure_bits);
                        }
                    }
                    stats
                })
                .reduce(RenderStats::default, RenderStats::add)
        };
        Ok(Some(RenderStats {
            render_ms: start.elapsed().as_secs_f64() * 1e3,
            ..stats
        }))
    }
}

/// A pixel the host evaluated: its ray's integral, and the camera depth per unit of the ray's `t`.
#[cfg(feature = "gpu")]
struct HostRay {
    ray: crate::render::pairing::RayIntegral,
    depth_per_t: f64,
}

#[cfg(feature = "gpu")]
impl std::ops::Deref for HostRay {
    type Target = crate::render::pairing::RayIntegral;
    fn deref(&self) -> &Self::Target {
        &self.ray
    }
}

/// What the host needs to evaluate the pixels the GPU's sums cannot give, as the CPU raster does.
#[cfg(feature = "gpu")]
struct HostPixels<'a> {
    gpu: &'a GpuRaster,
    r: &'a ThicknessRenderer,
    frame: &'a crate::render::gpu::GpuFrame,
    opts: &'a ThicknessOptions,
    cam: super::tiles::Camera,
    world_to_camera: crate::geometry::RigidTransform,
    dirs: crate::render::raster::PixelDirs,
    width: usize,
}

#[cfg(feature = "gpu")]
impl<'a> HostPixels<'a> {
    fn new(
        gpu: &'a GpuRaster,
        r: &'a ThicknessRenderer,
        view: &View,
        frame: &'a crate::render::gpu::GpuFrame,
        opts: &'a ThicknessOptions,
    ) -> Self {
        HostPixels {
            gpu,
            r,
            frame,
            opts,
            cam: super::tiles::Camera::new(view),
            world_to_camera: view.world_to_camera,
            dirs: crate::render::raster::PixelDirs::new(&view.intrinsics),
            width: view.intrinsics.width as usize,
        }
    }

    /// The (pixel, triangle) pairs the GPU listed for pixel `i`.
    fn listed(&self, i: usize) -> &'a [[u32; 2]] {
        let pairs = &self.frame.pairs;
        let first = pairs.partition_point(|p| (p[0] as usize) < i);
        let n = pairs[first..].partition_point(|p| p[0] as usize == i);
        &pairs[first..first + n]
    }

    /// Pixel (u, v)'s ray, from the candidate triangles the GPU listed for it with the CPU raster's
    /// edge functions and pairing (traced when none were listed), repaired like the CPU raster's;
    /// `None` (counted as culled) when it is near an edge but inside no triangle.
    fn evaluate(&self, u: usize, v: usize, stats: &mut RenderStats) -> Option<HostRay> {
        use super::rays::{Scratch, trace_single};
        use super::repair;
        use crate::render::pairing::{Crossing, integrate_crossings};
        use crate::render::raster::Edges;

        let r = self.r;
        let mine = self.listed(v * self.width + u);
        let (uf, vf) = (u as f64, v as f64);
        let path = self.dirs.camera_dir(uf, vf).length();
        let mut crossings: Vec<Crossing> = Vec::new();
        for &[_, t] in mine {
            let (g, k) = self.gpu.0.locate(t);
            // The camera-frame corners as the CPU raster projects them (source at the origin).
            let mesh = &r.scene.meshes[g].mesh;
            let corners =
                mesh.triangles[k].map(|c| self.world_to_camera.apply(mesh.vertices[c as usize]));
            let Some(edges) = Edges::new(corners, &self.dirs) else {
                continue;
            };
            let row = edges.row(vf);
            if row.covers(uf) {
                crossings.push(Crossing {
                    t: row.depth(uf) * path,
                    prim: k as u32,
                    geom: g as u16,
                    entry: edges.entry,
                });
            }
        }
        let (mut ray, depth_per_t) = if mine.is_empty() {
            // Not listed although the sums are unusable (the shader lists every such pixel; this only
            // guards against a driver that loses writes): traced.
            let dir = self.cam.dir(uf, vf);
            let scratch = &mut Scratch::new();
            let ray = trace_single(r.ray_tracer(), &r.scene, self.cam.source, dir, scratch);
            (ray, dir.dot(self.cam.axis_z))
        } else if crossings.is_empty() {
            // Near an edge, but inside no triangle.
            stats.rays_culled += 1;
            return None;
        } else {
            (
                integrate_crossings(&r.scene, &mut crossings, self.opts.masks),
                1.0 / path,
            )
        };
        if !ray.valid {
            ray = repair::repair(r.ray_tracer(), &r.scene, &self.cam, (uf, vf), ray, stats);
        }
        stats.rays_traced += 1;
        stats.hits += u64::from(ray.hits);
        Some(HostRay { ray, depth_per_t })
    }
}

/// The rows of an optional output (`w` values each), or endless empty rows when it was not asked for.
#[cfg(feature = "gpu")]
fn rows_of<T>(x: &mut [T], w: usize) -> impl Iterator<Item = &mut [T]> {
    x.chunks_mut(w.max(1))
        .chain(std::iter::repeat_with(|| &mut [][..]))
}
