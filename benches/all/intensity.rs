//! One AP+LAT intensity registration of phantom L3 from initial mTRE 10 mm on the default 1024 × 1024
//! detector with the default schedule (bins 16, 8, 4, 2; CMA-ES at bin 16; the finest level subsampled;
//! target ≤ 1.0 s), the same for a CT target (the phantom's L3 as a 1 mm synthetic CT, the volume DRR
//! masked to label 29; the finest level binned with 2 × 2 rays per pixel; target ≤ 2.5 s), and the time
//! of one pose evaluation (both views rendered and compared) at each level. The evaluations, iterations,
//! stopping rule and seconds of every stage of the two registrations are printed once.

use std::sync::Arc;

use criterion::Criterion;
use spinedrr::anatomy::ct::{SurfaceOptions, VoxelMask, label_surface};
use spinedrr::anatomy::synthetic_ct::{SyntheticCtOptions, synthetic_ct};
use spinedrr::anatomy::{Level, PhantomOptions, build_phantom};
use spinedrr::geometry::{CArm, RigidTransform};
use spinedrr::registration::SplitMix64;
use spinedrr::registration::intensity::{
    IntensityOptions, IntensityProblem, IntensityView, MovingDrr, MovingScope, Objective,
    Similarity, binned_image, binned_view, fixed_image, level_alone, level_targets, mtre_mm,
    phantom_moving, phantom_renderer, register_intensity, start_at_mtre, subsample,
    subsampled_image, subsampled_view,
};
use spinedrr::render::Backend;
use spinedrr::render::volume::{VolumeRenderOptions, VolumeRenderer};

/// The phantom's L3 alone as a synthetic CT (1 mm voxels), its volume DRR masked to the level, the
/// fixed images of AP and LAT at the truth, and the label surface's vertices as targets.
fn ct_problem(carm: &CArm) -> IntensityProblem {
    let phantom = build_phantom(&PhantomOptions {
        levels: vec![Level::L3],
        voxel_mm: 1.0,
        discs: false,
        ..PhantomOptions::default()
    })
    .unwrap();
    let (ct, seg) = synthetic_ct(
        &phantom,
        &SyntheticCtOptions {
            voxel_mm: 1.0,
            supersample: 1,
            ..SyntheticCtOptions::default()
        },
    )
    .unwrap();
    let mask = VoxelMask::from_labels(&seg, &[29]).unwrap();
    let renderer = VolumeRenderer::new(&ct, &VolumeRenderOptions::default(), Some(&mask)).unwrap();
    let targets = subsample(
        &label_surface(&seg, 29, &SurfaceOptions::default())
            .unwrap()
            .vertices,
        2000,
    );
    let views = ["ap", "lat"]
        .iter()
        .map(|n| {
            let v = carm.view(n).unwrap().clone();
            IntensityView {
                fixed: renderer.render(&v),
                view: v,
            }
        })
        .collect();
    IntensityProblem {
        moving: MovingDrr::Volume(Arc::new(renderer.into())),
        views,
        targets,
    }
}

/// Registers `problem` from a start at mTRE 10 mm and prints what it took; returns the start.
fn report(what: &str, problem: &IntensityProblem, opts: &IntensityOptions) -> RigidTransform {
    let truth = RigidTransform::IDENTITY;
    let init = start_at_mtre(
        &truth,
        &problem.targets,
        problem.centre(),
        problem.rho_mm(),
        10.0,
        &mut SplitMix64::new(1),
    );
    let r = register_intensity(problem, &init, opts).unwrap();
    eprintln!(
        "{what} from 10 mm: {} evaluations ({} renders), {:.2} s, final mTRE {:.4} mm, stages {:?}",
        r.evaluations,
        r.renders,
        r.seconds,
        mtre_mm(&r.pose, &truth, &problem.targets),
        r.stages
            .iter()
            .map(|s| (
                s.bin,
                s.stage,
                s.evaluations,
                s.iterations,
                s.stop,
                (s.seconds * 1e3).round()
            ))
            .collect::<Vec<_>>()
    );
    init
}

