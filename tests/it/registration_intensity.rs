//! Intensity-based registration of phantom L3 against independent expectations: exactness at the true
//! K (level alone and with neighbours + soft tissue), the analytic optima of a piercing shift (rotation
//! about the source) and a focal offset (depth shift), agreement with the landmark solver on densely
//! projected surface points, monotone bias in Δf, and robustness to Poisson noise and blur. The
//! detector is the default C-arm binned by 4 (256 × 256 px, fx = 1125 px) to keep the suite quick;
//! perturbations are stated at full resolution and binned with the detector.

use glam::{DMat3, DVec3};
use spinedrr::anatomy::{Level, Phantom};
use spinedrr::geometry::{Perturbation, RigidTransform, View};
use spinedrr::io::XrayModel;
use spinedrr::registration::intensity::{
    IntensityOptions, IntensityProblem, IntensityView, MovingScope, Objective, Similarity,
    binned_view, fixed_image, level_targets, mtre_mm, phantom_moving, phantom_renderer,
    register_intensity, start_at_mtre,
};
use spinedrr::registration::{
    RegistrationOptions, RegistrationProblem, SplitMix64, register_direct,
};
use spinedrr::render::Backend;

const BIN: u32 = 4;
const TRUTH: RigidTransform = RigidTransform::IDENTITY;

/// The L1–L5 phantom with discs and soft tissue, built once.
fn phantom() -> &'static Phantom {
    crate::common::phantom_with_soft_tissue()
}

/// The default view `name`, perturbed by `p` at full resolution, binned by [`BIN`].
fn view(name: &str, p: &Perturbation) -> View {
    let v = crate::common::carm_lat_750()
        .view(name)
        .unwrap()
        .perturbed(p)
        .unwrap();
    binned_view(&v, BIN).unwrap()
}

/// The problem of L3 in `views` with fixed images of the level alone (`whole = false`) or of the whole
/// phantom, through `model` when given, and the moving DRR of the level alone seen through `assumed`.
fn problem(
    views: &[&str],
    assumed: &Perturbation,
    whole: bool,
    model: Option<XrayModel>,
) -> IntensityProblem {
    let ph = phantom();
    let fixed_renderer = if whole {
        phantom_renderer(ph).unwrap()
    } else {
        phantom_renderer(&spinedrr::registration::intensity::level_alone(ph, Level::L3).unwrap())
            .unwrap()
    };
    let views = views
        .iter()
        .enumerate()
        .map(|(i, n)| {
            let m = model.map(|m| XrayModel {
                seed: m.seed + i as u64,
                ..m
            });
            IntensityView {
                fixed: fixed_image(
                    &fixed_renderer,
                    &view(n, &Perturbation::NONE),
                    &TRUTH,
                    m.as_ref(),
                )
                .unwrap(),
                view: view(n, assumed),
            }
        })
        .collect();
    IntensityProblem {
        moving: phantom_moving(ph, Level::L3, MovingScope::Level, Backend::Raster).unwrap(),
        views,
        targets: level_targets(ph, Level::L3).unwrap(),
    }
}

/// The default options with bins 4, 2, 1 of this 256² detector: the default schedule's bins 16, 8, 4 of
/// the full detector, the finest level sampling the fixed image's own rays (the default subsamples it).
fn options() -> IntensityOptions {
    IntensityOptions {
        levels: vec![4, 2, 1],
        ..IntensityOptions::default()
    }
}

