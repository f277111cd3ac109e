//! One view's setup for the mesh shader ([`ViewSetup`]): each mesh's reference depth, the vertices'
//! pixel positions when the host projects them, and the fixed-point scales that keep every pixel's sum
//! from overflowing (see `mesh.rs`).

use glam::DVec3;
use rayon::prelude::*;

use crate::geometry::View;
use crate::render::pairing::MIN_SILHOUETTE_CHORD_MM;
use crate::render::raster::MIN_DEPTH_MM;
use crate::render::scene::RenderScene;

/// How far from the silhouette threshold (mm) a chord summed on the GPU can be from the CPU's: the
/// pixel is then evaluated by the host (the GPU's depths are within ~1e-5 mm of the CPU's).
const CHORD_MARGIN_MM: f64 = 1e-4;

/// Where the scene's vertices lie in the GPU's vertex buffer, and each mesh's bounding box.
pub(super) struct SceneLayout {
    /// First global vertex of each mesh, and the total vertices.
    pub vertex_start: Vec<usize>,
    pub vertices: usize,
    /// Each mesh's bounding box (world frame).
    pub bounds: Vec<Option<(DVec3, DVec3)>>,
}

/// What a render of one view needs before its passes.
pub(super) struct ViewSetup {
    /// Per mesh its reference depth (its bounding box's centre).
    pub z_ref: Vec<f64>,
    /// The GPU projects the vertices (else `verts` holds the host's projections).
    pub on_gpu: bool,
    /// Per vertex, when the host projects, (u_hi, v_hi, u_lo, v_lo), (z, z − z_ref, 0, 0).
    pub verts: Vec<[f32; 4]>,
    /// The fixed-point scales of the sum and of the chords.
    pub scale: f64,
    pub chord_scale: f64,
    /// The chords (i32 bits, in units of `chord_scale`) within rounding of the silhouette threshold.
    pub chord_band: [u32; 2],
}

impl SceneLayout {
    /// `view`'s setup of `scene` (whose vertices this lays out), the GPU projecting the vertices when
    /// `gpu_projects` and every bounding box lies in front of the source plane; `None` when a vertex
    /// lies at or behind it (no finite projection).
    pub(super) fn setup(
        &self,
        scene: &RenderScene,
        view: &View,
        gpu_projects: bool,
    ) -> Option<ViewSetup> {
        let intr = &view.intrinsics;
        let (w, h) = (intr.width, intr.height);
        // Per mesh its reference depth (its bounding box's centre) and its depth extent; per vertex,
        // when the host projects, (u_hi, v_hi, u_lo, v_lo), (z, z − z_ref, 0, 0).
        let z_ref: Vec<f64> = self
            .bounds
            .iter()
            .map(|b| b.map_or(0.0, |(a, b)| view.depth(0.5 * (a + b))))
            .collect();
        // The GPU projects when it computes in f64 and every bounding box lies in front of the source
        // plane (then so does every vertex: depth is linear, the box convex).
        let corners = |(a, b): (DVec3, DVec3)| {
            (0..8).map(move |c| {
                let pick = |bit: usize, lo: f64, hi: f64| if c >> bit & 1 == 0 { lo } else { hi };
                view.depth(DVec3::new(
                    pick(0, a.x, b.x),
                    pick(1, a.y, b.y),
                    pick(2, a.z, b.z),
                ))
            })
        };
        let on_gpu = gpu_projects
            && self
                .bounds
                .iter()
                .flatten()
                .all(|&b| corners(b).all(|z| z > MIN_DEPTH_MM));
        let mut verts = if on_gpu {
            Vec::new()
        } else {
            vec![[0f32; 4]; 2 * self.vertices]
        };
        let mut extent = Vec::with_capacity(scene.meshes.len());
        for (g, m) in scene.meshes.iter().enumerate() {
            if on_gpu {
                // The box's depth range bounds the vertices'.
                let (lo, hi) = self.bounds[g].map_or((0.0, 0.0), |b| {
                    corners(b).fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), z| {
                        (lo.min(z), hi.max(z))
                    })
                });
                extent.push(hi - lo);
                continue;
            }
            let start = self.vertex_start[g];
            let n = m.mesh.vertices.len();
            let out = &mut verts[2 * start..2 * (start + n)];
            let z_ref = z_ref[g];
            let (lo, hi, ok) = out
                .par_chunks_mut(2)
                .zip(m.mesh.vertices.par_iter())
                .with_min_len(4096)
                .map(|(o, &p)| {
                    let c = view.world_to_camera.apply(p);
                    let px = intr.project_camera(c);
                    let (u_hi, u_lo) = split(px.x);
                    let (v_hi, v_lo) = split(px.y);
                    let dz = c.z - z_ref;
                    o[0] = [u_hi, v_hi, u_lo, v_lo];
                    o[1] = [c.z as f32, dz as f32, 0.0, 0.0];
                    (dz, dz, c.z > MIN_DEPTH_MM && px.is_finite())
                })
                .reduce(
                    || (f64::INFINITY, f64::NEG_INFINITY, true),
                    |a, b| (a.0.min(b.0), a.1.max(b.1), a.2 && b.2),
                );
            if !ok {
                return None;
            }
            extent.push(if hi >= lo { hi - lo } else { 0.0 });
        }
        // A power of two that keeps `bound` below 2³⁰ units.
        let scale_for = |bound: f64| {
            (f64::from(1u32 << 30) / (bound * (1.0 + 1e-6) + 1e-30))
                .log2()
                .floor()
                .exp2()
                .clamp(2f64.powi(-100), 2f64.powi(100))
        };
        // Every pixel's total |Σ ± μ·depth| is at most Σ μ·extent, a mesh's chord at most its extent.
        let scale = scale_for(
            scene
                .meshes
                .iter()
                .zip(&extent)
                .map(|(m, e)| m.mu_per_mm.abs() * e)
                .sum(),
        );
        let chord_scale = scale_for(extent.iter().fold(0.0, |a: f64, &b| a.max(b)));
        // The chords (depth, mm) within rounding of the silhouette threshold (ray length, mm): a ray's
        // length per mm of depth is |K⁻¹ (u, v, 1)| ≥ 1, at most its value at the farthest corner.
        let path_max = [
            (0.0, 0.0),
            (f64::from(w), 0.0),
            (0.0, f64::from(h)),
            (f64::from(w), f64::from(h)),
        ]
        .map(|(u, v)| intr.back_project(u, v).length())
        .into_iter()
        .fold(1.0, f64::max);
        let chord_band = [
            (MIN_SILHOUETTE_CHORD_MM / path_max - CHORD_MARGIN_MM) * chord_scale,
            (MIN_SILHOUETTE_CHORD_MM + CHORD_MARGIN_MM) * chord_scale,
        ]
        .map(|c| (c.round() as i32).cast_unsigned());
        Some(ViewSetup {
            z_ref,
            on_gpu,
            verts,
            scale,
            chord_scale,
            chord_band,
        })
    }
}

/// `v` as `hi + lo` in f32 (hi the nearest f32, lo the rest rounded).
fn split(v: f64) -> (f32, f32) {
    let hi = v as f32;
    (hi, (v - f64::from(hi)) as f32)
}
