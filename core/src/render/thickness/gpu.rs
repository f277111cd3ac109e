//! A thickness render on the GPU backend: the GPU's signed-depth sums
//! (`render::gpu::GpuMeshRenderer`) turned into the renderer's outputs, and the few pixels the sums
//! cannot give (crossings that do not balance, a centre near an edge, a ray an implant may meet: an
//! implant displaces what it occupies) evaluated on the CPU exactly as the CPU raster evaluates them.
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
    /// raster's value exactly (repaired like it when its crossings do not pair). Every other pixel is
    /// finished on the GPU (its line integral, and with depth or masks its silhouettes and depth: one
    /// f32 or five words per pixel come back), and the host visits only the listed pixels.
    pub(super) fn render(
        &self,
        r: &ThicknessRenderer,
        view: &View,
        opts: &ThicknessOptions,
        out: Outputs,
    ) -> Result<Option<RenderStats>> {
        use rayon::prelude::*;

        let start = std::time::Instant::now();
        let Some(frame) = self.0.rasterise(&r.scene, view, opts.masks || opts.depth)? else {
            return Ok(None);
        };
        let done = &frame.finished;
        // The GPU's pixels: the line integral, and with depth or masks its silhouettes and depth.
        out.li.copy_from_slice(&done.image);
        // `extra`: per pixel the depth (f32 bits, +inf: none), the object bits (two words) and the
        // structure bits (empty without depth and masks).
        let extra = &done.extra;
        if !extra.is_empty() {
            out.depth.par_iter_mut().enumerate().for_each(|(i, d)| {
                let z = f32::from_bits(extra[4 * i]);
                if z.is_finite() {
                    *d = z;
                }
            });
            let masks = out.obj.par_iter_mut().zip(out.st.par_iter_mut());
            masks.enumerate().for_each(|(i, (o, s))| {
                let e = &extra[4 * i..4 * i + 4];
                (*o, *s) = (u64::from(e[1]) | u64::from(e[2]) << 32, e[3]);
            });
        }
        let (rays, mut stats) = self.host_pixels(r, view, &frame, opts);
        for (i, ray) in rays {
            let Some((ray, depth_per_t)) = ray else {
                continue;
            };
            out.li[i] = ray.line_integral as f32;
            if let Some(d) = out.depth.get_mut(i)
                && ray.first_t.is_finite()
            {
                *d = (ray.first_t * depth_per_t) as f32;
            }
            if let (Some(o), Some(s)) = (out.obj.get_mut(i), out.st.get_mut(i)) {
                (*o, *s) = (ray.object_bits, ray.structure_bits);
            }
        }
        stats.render_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(Some(stats))
    }

    /// [`Self::render`]'s line integral left on the GPU, in the f32 image at byte `offset` of `image`:
    /// the GPU's finished pixels copied there, the host's evaluated and scattered in (only the lists come
    /// back). `None` when the GPU cannot take the view.
    pub(super) fn line_integral_onto(
        &self,
        r: &ThicknessRenderer,
        view: &View,
        image: &wgpu::Buffer,
        offset: u64,
    ) -> Result<Option<RenderStats>> {
        let start = std::time::Instant::now();
        let Some(frame) = self.0.rasterise_onto(&r.scene, view, image, offset)? else {
            return Ok(None);
        };
        let (rays, mut stats) = self.host_pixels(r, view, &frame, &ThicknessOptions::image_only());
        let values: Vec<(u32, f32)> = rays
            .into_iter()
            .map(|(i, ray)| {
                (
                    i as u32,
                    ray.map_or(0.0, |(ray, _)| ray.line_integral as f32),
                )
            })
            .collect();
        crate::render::gpu::scatter(self.0.context(), image, offset, &values)?;
        stats.render_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(Some(stats))
    }

    /// The host's pixels of `frame`, evaluated in parallel (each with its ray and camera depth per unit
    /// of `t`, `None` when culled), and the render's counters.
    #[allow(clippy::type_complexity)]
    fn host_pixels(
        &self,
        r: &ThicknessRenderer,
        view: &View,
        frame: &crate::render::gpu::GpuFrame,
        opts: &ThicknessOptions,
    ) -> (
        Vec<(usize, Option<(crate::render::pairing::RayIntegral, f64)>)>,
        RenderStats,
    ) {
        use rayon::prelude::*;

        let host = HostPixels::new(self, r, view, frame, opts);
        let done = &frame.finished;
        let w = view.intrinsics.width as usize;
        let rays: Vec<_> = done
            .pixels
            .par_iter()
            .map(|&i| {
                let i = i as usize;
                let mut stats = RenderStats::default();
                let ray = host.evaluate(i % w, i / w, &mut stats);
                (i, ray, stats)
            })
            .collect();
        let mut stats = RenderStats {
            rays_traced: u64::from(done.rays),
            hits: done.hits,
            gpu_rays_on_cpu: Some(done.pixels.len() as u64),
            ..RenderStats::default()
        };
        let rays = rays
            .into_iter()
            .map(|(i, ray, s)| {
                stats = stats.add(s);
                (i, ray)
            })
            .collect();
        // Every ray not traced was culled (untouched, or near an edge but inside no triangle).
        let pixels = (w * view.intrinsics.height as usize) as u64;
        stats.rays_culled = pixels - stats.rays_traced;
        (rays, stats)
    }
}

