//! The Rust side of the Python-overhead comparison (issue 17): the 1024² AP DRR of phantom L3 (no
//! discs) with the raster backend, renderer built once, the line integral alone: exactly what
//! `spinedrr.Renderer(spinedrr.phantom("L3", discs=False).scene).render(carm.view("ap"))` does.
//! `python/benches/overhead.py` times that call in a Python loop; compare its mean with this one.
//! Run with `cargo bench --bench all -- python_overhead`.

use criterion::{Criterion, Throughput};
use spinedrr::anatomy::{PhantomOptions, build_phantom, parse_levels};
use spinedrr::geometry::CArm;
use spinedrr::render::{Backend, ThicknessOptions, ThicknessRenderer, phantom_scene};

/// This module's benchmarks (see `main.rs`).
pub fn run(c: &mut Criterion) {
    let opts = PhantomOptions {
        levels: parse_levels("L3").expect("levels"),
        discs: false,
        ..PhantomOptions::default()
    };
    let scene = phantom_scene(&build_phantom(&opts).expect("phantom")).expect("scene");
    let renderer: ThicknessRenderer = Backend::Raster.renderer(scene).expect("renderer");
    let view = CArm::default_paper().view("ap").expect("view").clone();
    let drr = ThicknessOptions::image_only();
    let mut g = c.benchmark_group("python_overhead/L3/ap");
    g.sample_size(50);
    g.throughput(Throughput::Elements(1024 * 1024));
    g.bench_function("raster", |b| {
        b.iter(|| renderer.render(&view, &drr).expect("render"))
    });
    g.finish();
}