/// This module's benchmarks (see `main.rs`).
pub fn run(c: &mut Criterion) {
    let phantom = build_phantom(&PhantomOptions::default()).unwrap();
    let fixed_r = phantom_renderer(&level_alone(&phantom, Level::L3).unwrap()).unwrap();
    let carm = CArm::default_paper();
    let truth = RigidTransform::IDENTITY;
    let views: Vec<IntensityView> = ["ap", "lat"]
        .iter()
        .map(|n| {
            let v = carm.view(n).unwrap().clone();
            IntensityView {
                fixed: fixed_image(&fixed_r, &v, &truth, None).unwrap(),
                view: v,
            }
        })
        .collect();
    let problem = IntensityProblem {
        moving: phantom_moving(&phantom, Level::L3, MovingScope::Level, Backend::Raster).unwrap(),
        views,
        targets: level_targets(&phantom, Level::L3).unwrap(),
    };
    let opts = IntensityOptions::default();
    let init = report("AP+LAT L3 (meshes)", &problem, &opts);
    let ct = ct_problem(&carm);
    let ct_init = report("AP+LAT L3 (masked CT)", &ct, &opts);
    let mut g = c.benchmark_group("intensity");
    g.sample_size(10);
    g.bench_function(
        "AP+LAT registration of L3 from mTRE 10 mm (bins 16,8,4,2)",
        |b| b.iter(|| register_intensity(&problem, &init, &opts).unwrap()),
    );
    g.bench_function(
        "AP+LAT registration of a masked CT L3 from mTRE 10 mm (bins 16,8,4,2)",
        |b| b.iter(|| register_intensity(&ct, &ct_init, &opts).unwrap()),
    );
    // One evaluation at each level of the default schedule, as the pipeline makes it: the coarse levels
    // bin the fixed image, render the decimated meshes one ray per pixel and smooth both images; the
    // finest (bin 2) subsamples the detector and renders the full meshes.
    let finest = *opts.levels.last().unwrap();
    for &bin in &opts.levels {
        let last = bin == finest;
        let views = problem
            .views
            .iter()
            .map(|v| {
                if last {
                    (
                        subsampled_view(&v.view, bin).unwrap(),
                        subsampled_image(&v.fixed, bin),
                    )
                } else {
                    (
                        binned_view(&v.view, bin).unwrap(),
                        binned_image(&v.fixed, bin),
                    )
                }
            })
            .collect();
        let obj = Objective::new(
            &problem.moving,
            (bin / finest).max(1),
            views,
            Similarity::Ncc,
            if last { 0.0 } else { opts.smooth_px },
            init,
            problem.centre(),
            problem.rho_mm(),
        )
        .unwrap();
        g.bench_function(
            format!(
                "one AP+LAT evaluation of the meshes at bin {bin} ({})",
                if last { "subsampled" } else { "binned" }
            ),
            |b| b.iter(|| obj.evaluate(&[0.1, 0.0, 0.0, 0.0, 0.2, 0.0], None).unwrap()),
        );
    }
    // The CT's finest level: binned by 2 with 2 × 2 rays per pixel (the full detector's rays).
    let views = ct
        .views
        .iter()
        .map(|v| (v.view.clone(), binned_image(&v.fixed, 2)))
        .collect();
    let obj = Objective::supersampled(
        &ct.moving,
        1,
        2,
        views,
        Similarity::Ncc,
        0.0,
        ct_init,
        ct.centre(),
        ct.rho_mm(),
    )
    .unwrap();
    g.bench_function(
        "one AP+LAT evaluation of the masked CT at bin 2 (2×2 rays per pixel)",
        |b| b.iter(|| obj.evaluate(&[0.1, 0.0, 0.0, 0.0, 0.2, 0.0], None).unwrap()),
    );
    g.finish();
}
