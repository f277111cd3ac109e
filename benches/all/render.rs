//! Thickness-DRR benchmarks: 1024² AP and LAT renders of phantom L3 and of the L1–L5 segment with every
//! backend (Embree, the reference BVH, the raster), Embree's closest-hit floor for the same pixels, and
//! acceleration-structure build times.
//!
//! The timed renders produce the DRR (line-integral image); the summary lines also give the time with
//! every output (silhouette masks and depth map). Run with `cargo bench --bench all -- render`. Before the
//! timed groups it prints one line per configuration with rays traced, hits, rays/s, hits/s and the build
//! time, the numbers the README table reports.

use std::time::Instant;

use criterion::{Criterion, Throughput};
use spinedrr::anatomy::{PhantomOptions, build_phantom, parse_levels};
use spinedrr::geometry::CArm;
use spinedrr::render::embree::EmbreeScene;
use spinedrr::render::{Backend, RenderScene, ThicknessOptions, ThicknessRenderer, phantom_scene};

const BACKENDS: [Backend; 3] = [Backend::Embree, Backend::Raster, Backend::Bvh];

fn scene(levels: &str) -> RenderScene {
    let opts = PhantomOptions {
        levels: parse_levels(levels).expect("levels"),
        discs: false,
        ..PhantomOptions::default()
    };
    phantom_scene(&build_phantom(&opts).expect("phantom")).expect("scene")
}

/// Best of `n` calls of `f` (ms).
fn best_ms(n: usize, mut f: impl FnMut() -> f64) -> f64 {
    (0..n).map(|_| f()).fold(f64::INFINITY, f64::min)
}

/// This module's benchmarks (see `main.rs`).
pub fn run(c: &mut Criterion) {
    let carm = CArm::default_paper();
    let drr = ThicknessOptions::image_only();
    let full = ThicknessOptions::default();
    for (label, levels) in [("L3", "L3"), ("L1-L5", "L1-L5")] {
        let scene = scene(levels);
        let tris = scene.triangle_count();
        let floor_scene = EmbreeScene::new(&scene, false).expect("floor scene");
        let renderers: Vec<(Backend, ThicknessRenderer, f64)> = BACKENDS
            .iter()
            .map(|&b| {
                let t0 = Instant::now();
                let r = b.renderer(scene.clone()).expect("renderer");
                (b, r, t0.elapsed().as_secs_f64() * 1e3)
            })
            .collect();
        for view_name in ["ap", "lat"] {
            let view = carm.view(view_name).expect("view");
            // The floor is timed interleaved with each backend's renders, so that a slow spell of a
            // shared machine affects both sides of the ratio alike.
            for (backend, r, build_ms) in &renderers {
                let s = r.render(view, &drr).expect("render").stats;
                let (mut best, mut floor_ms) = (f64::INFINITY, f64::INFINITY);
                for _ in 0..15 {
                    floor_ms = floor_ms.min(floor_scene.first_hit_floor(&scene, view, &drr).1);
                    best = best.min(r.render(view, &drr).expect("render").stats.render_ms);
                }
                let best_full =
                    best_ms(7, || r.render(view, &full).expect("render").stats.render_ms);
                eprintln!(
                    "summary {label:6} {view_name:3} {:6} tris {tris:6} build {build_ms:7.1} ms  drr {best:7.2} ms  \
                     with masks+depth {best_full:7.2} ms  rays {:7} ({:.1} M/s)  hits {:7} ({:.1} M/s)  \
                     repaired {}  first-hit floor {floor_ms:.2} ms  ratio {:.2}",
                    backend.name(),
                    s.rays_traced,
                    s.rays_traced as f64 / best / 1e3,
                    s.hits,
                    s.hits as f64 / best / 1e3,
                    s.rays_repaired,
                    best / floor_ms,
                );
            }
            let mut g = c.benchmark_group(format!("render/{label}/{view_name}"));
            g.sample_size(20);
            for (backend, r, _) in &renderers {
                g.throughput(Throughput::Elements(1024 * 1024));
                g.bench_function(backend.name(), |b| {
                    b.iter(|| r.render(view, &drr).expect("render"))
                });
            }
            g.bench_function("embree_first_hit_floor", |b| {
                b.iter(|| floor_scene.first_hit_floor(&scene, view, &drr))
            });
            g.finish();
        }
        let mut g = c.benchmark_group(format!("render/bvh_build/{label}"));
        g.sample_size(10);
        g.bench_function("embree", |b| {
            b.iter(|| Backend::Embree.renderer(scene.clone()).expect("build"))
        });
        g.bench_function("bvh", |b| {
            b.iter(|| Backend::Bvh.renderer(scene.clone()).expect("build"))
        });
        g.finish();
    }
}