/// Final mTREs of `n` registrations from starts with initial mTRE uniform in `(0, max_mm)`.
fn final_mtres(
    p: &IntensityProblem,
    opts: &IntensityOptions,
    n: usize,
    max_mm: f64,
    seed: u64,
) -> Vec<f64> {
    use rayon::prelude::*;
    // The starts are drawn in order from one generator, then registered in parallel (each start is
    // independent and deterministic, so the results do not depend on the thread count).
    let mut rng = SplitMix64::new(seed);
    let starts: Vec<RigidTransform> = (0..n)
        .map(|_| {
            let m = max_mm * rng.uniform();
            start_at_mtre(&TRUTH, &p.targets, p.centre(), p.rho_mm(), m, &mut rng)
        })
        .collect();
    starts
        .par_iter()
        .enumerate()
        .map(|(i, init)| {
            let o = IntensityOptions {
                cmaes: spinedrr::registration::intensity::CmaesOptions {
                    seed: seed + i as u64,
                    ..opts.cmaes
                },
                ..opts.clone()
            };
            let r = register_intensity(p, init, &o).unwrap();
            mtre_mm(&r.pose, &TRUTH, &p.targets)
        })
        .collect()
}

fn rate(v: &[f64], below: f64) -> f64 {
    v.iter().filter(|&&m| m < below).count() as f64 / v.len() as f64
}

#[test]
fn exact_at_the_true_k_from_starts_up_to_10_mm() {
    let p = problem(&["ap", "lat"], &Perturbation::NONE, false, None);
    let m = final_mtres(&p, &options(), 40, 10.0, 11);
    // Every start succeeds (van de Kraats: < 2 mm) and at least 95 % end at ≤ 0.05 mm.
    assert!(rate(&m, 2.0) >= 1.0, "success {}: {m:?}", rate(&m, 2.0));
    assert!(
        rate(&m, 0.05 + 1e-12) >= 0.95,
        "≤ 0.05 mm: {} of starts: {m:?}",
        rate(&m, 0.05 + 1e-12)
    );
}

#[test]
fn with_neighbours_and_soft_tissue_in_the_fixed_image() {
    let p = problem(&["ap", "lat"], &Perturbation::NONE, true, None);
    let opts = IntensityOptions {
        similarity: Similarity::GradientCorrelation,
        ..options()
    };
    let m = final_mtres(&p, &opts, 40, 10.0, 12);
    let ok: Vec<f64> = m.iter().copied().filter(|&x| x < 2.0).collect();
    let mean = ok.iter().sum::<f64>() / ok.len().max(1) as f64;
    assert!(rate(&m, 2.0) >= 0.9, "success {}: {m:?}", rate(&m, 2.0));
    assert!(mean <= 0.5, "mean final mTRE of successes {mean} mm");
}

/// The shortest rotation taking direction `a` to direction `b`.
fn rotation_between(a: DVec3, b: DVec3) -> DMat3 {
    let (a, b) = (a.normalize(), b.normalize());
    let axis = a.cross(b);
    let angle = axis.length().atan2(a.dot(b));
    DMat3::from_axis_angle(axis.normalize(), angle)
}

/// Registers from the truth with the local stage alone, on the detector binned by 2 and then the full
/// one (the optima below are near the truth; a single view hardly constrains depth on a coarser one).
fn local_from_truth(p: &IntensityProblem) -> RigidTransform {
    let opts = IntensityOptions {
        global: false,
        levels: vec![2, 1],
        ..options()
    };
    register_intensity(p, &TRUTH, &opts).unwrap().pose
}

#[test]
fn a_piercing_shift_is_a_rotation_about_the_source() {
    let shift = Perturbation::piercing(30.0, 0.0);
    let p = problem(&["ap"], &shift, false, None);
    let reg = local_from_truth(&p);
    // The camera-frame rotation that carries the centre's ray through K onto its ray through K′ at the
    // same pixel: to first order the homography K′ R K⁻¹ is then the identity shifted by 30 px.
    let (t, a) = (&view("ap", &Perturbation::NONE), &view("ap", &shift));
    let c = p.centre();
    let x = t.project(c);
    let ray = |v: &View| v.intrinsics.matrix().inverse() * DVec3::new(x.x, x.y, 1.0);
    let r_cam = rotation_between(ray(t), ray(a));
    let w = t.world_to_camera;
    let about_source = w
        .inverse()
        .compose(&RigidTransform::new(r_cam, DVec3::ZERO))
        .compose(&w);
    let analytic = about_source.compose(&TRUTH);
    let d = mtre_mm(&reg, &analytic, &p.targets);
    let moved = mtre_mm(&analytic, &TRUTH, &p.targets);
    assert!(
        moved > 3.0,
        "the shift should move the pose by millimetres, moved {moved}"
    );
    assert!(
        d <= 0.1,
        "mTRE to the analytic pose {d} mm (the pose moved {moved} mm)"
    );
}

