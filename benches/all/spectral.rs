//! Spectral-DRR benchmarks (issue #32): a 1024² polychromatic DRR of the L1–L5 phantom (80 kV TASMIP,
//! 2.5 mm Al, 0.6 mm CsI) against the monochromatic DRR of the phantom with the raster: the phantom alone,
//! with two titanium pedicle screws per level (the criterion: ≤ 3× the monochromatic DRR), and
//! with the screws and the soft-tissue outline (every pixel attenuates: the energy sum's worst case). The
//! monochromatic DRR has no screws (what a registration system renders). Run with
//! `cargo bench --bench all -- spectral`; the summary lines give the channel renders and the energy sum
//! apart, and the ratio to the monochromatic DRR.

use criterion::Criterion;
use spinedrr::anatomy::{PhantomOptions, build_phantom, parse_levels};
use spinedrr::geometry::CArm;
use spinedrr::render::{
    Backend, SpectralRenderer, ThicknessOptions, add_pedicle_screws, phantom_scene,
    phantom_spectral_scene,
};
use spinedrr::spectral::model_from_specs;

/// This module's benchmarks (see `main.rs`).
pub fn run(c: &mut Criterion) {
    let carm = CArm::default_paper();
    let drr = ThicknessOptions::image_only();
    for (soft_tissue, screws) in [(false, false), (false, true), (true, true)] {
        let opts = PhantomOptions {
            levels: parse_levels("L1-L5").expect("levels"),
            soft_tissue,
            ..PhantomOptions::default()
        };
        let phantom = build_phantom(&opts).expect("phantom");
        let mono = Backend::Raster
            .renderer(phantom_scene(&phantom).expect("scene"))
            .expect("renderer");
        let model = model_from_specs("80", "al:2.5", "csi:0.6").expect("model");
        let bins = model.bins();
        let mut scene = phantom_spectral_scene(&phantom).expect("spectral scene");
        if screws {
            add_pedicle_screws(&mut scene, &phantom).expect("screws");
        }
        let spectral =
            SpectralRenderer::new(&scene, model, Backend::Raster).expect("spectral renderer");
        let label = match (soft_tissue, screws) {
            (false, false) => "L1-L5",
            (false, true) => "L1-L5+screws",
            _ => "L1-L5+screws+soft",
        };
        for view_name in ["ap", "lat"] {
            let view = carm.view(view_name).expect("view");
            let (mut mono_ms, mut ch_ms, mut sum_ms) =
                (f64::INFINITY, f64::INFINITY, f64::INFINITY);
            for _ in 0..9 {
                mono_ms = mono_ms.min(mono.render(view, &drr).expect("render").stats.render_ms);
                let s = spectral.render(view).expect("spectral");
                ch_ms = ch_ms.min(s.channels_ms);
                sum_ms = sum_ms.min(s.energy_sum_ms);
            }
            eprintln!(
                "summary spectral {label:17} {view_name:3} bins {bins} channels {}  mono {mono_ms:7.2} ms  \
                 channel renders {ch_ms:7.2} ms  energy sum {sum_ms:7.2} ms  ratio {:.2}",
                spectral.channels.len(),
                (ch_ms + sum_ms) / mono_ms
            );
            let mut g = c.benchmark_group(format!("spectral/{label}/{view_name}"));
            g.sample_size(10);
            g.bench_function("monochromatic", |b| {
                b.iter(|| mono.render(view, &drr).expect("render"))
            });
            g.bench_function("spectral_80kv", |b| {
                b.iter(|| spectral.render(view).expect("spectral"))
            });
            g.finish();
        }
    }
}