#[cfg(feature = "gpu")]
impl ThicknessRenderer {
    /// The GPU device of a gpu-backend renderer, else `None`.
    pub(crate) fn gpu_context(&self) -> Option<&std::sync::Arc<crate::render::gpu::GpuContext>> {
        match &self.gather {
            super::Gather::Raster { gpu: Some(g), .. } => Some(g.0.context()),
            _ => None,
        }
    }

    /// The line integral of `view` into the f32 image at byte `offset` of `image` on this renderer's
    /// GPU (a registration level evaluated there): with `summed`, the GPU's signed sums with the host's
    /// pixels scattered in, as [`ThicknessRenderer::render_line_integral_summed_into`] gives them; else,
    /// and for a view the GPU cannot take, the CPU's paired render, uploaded.
    pub(crate) fn line_integral_onto_gpu(
        &self,
        view: &View,
        image: &wgpu::Buffer,
        offset: u64,
        summed: bool,
    ) -> Result<RenderStats> {
        let super::Gather::Raster { gpu: Some(g), .. } = &self.gather else {
            return Err(crate::Error::Internal(
                "a GPU image from a renderer without the gpu backend".into(),
            ));
        };
        view.intrinsics.validate()?;
        if summed && let Some(stats) = g.line_integral_onto(self, view, image, offset)? {
            return Ok(stats);
        }
        let mut out = crate::io::ImageF32::zeros(0, 0);
        let stats = self.render_line_integral_into(view, &mut out)?;
        g.0.context()
            .queue
            .write_buffer(image, offset, bytemuck::cast_slice(&out.data));
        Ok(stats)
    }
}

/// What the host needs to evaluate the pixels the GPU's sums cannot give, as the CPU raster does.
#[cfg(feature = "gpu")]
struct HostPixels<'a> {
    gpu: &'a GpuRaster,
    r: &'a ThicknessRenderer,
    /// (pixel, global triangle) for every pixel the host evaluates, sorted.
    pairs: &'a [[u32; 2]],
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
            pairs: &frame.pairs,
            opts,
            cam: super::tiles::Camera::new(view),
            world_to_camera: view.world_to_camera,
            dirs: crate::render::raster::PixelDirs::new(&view.intrinsics),
            width: view.intrinsics.width as usize,
        }
    }

    /// The (pixel, triangle) pairs the GPU listed for pixel `i`.
    fn listed(&self, i: usize) -> &'a [[u32; 2]] {
        let pairs = self.pairs;
        let first = pairs.partition_point(|p| (p[0] as usize) < i);
        let n = pairs[first..].partition_point(|p| p[0] as usize == i);
        &pairs[first..first + n]
    }

    /// Pixel (u, v)'s ray, from the candidate triangles the GPU listed for it with the CPU raster's
    /// edge functions and pairing (traced when none were listed), repaired like the CPU raster's, and
    /// the camera depth per unit of its `t`; `None` (a culled ray) when the pixel is near an edge but
    /// inside no triangle.
    fn evaluate(
        &self,
        u: usize,
        v: usize,
        stats: &mut RenderStats,
    ) -> Option<(crate::render::pairing::RayIntegral, f64)> {
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
            // The corners' centred homogeneous pixel coordinates as the CPU raster computes them (source at
            // the origin).
            let mesh = &r.scene.meshes[g].mesh;
            let corners = mesh.triangles[k].map(|c| {
                self.dirs
                    .homogeneous(self.world_to_camera.apply(mesh.vertices[c as usize]))
            });
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
        Some((ray, depth_per_t))
    }
}
