//! All metrics for a pair of 1024² images (target ≤ 150 ms), and the parts separately.

use criterion::Criterion;
use glam::{DVec2, DVec3};
use spinedrr::analysis::{
    Landmark, MaskPair, compare, gradient_correlation, image_metrics, mutual_information, ncc,
    silhouette_metrics, ssim,
};
use spinedrr::geometry::{CArm, Perturbation};
use spinedrr::io::ImageF32;

const N: u32 = 1024;

/// A vertebra-sized elliptical "DRR" (thickness of an ellipsoid) and its silhouette.
fn drr(centre: DVec2, scale: f64) -> (ImageF32, Vec<bool>) {
    let mut img = ImageF32::zeros(N, N);
    let mut mask = vec![false; (N * N) as usize];
    let (a, b) = (190.0 * scale, 130.0 * scale);
    for v in 0..N {
        for u in 0..N {
            let d = (DVec2::new(u as f64, v as f64) - centre) / DVec2::new(a, b);
            let q = 1.0 - d.length_squared();
            let i = (v * N + u) as usize;
            img.data[i] = (40.0 * q.max(0.0).sqrt()) as f32;
            mask[i] = q >= 0.0;
        }
    }
    (img, mask)
}

/// This module's benchmarks (see `main.rs`).
pub fn run(c: &mut Criterion) {
    let (a, ma) = drr(DVec2::new(511.5, 511.5), 1.0);
    let (b, mb) = drr(DVec2::new(520.0, 505.0), 1.067);
    let masks = vec![MaskPair {
        name: "vertebra".into(),
        width: N,
        height: N,
        reference: ma,
        perturbed: mb,
    }];
    let carm = CArm::default_paper();
    let ap = carm.view("ap").unwrap();
    let pert = ap.perturbed(&Perturbation::focal(300.0)).unwrap();
    let lms: Vec<Landmark> = (0..10)
        .map(|i| Landmark {
            name: format!("l{i}"),
            position: DVec3::new(i as f64 * 3.0, 0.0, 10.0 - i as f64),
        })
        .collect();
    let mut g = c.benchmark_group("metrics/1024²");
    g.sample_size(20);
    g.bench_function("all metrics (compare)", |bn| {
        bn.iter(|| compare(&a, &b, &masks, &lms, Some((ap, &pert))).unwrap())
    });
    g.bench_function("image metrics", |bn| {
        bn.iter(|| image_metrics(&a, &b).unwrap())
    });
    g.bench_function("silhouette metrics", |bn| {
        bn.iter(|| silhouette_metrics(&masks[0]).unwrap())
    });
    g.bench_function("ncc", |bn| bn.iter(|| ncc(&a, &b).unwrap()));
    g.bench_function("ssim", |bn| bn.iter(|| ssim(&a, &b).unwrap()));
    g.bench_function("mutual information", |bn| {
        bn.iter(|| mutual_information(&a, &b, 64).unwrap())
    });
    g.bench_function("gradient correlation", |bn| {
        bn.iter(|| gradient_correlation(&a, &b).unwrap())
    });
    g.finish();
}
