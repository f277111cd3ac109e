//! CT volume DRR speed: 1024² images through a generated 512 × 512 × 133 CT (Siddon, trilinear, and a
//! single-vertebra masked render), surface extraction of one label from a 512 × 512 × 133 label map, and
//! quadric decimation of the phantom's L3 outer surface (~300k triangles) to 40k. The real CT's DRRs are
//! the `real_ct` module.

use std::time::Instant;

use criterion::{Criterion, Throughput};
use glam::{DMat4, DVec3};
use spinedrr::anatomy::ct::{CtVolume, LabelMap, SurfaceOptions, VoxelMask, label_surface};
use spinedrr::anatomy::{Level, PhantomOptions, build_phantom, decimate};
use spinedrr::geometry::CArm;
use spinedrr::render::volume::{VolumeMethod, VolumeRenderOptions, VolumeRenderer};

const DIMS: [usize; 3] = [512, 512, 133];

/// A torso-like CT centred on the world origin: water ellipse, a bone column and one "vertebra" label.
fn phantom_ct() -> (CtVolume, LabelMap) {
    let sp = DVec3::new(0.7, 0.7, 2.5);
    let half = DVec3::new(DIMS[0] as f64, DIMS[1] as f64, DIMS[2] as f64) * 0.5 - 0.5;
    let a = DMat4::from_scale_rotation_translation(sp, Default::default(), -half * sp);
    let mut ct = CtVolume::filled(DIMS, -1000.0, a).unwrap();
    let mut seg = LabelMap::filled(DIMS, 0, a).unwrap();
    for k in 0..DIMS[2] {
        for j in 0..DIMS[1] {
            for i in 0..DIMS[0] {
                let p = ct.voxel_centre(i, j, k);
                let n = ct.linear(i, j, k);
                if (p.x / 160.0).powi(2) + (p.y / 110.0).powi(2) <= 1.0 {
                    ct.values[n] = 40.0;
                }
                if (p.x / 25.0).powi(2) + ((p.y + 10.0) / 18.0).powi(2) <= 1.0 {
                    ct.values[n] = 300.0 + 900.0 * (((p.z / 30.0).sin()).abs() as f32);
                    seg.values[n] = if p.z.abs() < 14.0 { 31 } else { 30 };
                }
            }
        }
    }
    (ct, seg)
}

/// This module's benchmarks (see `main.rs`).
pub fn run(c: &mut Criterion) {
    let (ct, seg) = phantom_ct();
    let view = CArm::default_paper().view("ap").unwrap().clone();
    let mask = VoxelMask::from_labels(&seg, &[31]).unwrap();
    // Full-volume 1024² renders take seconds each: time them directly (best of three) and print a summary
    // line with ms per image and voxel visits per second; criterion times the fast masked render.
    for (name, method) in [
        ("siddon", VolumeMethod::Siddon),
        ("trilinear", VolumeMethod::Trilinear),
    ] {
        let opts = VolumeRenderOptions {
            method,
            ..Default::default()
        };
        let r = VolumeRenderer::new(&ct, &opts, None).unwrap();
        // The first render also builds Siddon's running sums along the view's dominant axis.
        let times: Vec<f64> = (0..3)
            .map(|_| {
                let t = Instant::now();
                std::hint::black_box(r.render(&view));
                t.elapsed().as_secs_f64()
            })
            .collect();
        let best = times.iter().copied().fold(f64::INFINITY, f64::min);
        let (visits, events) = voxel_visits(&r, &view, method);
        let steps = match method {
            VolumeMethod::Siddon => {
                format!(", {events:.2e} minor-axis crossings (the walk's steps)")
            }
            VolumeMethod::Trilinear => String::new(),
        };
        eprintln!(
            "summary volume/drr_1024/{name}: {:.0} ms per image (first {:.0} ms), {:.2e} voxel visits \
             ({:.0} M/s){steps}",
            best * 1e3,
            times[0] * 1e3,
            visits,
            visits / best / 1e6,
        );
    }
    let mut g = c.benchmark_group("volume/drr_1024");
    g.sample_size(10);
    g.throughput(Throughput::Elements(1024 * 1024));
    let r = VolumeRenderer::new(&ct, &VolumeRenderOptions::default(), Some(&mask)).unwrap();
    g.bench_function("siddon_masked_L1", |b| b.iter(|| r.render(&view)));
    g.finish();
    let mut g = c.benchmark_group("volume/label_surface_512x512x133");
    g.sample_size(10);
    g.bench_function("L1", |b| {
        b.iter(|| label_surface(&seg, 31, &SurfaceOptions::default()).unwrap())
    });
    g.finish();
    let phantom = build_phantom(&PhantomOptions {
        levels: vec![Level::L3],
        discs: false,
        // The raw marching-tetrahedra surface (~300k triangles), not the phantom's own simplification.
        simplify_edge_mm: 0.0,
        ..PhantomOptions::default()
    })
    .unwrap();
    let l3 = &phantom.vertebrae[0].cortical;
    let mut g = c.benchmark_group("volume/decimate");
    g.sample_size(10);
    g.throughput(Throughput::Elements(l3.triangles.len() as u64));
    g.bench_function("phantom_L3_to_40k", |b| {
        b.iter(|| decimate(l3, 40_000).unwrap())
    });
    g.finish();
}

/// Voxels visited by one image, and the crossings of the rays' two minor axes. A step-by-step Siddon walk
/// visits each voxel crossed (≈ Σ over rays of the clipped length in voxel units, |Δi| + |Δj| + |Δk|);
/// ours takes a step per minor-axis crossing only (the runs along the dominant axis are differences of
/// running sums). Trilinear samples 8 voxels every step.
fn voxel_visits(
    r: &VolumeRenderer,
    view: &spinedrr::geometry::View,
    method: VolumeMethod,
) -> (f64, f64) {
    let (mut total, mut minor) = (0.0, 0.0);
    for v in (0..view.intrinsics.height).step_by(8) {
        for u in (0..view.intrinsics.width).step_by(8) {
            let ray = view.pixel_ray(u as f64, v as f64);
            let (dp, len) = r.clipped_index_segment(&ray);
            let crossed = dp.abs() * len;
            total += match method {
                VolumeMethod::Siddon => crossed.element_sum(),
                VolumeMethod::Trilinear => 8.0 * len / r.step_mm(),
            };
            minor += crossed.element_sum() - crossed.max_element();
        }
    }
    (total * 64.0, minor * 64.0)
}