#[test]
fn a_focal_offset_is_a_depth_shift_and_the_bias_grows_with_df() {
    let t = view("ap", &Perturbation::NONE);
    let mut last = 0.0;
    for df in [100.0, 200.0, 300.0, 400.0, 500.0] {
        let p = problem(&["ap"], &Perturbation::focal(df), false, None);
        let reg = local_from_truth(&p);
        let c = p.centre();
        let (before, after) = (
            t.world_to_camera.apply(TRUTH.apply(c)),
            t.world_to_camera.apply(reg.apply(c)),
        );
        let alpha = (t.intrinsics.fx * f64::from(BIN) + df) / (t.intrinsics.fx * f64::from(BIN));
        let predicted = (alpha - 1.0) * before.z;
        let dz = after.z - before.z;
        let in_plane = ((after.x - before.x).powi(2) + (after.y - before.y).powi(2)).sqrt();
        if df == 300.0 {
            assert!(
                (dz - predicted).abs() <= 0.03 * predicted,
                "Δz {dz} vs {predicted} mm"
            );
            assert!(in_plane <= 0.02 * predicted, "in-plane {in_plane} mm");
        }
        let e = mtre_mm(&reg, &TRUTH, &p.targets);
        assert!(e > last, "bias at Δf = {df}: {e} mm, not above {last}");
        last = e;
    }
}

#[test]
fn joint_focal_and_piercing_error_agrees_with_the_landmark_solver() {
    let pert = Perturbation {
        df_px: 300.0,
        ..Perturbation::piercing(30.0, 30.0)
    };
    let p = problem(&["ap", "lat"], &pert, false, None);
    let reg = local_from_truth(&p);
    // The landmark solver on the surface points projected through the true K, solved with the same
    // assumed K.
    let names = (0..p.targets.len()).map(|i| format!("p{i}")).collect();
    let truth_views = [
        view("ap", &Perturbation::NONE),
        view("lat", &Perturbation::NONE),
    ];
    let lm = RegistrationProblem::synthesize(names, p.targets.clone(), &truth_views, &TRUTH)
        .unwrap()
        .with_intrinsics(|v| Ok(view(&v.name, &pert).intrinsics))
        .unwrap();
    assert!(lm.model_points.len() >= 500);
    let landmark = register_direct(&lm, &TRUTH, &RegistrationOptions::default())
        .unwrap()
        .pose;
    let bias = mtre_mm(&landmark, &TRUTH, &p.targets);
    // The intensity result is its own objective's optimum, checked with another optimiser: a compass
    // search on the finest level's similarity (steps 0.2 down to 0.002 in each parameter, mm and mm of
    // rotation at the targets' radius) started at the registered pose moves it by little — the cost is
    // flat along the out-of-plane rotation here, so the LM's tolerances stop it short by ~0.15 mm.
    let (c, rho) = (p.centre(), p.rho_mm());
    let views = p
        .views
        .iter()
        .map(|v| (v.view.clone(), v.fixed.clone()))
        .collect();
    let obj = Objective::new(&p.moving, 1, views, Similarity::Ncc, 0.0, reg, c, rho).unwrap();
    let at = |q: &[f64; 6]| obj.evaluate(q, None).unwrap().similarity;
    let (mut x, mut step) = ([0.0; 6], 0.2);
    let mut best = at(&x);
    while step > 0.002 {
        let mut improved = false;
        for i in 0..6 {
            for sign in [-1.0, 1.0] {
                let mut q = x;
                q[i] += sign * step;
                let s = at(&q);
                if s > best {
                    (best, x, improved) = (s, q, true);
                }
            }
        }
        if !improved {
            step /= 2.0;
        }
    }
    let refined = obj.pose(&x);
    let polish = mtre_mm(&refined, &reg, &p.targets);
    assert!(
        polish <= 0.25,
        "a compass search moved the optimum {polish} mm"
    );
    let from_reg = landmark.compose(&reg.inverse());
    let w = spinedrr::geometry::rotation_log(from_reg.rotation) * rho;
    let t = from_reg.apply(reg.apply(c)) - reg.apply(c);
    let at_landmark = at(&[w.x, w.y, w.z, t.x, t.y, t.z]);
    assert!(
        at_landmark < best,
        "the landmark optimum's similarity {at_landmark} is not below the intensity optimum's {best}"
    );
    // The two optima place the vertebra's centre alike (the 0.5 mm holds for it); they differ in
    // rotation. Under an inconsistent geometry no pose fits both views, and the image similarity also
    // trades the wrong magnification against out-of-plane rotation (tilting the vertebra changes its
    // silhouette's extent, which points do not see): measured, the optima are 2.2° apart about the AP
    // beam's axis, out of plane for LAT, whose similarity gains 0.014 while AP's loses 0.002. Their mTRE
    // distance is then a share of the bias (~9 % here; 0.4–1.1 mm across the similarities and for the
    // piercing shift alone), so it is bounded by 0.5 mm or 10 % of the bias (issue #13 notes it).
    let centre_gap = (reg.apply(c) - landmark.apply(c)).length();
    assert!(centre_gap <= 0.5, "centres {centre_gap} mm apart");
    for (what, pose) in [("registered", &reg), ("compass-refined", &refined)] {
        let d = mtre_mm(pose, &landmark, &p.targets);
        assert!(
            d <= 0.5_f64.max(0.1 * bias),
            "{what} intensity vs landmark optimum {d} mm (landmark bias {bias} mm)"
        );
    }
}

