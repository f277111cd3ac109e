//! Thickness-DRR benchmarks: 1024² AP and LAT renders of phantom L3 and of the L1–L5 segment with both
//! backends, Embree's closest-hit floor for the same pixels, and BVH build times.
//!
//! Run with `cargo bench --bench render`. Before the timed groups it prints one line per configuration
//! with rays traced, hits, rays/s, hits/s and the build time, the numbers the README table reports.

use std::time::Instant;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use spinedrr::anatomy::{PhantomOptions, build_phantom, parse_levels};
use spinedrr::geometry::CArm;
use spinedrr::render::embree::EmbreeScene;
use spinedrr::render::{Backend, RenderScene, ThicknessOptions, phantom_scene};

fn scene(levels: &str) -> RenderScene {
    let opts = PhantomOptions {
        levels: parse_levels(levels).expect("levels"),
        discs: false,
        ..PhantomOptions::default()
    };
    phantom_scene(&build_phantom(&opts).expect("phantom")).expect("scene")
}

fn bench_render(c: &mut Criterion) {
    let carm = CArm::default_paper();
    let opts = ThicknessOptions::default();
    for (label, levels) in [("L3", "L3"), ("L1-L5", "L1-L5")] {
        let scene = scene(levels);
        let tris = scene.triangle_count();
        let floor_scene = EmbreeScene::new(&scene, false).expect("floor scene");
        for backend in [Backend::Embree, Backend::Bvh] {
            let t0 = Instant::now();
            let r = backend.renderer(scene.clone()).expect("renderer");
            let build_ms = t0.elapsed().as_secs_f64() * 1e3;
            for view_name in ["ap", "lat"] {
                let view = carm.view(view_name).expect("view");
                let drr = r.render(view, &opts).expect("render");
                let s = drr.stats;
                let mut best = f64::INFINITY;
                for _ in 0..5 {
                    best = best.min(r.render(view, &opts).expect("render").stats.render_ms);
                }
                let (_, floor_ms) = if backend == Backend::Embree {
                    (0..5)
                        .map(|_| r.first_hit_floor(&floor_scene, view, &opts))
                        .min_by(|a, b| a.1.total_cmp(&b.1))
                        .expect("five runs")
                } else {
                    (drr.depth.clone(), f64::NAN)
                };
                eprintln!(
                    "summary {label:6} {view_name:3} {:6} tris {tris:6} build {build_ms:7.1} ms  best {best:7.2} ms  \
                     rays {:7} ({:.1} M/s)  hits {:7} ({:.1} M/s)  repaired {}  first-hit floor {floor_ms:.2} ms",
                    backend_name(backend),
                    s.rays_traced,
                    s.rays_traced as f64 / best / 1e3,
                    s.hits,
                    s.hits as f64 / best / 1e3,
                    s.rays_repaired,
                );
                let mut g = c.benchmark_group(format!("render/{label}/{view_name}"));
                g.sample_size(20);
                g.throughput(Throughput::Elements(s.rays_traced));
                g.bench_function(backend_name(backend), |b| {
                    b.iter(|| r.render(view, &opts).expect("render"))
                });
                if backend == Backend::Embree {
                    g.bench_function("embree_first_hit_floor", |b| {
                        b.iter(|| r.first_hit_floor(&floor_scene, view, &opts))
                    });
                }
                g.finish();
            }
        }
        let mut g = c.benchmark_group(format!("bvh_build/{label}"));
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

fn backend_name(b: Backend) -> &'static str {
    match b {
        Backend::Embree => "embree",
        Backend::Bvh => "bvh",
    }
}

criterion_group!(benches, bench_render);
criterion_main!(benches);
