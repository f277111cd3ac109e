//! One AP+LAT intensity registration of phantom L3 from initial mTRE 10 mm on the default 1024 × 1024
//! detector with the default schedule (bins 8, 4, 2; CMA-ES at bin 8; target ≤ 1.0 s), and the time of
//! one pose evaluation (both views rendered and compared) at each binning. The evaluation count of the
//! registration is printed once.

use criterion::{Criterion, criterion_group, criterion_main};
use spinedrr::anatomy::{Level, PhantomOptions, build_phantom};
use spinedrr::geometry::{CArm, Perturbation, RigidTransform};
use spinedrr::registration::SplitMix64;
use spinedrr::registration::intensity::{
    IntensityOptions, IntensityProblem, IntensityView, MovingScope, Objective, Similarity,
    binned_image, binned_view, fixed_image, level_alone, level_targets, mtre_mm, phantom_moving,
    phantom_renderer, register_intensity, start_at_mtre,
};

fn bench(c: &mut Criterion) {
    let phantom = build_phantom(&PhantomOptions::default()).unwrap();
    let fixed_r = phantom_renderer(&level_alone(&phantom, Level::L3).unwrap()).unwrap();
    let carm = CArm::default_paper();
    let truth = RigidTransform::IDENTITY;
    let views: Vec<IntensityView> = ["ap", "lat"]
        .iter()
        .map(|n| {
            let v = carm
                .view(n)
                .unwrap()
                .perturbed(&Perturbation::NONE)
                .unwrap();
            IntensityView {
                fixed: fixed_image(&fixed_r, &v, &truth, None).unwrap(),
                view: v,
            }
        })
        .collect();
    let problem = IntensityProblem {
        moving: phantom_moving(&phantom, Level::L3, MovingScope::Level).unwrap(),
        views,
        targets: level_targets(&phantom, Level::L3).unwrap(),
    };
    let init = start_at_mtre(
        &truth,
        &problem.targets,
        problem.centre(),
        problem.rho_mm(),
        10.0,
        &mut SplitMix64::new(1),
    );
    let opts = IntensityOptions::default();
    let r = register_intensity(&problem, &init, &opts).unwrap();
    eprintln!(
        "AP+LAT L3 from 10 mm: {} evaluations ({} renders), final mTRE {:.4} mm, stages {:?}",
        r.evaluations,
        r.renders,
        mtre_mm(&r.pose, &truth, &problem.targets),
        r.stages
            .iter()
            .map(|s| (s.bin, s.stage, s.evaluations))
            .collect::<Vec<_>>()
    );
    let mut g = c.benchmark_group("intensity");
    g.sample_size(10);
    g.bench_function(
        "AP+LAT registration of L3 from mTRE 10 mm (bins 8,4,2)",
        |b| b.iter(|| register_intensity(&problem, &init, &opts).unwrap()),
    );
    for bin in [8, 4, 2, 1] {
        let views = problem
            .views
            .iter()
            .map(|v| {
                (
                    binned_view(&v.view, bin).unwrap(),
                    binned_image(&v.fixed, bin),
                )
            })
            .collect();
        let detail = (bin / 2).max(1);
        let obj = Objective::new(
            &problem.moving,
            detail,
            views,
            Similarity::Ncc,
            opts.smooth_px,
            init,
            problem.centre(),
            problem.rho_mm(),
        )
        .unwrap();
        g.bench_function(format!("one AP+LAT evaluation at bin {bin}"), |b| {
            b.iter(|| obj.evaluate(&[0.1, 0.0, 0.0, 0.0, 0.2, 0.0], None).unwrap())
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
