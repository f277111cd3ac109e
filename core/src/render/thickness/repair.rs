//! Rays whose surface crossings do not pair up (a hit lost at an edge or vertex): retraced with tiny
//! sub-pixel offsets, and failing that kept within [0, Σ |μ|·longest chord] of its meshes.

use super::output::RenderStats;
use super::rays::{Scratch, trace_single};
use super::tiles::Camera;
use crate::render::pairing::RayIntegral;
use crate::render::scene::RenderScene;
use crate::render::tracer::HitTracer;

/// Sub-pixel offsets (pixels) tried in turn when a ray's crossings do not pair up.
const REPAIR_OFFSETS: [(f64, f64); 4] = [
    (1.3e-4, 0.7e-4),
    (-0.9e-4, 1.1e-4),
    (0.6e-4, -1.4e-4),
    (-1.2e-4, -0.8e-4),
];

/// Retraces the ray through pixel position (u, v), whose integral `first` did not pair up, with each
/// offset of [`REPAIR_OFFSETS`]; the first that pairs up is the pixel's value (counted as repaired). If
/// none does, `first` is kept with its line integral clamped to `±Σ_m |μ_m| · chord_m` (counted as
/// unrepaired).
pub(super) fn repair(
    tracer: &dyn HitTracer,
    scene: &RenderScene,
    cam: &Camera,
    (u, v): (f64, f64),
    first: RayIntegral,
    stats: &mut RenderStats,
) -> RayIntegral {
    let mut scratch = Scratch::new();
    for (du, dv) in REPAIR_OFFSETS {
        let ray = trace_single(
            tracer,
            scene,
            cam.source,
            cam.dir(u + du, v + dv),
            &mut scratch,
        );
        if ray.valid {
            stats.rays_repaired += 1;
            return ray;
        }
    }
    stats.rays_unrepaired += 1;
    let cap: f64 = scene
        .meshes
        .iter()
        .zip(&scene.max_chord)
        .map(|(m, c)| m.mu_per_mm.abs() * c)
        .sum();
    // A physical scene's line integral is never negative (differential μ of nested surfaces sums to
    // the outer tissue's μ or more): an unpaired ray's sum is kept within [0, cap].
    RayIntegral {
        line_integral: first.line_integral.clamp(0.0, cap),
        ..first
    }
}
