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
    /// raster's value exactly (repaired like it when its crossings do not pair).
    pub(super) fn render(
        &self,
        r: &ThicknessRenderer,
        view: &View,
        opts: &ThicknessOptions,
        out: Outputs,
    ) -> Result<Option<RenderStats>> {
        use rayon::prelude::*;

        use super::rays::{Scratch, trace_single};
        use super::repair;
        use super::tiles::Camera;
        use crate::render::pairing::{Crossing, MIN_SILHOUETTE_CHORD_MM, integrate_crossings};
        use crate::render::raster::{Edges, PixelDirs};

        let start = std::time::Instant::now();
        let Some(frame) = self.0.rasterise(&r.scene, view, opts.masks || opts.depth)? else {
            return Ok(None);
        };
        let cam = Camera::new(view);
        let dirs = PixelDirs::new(&view.intrinsics);
        let w = view.intrinsics.width as usize;
        let rows: Vec<_> = out
            .li
            .chunks_mut(w)
            .zip(rows_of(out.depth, w))
            .zip(rows_of(out.obj, w))
            .zip(rows_of(out.st, w))
            .collect();
        let stats = rows
            .into_par_iter()
            .enumerate()
            .map(|(v, (((li, depth), obj), st))| {
                let mut stats = RenderStats::default();
                let mut crossings: Vec<Crossing> = Vec::new();
                let scratch = &mut Scratch::new();
                // This row's share of the host's (pixel, triangle) pairs.
                let first = frame.pairs.partition_point(|p| (p[0] as usize) < v * w);
                let mut pairs = &frame.pairs[first..];
                for (u, li) in li.iter_mut().enumerate() {
                    let i = v * w + u;
                    let n = pairs.partition_point(|p| p[0] as usize == i);
                    let (mine, rest) = pairs.split_at(n);
                    pairs = rest;
                    if !frame.touched(i) {
                        stats.rays_culled += 1;
                        continue;
                    }
                    // The shader lists the triangles of every pixel the host must evaluate.
                    if mine.is_empty() && frame.balanced(i) {
                        stats.rays_traced += 1;
                        stats.hits += u64::from(frame.crossings(i));
                        let path = dirs.camera_dir(u as f64, v as f64).length();
                        *li = (frame.sum(i) * path) as f32;
                        if frame.stride > 4 {
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
                        }
                        continue;
                    }
                    // The CPU raster's crossings of this pixel, from the candidates the GPU listed.
                    let (uf, vf) = (u as f64, v as f64);
                    let path = dirs.camera_dir(uf, vf).length();
                    // Camera depth per unit of the ray's `t`.
                    let path_of_t;
                    crossings.clear();
                    for &[_, t] in mine {
                        let (g, k) = self.0.locate(t);
                        let first = self.0.vertex_start(g);
                        let corners = r.scene.meshes[g].mesh.triangles[k]
                            .map(|c| frame.cam[first + c as usize]);
                        let Some(edges) = Edges::new(corners, &dirs) else {
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
                    let mut ray = if mine.is_empty() {
                        // Not listed although the sums are unusable (the shader lists every such
                        // pixel; this only guards against a driver that loses writes): traced.
                        let dir = cam.dir(uf, vf);
                        let ray = trace_single(r.ray_tracer(), &r.scene, cam.source, dir, scratch);
                        path_of_t = dir.dot(cam.axis_z);
                        ray
                    } else if crossings.is_empty() {
                        // Near an edge, but inside no triangle.
                        stats.rays_culled += 1;
                        continue;
                    } else {
                        path_of_t = 1.0 / path;
                        integrate_crossings(&r.scene, &mut crossings, opts.masks)
                    };
                    if !ray.valid {
                        ray = repair::repair(
                            r.ray_tracer(),
                            &r.scene,
                            &cam,
                            (uf, vf),
                            ray,
                            &mut stats,
                        );
                    }
                    stats.rays_traced += 1;
                    stats.hits += u64::from(ray.hits);
                    *li = ray.line_integral as f32;
                    if let Some(d) = depth.get_mut(u)
                        && ray.first_t.is_finite()
                    {
                        *d = (ray.first_t * path_of_t) as f32;
                    }
                    if let (Some(o), Some(s)) = (obj.get_mut(u), st.get_mut(u)) {
                        (*o, *s) = (ray.object_bits, ray.structure_bits);
                    }
                }
                stats
            })
            .reduce(RenderStats::default, RenderStats::add);
        Ok(Some(RenderStats {
            render_ms: start.elapsed().as_secs_f64() * 1e3,
            ..stats
        }))
    }
}

/// The rows of an optional output (`w` values each), or endless empty rows when it was not asked for.
#[cfg(feature = "gpu")]
fn rows_of<T>(x: &mut [T], w: usize) -> impl Iterator<Item = &mut [T]> {
    x.chunks_mut(w.max(1))
        .chain(std::iter::repeat_with(|| &mut [][..]))
}
