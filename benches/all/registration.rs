//! One direct AP+LAT registration of 10 landmarks (target ≤ 100 µs), and the other methods beside it.

use criterion::Criterion;
use glam::DVec3;
use spinedrr::geometry::{CArm, RigidTransform, rotation_exp};
use spinedrr::registration::{
    Method, PnpSolver, RegistrationOptions, RegistrationProblem, perturb_pose, register,
};

fn problem(views: &[&str]) -> (RegistrationProblem, RigidTransform) {
    let pts: Vec<DVec3> = [
        [0.0, 15.0, 12.0],
        [0.0, 15.0, -12.0],
        [0.0, -15.0, 12.5],
        [0.0, -15.0, -12.0],
        [0.0, 0.0, 13.0],
        [0.0, 0.0, -13.0],
        [-12.0, -22.0, 4.0],
        [12.0, -22.0, 4.0],
        [0.0, -55.0, -8.0],
        [-38.0, -28.0, 6.0],
    ]
    .iter()
    .map(|p| DVec3::from(*p))
    .collect();
    let names = (0..pts.len()).map(|i| format!("l{i}")).collect();
    let carm = CArm::default_paper();
    let vs: Vec<_> = views
        .iter()
        .map(|n| carm.view(n).unwrap().clone())
        .collect();
    let truth = RigidTransform::new(
        rotation_exp(DVec3::new(0.05, -0.08, 0.12)),
        DVec3::new(2.0, -3.0, 5.0),
    );
    (
        RegistrationProblem::synthesize(names, pts, &vs, &truth).unwrap(),
        truth,
    )
}

/// This module's benchmarks (see `main.rs`).
pub fn run(c: &mut Criterion) {
    let (joint, truth) = problem(&["ap", "lat"]);
    let (single, _) = problem(&["ap"]);
    let opts = RegistrationOptions {
        init: Some(perturb_pose(&truth, 5.0, 10.0, truth.translation, 1)),
        ..Default::default()
    };
    let mut g = c.benchmark_group("registration");
    g.bench_function("direct AP+LAT, 10 landmarks", |b| {
        b.iter(|| register(&joint, Method::Direct, &opts).unwrap())
    });
    g.bench_function("kabsch AP+LAT, 10 landmarks", |b| {
        b.iter(|| register(&joint, Method::Kabsch, &opts).unwrap())
    });
    g.bench_function("direct AP, 10 landmarks", |b| {
        b.iter(|| register(&single, Method::Direct, &opts).unwrap())
    });
    g.bench_function("opencv iterative AP, 10 landmarks", |b| {
        b.iter(|| register(&single, Method::OpenCv(PnpSolver::Iterative), &opts).unwrap())
    });
    g.finish();
}