#[test]
fn poisson_noise_and_blur_keep_90_percent_success_within_5_mm() {
    let model = XrayModel::new(1e4, 1.0, 5, true).unwrap();
    let p = problem(&["ap", "lat"], &Perturbation::NONE, false, Some(model));
    let m = final_mtres(&p, &options(), 20, 5.0, 13);
    assert!(rate(&m, 2.0) >= 0.9, "success {}: {m:?}", rate(&m, 2.0));
}

/// Broyden's secant updates on the finest level reach the optimum classical LM (a Jacobian by differences
/// at every iteration) reaches, with fewer DRR evaluations there: the level alone, AP+LAT, from five
/// starts within 10 mm.
#[test]
fn secant_updates_reach_the_classical_optimum_with_fewer_renders() {
    let p = problem(&["ap", "lat"], &Perturbation::NONE, false, None);
    let mut rng = SplitMix64::new(14);
    let (mut secant, mut classical) = (0, 0);
    for _ in 0..5 {
        let m = 10.0 * rng.uniform();
        let init = start_at_mtre(&TRUTH, &p.targets, p.centre(), p.rho_mm(), m, &mut rng);
        let run = |broyden: bool| {
            let mut o = options();
            o.lm.broyden = broyden;
            register_intensity(&p, &init, &o).unwrap()
        };
        let (b, c) = (run(true), run(false));
        let d = mtre_mm(&b.pose, &c.pose, &p.targets);
        assert!(d <= 0.01, "Broyden vs classical optimum: {d} mm");
        let finest = |r: &spinedrr::registration::intensity::IntensityResult| {
            r.stages.last().map_or(0, |s| s.evaluations)
        };
        secant += finest(&b);
        classical += finest(&c);
    }
    assert!(
        secant < classical,
        "finest-level evaluations: {secant} with secants, {classical} without"
    );
}
