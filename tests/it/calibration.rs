//! Calibration in the loop: noise-free recovery by both estimators, our DLT + LM against OpenCV on the
//! same noisy data, our RQ against OpenCV's `decomposeProjectionMatrix`, the Monte-Carlo spread against
//! the first-order prediction `σ² (JᵀJ)⁻¹`, and the focal-length / depth degeneracy of plate views.

use glam::{DVec2, DVec3};
use spinedrr::calibration::acquisition::with_noise;
use spinedrr::calibration::bundle::{self, Geometry, Skew};
use spinedrr::calibration::opencv::{calibrate_camera, decompose_projection_matrix, f32_pixels};
use spinedrr::calibration::output::trial_seed;
use spinedrr::calibration::{
    CalibrationPhantom, CalibrationSetup, SetupOptions, dlt, dlt_init, run_trial,
};
use spinedrr::geometry::{CArm, Intrinsics, RigidTransform, rotation_angle_deg};

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1.0)
}

/// Largest relative error of fx, fy, cx, cy (and the skew relative to fx).
fn k_err(a: &Intrinsics, b: &Intrinsics) -> f64 {
    [
        rel(a.fx, b.fx),
        rel(a.fy, b.fy),
        rel(a.cx, b.cx),
        rel(a.cy, b.cy),
        (a.skew - b.skew).abs() / b.fx,
    ]
    .into_iter()
    .fold(0.0, f64::max)
}

/// Rotation error (rad) and translation error relative to |t|.
fn pose_err(a: &RigidTransform, b: &RigidTransform) -> f64 {
    let rot = rotation_angle_deg(a.rotation * b.rotation.transpose()).to_radians();
    let t = (a.translation - b.translation).length() / b.translation.length();
    rot.max(t)
}

fn truth_k() -> Intrinsics {
    CArm::default_paper().views[0].intrinsics
}

#[test]
fn noise_free_plate_and_helix_recover_k_and_every_pose() {
    let carm = CArm::default_paper();
    for phantom in [
        CalibrationPhantom::default_plate(),
        CalibrationPhantom::default_helix(),
    ] {
        let setup = CalibrationSetup::new(&carm, &phantom, SetupOptions::default()).unwrap();
        let r = run_trial(&setup, 0.0, 1).unwrap();
        let e = k_err(&r.k(), &truth_k());
        // The plate's calibration is OpenCV's, which works on f32 pixels: their rounding (~3e-5 px at
        // u, v ~ 500) leaves K a few parts in 1e6 off; the helix's is our f64 LM.
        let bound = if phantom.name.starts_with("plate") {
            5e-6
        } else {
            1e-6
        };
        assert!(e <= bound, "{}: K relative error {e:e}", phantom.name);
        for (im, est) in setup.ideal.iter().zip(&r.calibration.geometry.poses) {
            let e = pose_err(est, &im.phantom_to_camera);
            assert!(e <= 1e-6, "{}: pose error {e:e}", phantom.name);
        }
        for (v, est) in carm.views.iter().zip(&r.views) {
            let e = pose_err(&est.world_to_camera, &v.world_to_camera);
            assert!(
                e <= 1e-6,
                "{} view {}: extrinsics error {e:e}",
                phantom.name,
                v.name
            );
        }
        assert!(r.calibration.rms_px < 1e-4, "{}", r.calibration.rms_px);
        assert!(r.heldout_err_mm < 1e-3, "{}", r.heldout_err_mm);
    }
}

#[test]
fn noise_free_helix_with_skew_recovers_the_skew() {
    // Our K carries a skew; the 3-D method estimates it (Zhang's, like OpenCV, holds it at 0).
    let text =
        spinedrr::geometry::DEFAULT_GEOMETRY_TOML.replace("# skew_px = 0.0", "skew_px = 3.5");
    let carm = CArm::from_toml_str(&text, "skewed").unwrap();
    let setup = CalibrationSetup::new(
        &carm,
        &CalibrationPhantom::default_helix(),
        SetupOptions::default(),
    )
    .unwrap();
    let r = run_trial(&setup, 0.0, 1).unwrap();
    let e = k_err(&r.k(), &carm.views[0].intrinsics);
    assert!(
        e <= 1e-6 && (r.k().skew - 3.5).abs() < 1e-3,
        "{e:e} {:?}",
        r.k()
    );
}

#[test]
fn our_dlt_lm_and_opencv_agree_on_the_same_noisy_helix_data() {
    let carm = CArm::default_paper();
    let phantom = CalibrationPhantom::default_helix();
    let setup = CalibrationSetup::new(&carm, &phantom, SetupOptions::default()).unwrap();
    let bbs = phantom.points();
    let k0 = truth_k();
    for seed in 0..5 {
        // OpenCV calibrates in f32: both solvers get the same f32-exact pixels.
        let images = f32_pixels(&with_noise(&setup.ideal, 0.5, trial_seed(7, seed)));
        let mut init = dlt_init(&images, &bbs, k0.width, k0.height).unwrap();
        init.k.skew = 0.0;
        let ours = bundle::refine(&init, &images, &bbs, Skew::Fixed, 200).unwrap();
        let (cv, _) = calibrate_camera(&images, &bbs, k0.width, k0.height, Some(&init.k)).unwrap();
        let e = k_err(&ours.geometry.k, &cv.k);
        assert!(
            e <= 1e-6,
            "seed {seed}: K differs by {e:e}: {:?} vs {:?}",
            ours.geometry.k,
            cv.k
        );
        for (a, b) in ours.geometry.poses.iter().zip(&cv.poses) {
            let e = pose_err(a, b);
            assert!(e <= 1e-6, "seed {seed}: pose differs by {e:e}");
        }
        // And the noise moved the estimate far more than the two solvers differ.
        assert!(k_err(&ours.geometry.k, &k0) > 1e3 * e);
    }
}

#[test]
fn our_rq_decomposition_matches_opencv_decompose_projection_matrix() {
    let carm = CArm::default_paper();
    let phantom = CalibrationPhantom::default_helix();
    let setup = CalibrationSetup::new(&carm, &phantom, SetupOptions::default()).unwrap();
    let bbs = phantom.points();
    let images = with_noise(&setup.ideal, 1.0, 3);
    for im in &images {
        let world: Vec<DVec3> = im.observed.iter().map(|&(i, _)| bbs[i]).collect();
        let px: Vec<DVec2> = im.observed.iter().map(|&(_, x)| x).collect();
        let p = dlt::dlt(&world, &px).unwrap();
        let (k, pose) = dlt::decompose(&p, 1024, 1024).unwrap();
        // OpenCV's RQDecomp3x3 regularises its Givens rotations with DBL_EPSILON under the square root,
        // which a unit-Frobenius P (last row ~1e-7) feels: give it P scaled so M's last row is a unit
        // vector (P is homogeneous, the scale changes nothing else).
        let m3 = (p[(2, 0)].powi(2) + p[(2, 1)].powi(2) + p[(2, 2)].powi(2)).sqrt();
        let rows: [[f64; 4]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| p[(r, c)] / m3));
        let (kc, rc, centre) = decompose_projection_matrix(&rows).unwrap();
        // OpenCV leaves the signs free (P is homogeneous): K D, D R with D = diag(sign K_ii) has a
        // positive diagonal, and R's sign follows det R = +1.
        let d: [f64; 3] = std::array::from_fn(|i| kc[i][i].signum());
        let kc: [[f64; 3]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| kc[r][c] * d[c]));
        let mut rc: [[f64; 3]; 3] =
            std::array::from_fn(|r| std::array::from_fn(|c| rc[r][c] * d[r]));
        if glam::DMat3::from_cols_array_2d(&rc).determinant() < 0.0 {
            rc = rc.map(|row| row.map(|v| -v));
        }
        let ours = k.matrix_rows();
        for r in 0..3 {
            for c in 0..3 {
                let (a, b) = (ours[r][c], kc[r][c]);
                assert!(
                    (a - b).abs() <= 1e-9 * ours[0][0],
                    "K[{r}][{c}]: {a} vs {b}"
                );
            }
        }
        let rr = pose.rotation_rows();
        for r in 0..3 {
            for c in 0..3 {
                assert!(
                    (rr[r][c] - rc[r][c]).abs() < 1e-9,
                    "R[{r}][{c}]: {rr:?} vs {rc:?}"
                );
            }
        }
        let ours_centre = RigidTransform::new(pose.rotation, pose.translation)
            .inverse()
            .translation;
        assert!(
            (ours_centre - centre).length() < 1e-6 * centre.length(),
            "{ours_centre} vs {centre}"
        );
        // And K [R | t] is the DLT's P up to scale.
        let view = spinedrr::geometry::View::new("v", k, pose);
        for x in &world {
            let h = p * nalgebra::Vector4::new(x.x, x.y, x.z, 1.0);
            let from_p = DVec2::new(h.x / h.z, h.y / h.z);
            assert!((view.project(*x) - from_p).length() < 1e-9, "{from_p}");
        }
    }
}

/// Sample standard deviation.
fn sd(x: &[f64]) -> f64 {
    let m = x.iter().sum::<f64>() / x.len() as f64;
    (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (x.len() as f64 - 1.0)).sqrt()
}

fn corr(a: &[f64], b: &[f64]) -> f64 {
    let (ma, mb) = (
        a.iter().sum::<f64>() / a.len() as f64,
        b.iter().sum::<f64>() / b.len() as f64,
    );
    let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

/// A named intrinsic parameter.
type Param = fn(&Intrinsics) -> f64;

/// Monte-Carlo sd of (fx, fy, cx, cy[, skew]) against `σ √diag (JᵀJ)⁻¹` at the truth.
fn check_first_order(phantom: CalibrationPhantom, tilt_deg: f64, sigma: f64, skew: Skew) {
    let carm = CArm::default_paper();
    let opts = SetupOptions {
        tilt_deg,
        ..SetupOptions::default()
    };
    let setup = CalibrationSetup::new(&carm, &phantom, opts).unwrap();
    let truth = Geometry {
        k: truth_k(),
        poses: setup.ideal.iter().map(|im| im.phantom_to_camera).collect(),
    };
    let cov = bundle::covariance(&truth, &setup.ideal, &phantom.points(), skew, sigma).unwrap();
    let trials: Vec<Intrinsics> = (0..200)
        .map(|i| run_trial(&setup, sigma, trial_seed(11, i)).unwrap().k())
        .collect();
    let mut params: Vec<(&str, Param)> = vec![
        ("fx", |k| k.fx),
        ("fy", |k| k.fy),
        ("cx", |k| k.cx),
        ("cy", |k| k.cy),
    ];
    if skew == Skew::Free {
        params.push(("skew", |k| k.skew));
    }
    for (i, (name, f)) in params.iter().enumerate() {
        let mc = sd(&trials.iter().map(f).collect::<Vec<_>>());
        let predicted = cov[(i, i)].sqrt();
        let ratio = mc / predicted;
        assert!(
            (0.85..=1.15).contains(&ratio),
            "{}: sd({name}) = {mc} px over 200 trials, first-order {predicted} px (ratio {ratio})",
            phantom.name
        );
    }
}

#[test]
fn plate_monte_carlo_spread_matches_the_first_order_prediction() {
    check_first_order(CalibrationPhantom::default_plate(), 20.0, 0.5, Skew::Fixed);
}

#[test]
fn helix_monte_carlo_spread_matches_the_first_order_prediction() {
    check_first_order(CalibrationPhantom::default_helix(), 30.0, 0.5, Skew::Free);
}

#[test]
fn plate_focal_length_trades_against_depth_and_tilt_shrinks_but_keeps_the_direction() {
    // A 100 mm plate (11 × 11 BBs at 10 mm) at 1000 mm in the AP view alone, σ = 0.3 px.
    let text = spinedrr::geometry::DEFAULT_GEOMETRY_TOML;
    let ap_only = &text[..text.find("[[view]]\nname = \"lat\"").unwrap()];
    let carm = CArm::from_toml_str(ap_only, "ap only").unwrap();
    assert_eq!(carm.views.len(), 1);
    let plate = CalibrationPhantom::plate(11, 11, 10.0).unwrap();
    let sigma = 0.3;
    let mut sds = Vec::new();
    for tilt in [2.0, 10.0, 45.0] {
        let opts = SetupOptions {
            tilt_deg: tilt,
            ..SetupOptions::default()
        };
        let setup = CalibrationSetup::new(&carm, &plate, opts).unwrap();
        let (mut fx, mut tz, mut rms) = (Vec::new(), Vec::new(), Vec::new());
        for i in 0..200 {
            let r = run_trial(&setup, sigma, trial_seed(5, i)).unwrap();
            fx.push(r.k().fx);
            tz.push(r.calibration.geometry.poses[0].translation.z);
            rms.push(r.calibration.rms_px);
        }
        let c = corr(&fx, &tz);
        assert!(c > 0.99, "tilt {tilt}°: corr(fx, t_z) = {c}");
        let mean_rms = rms.iter().sum::<f64>() / rms.len() as f64;
        let floor = setup.rms_floor(sigma);
        assert!(
            (mean_rms / floor - 1.0).abs() < 0.1,
            "tilt {tilt}°: RMS {mean_rms} vs floor {floor}"
        );
        sds.push(sd(&fx));
    }
    eprintln!("sd(fx) at tilts 2°, 10°, 45°: {sds:?} px");
    assert!(
        sds[0] > sds[1] && sds[1] > sds[2],
        "sd(fx) by tilt 2°, 10°, 45°: {sds:?}"
    );
}

#[test]
fn bbs_measured_from_rendered_spheres_calibrate_close_to_the_truth() {
    // Blob centroids of rendered 1 mm BB spheres instead of exact projections, no added noise: the
    // centroid's sub-pixel bias is all that separates the estimate from the truth.
    let carm = CArm::default_paper();
    let opts = SetupOptions {
        detection: spinedrr::calibration::Detection::Rendered { radius_mm: 1.0 },
        ..SetupOptions::default()
    };
    let setup = CalibrationSetup::new(&carm, &CalibrationPhantom::default_helix(), opts).unwrap();
    let exact = CalibrationSetup::new(
        &carm,
        &CalibrationPhantom::default_helix(),
        SetupOptions::default(),
    )
    .unwrap();
    let mut worst: f64 = 0.0;
    for (a, b) in setup.ideal.iter().zip(&exact.ideal) {
        for ((_, x), (_, y)) in a.observed.iter().zip(&b.observed) {
            worst = worst.max((*x - *y).length());
        }
    }
    assert!(
        worst > 0.0 && worst < 0.1,
        "centroid vs projection: {worst} px"
    );
    let r = run_trial(&setup, 0.0, 1).unwrap();
    assert!(r.calibration.rms_px < 0.1, "{}", r.calibration.rms_px);
    assert!(k_err(&r.k(), &truth_k()) < 0.01, "{:?}", r.k());
}

#[test]
fn zhang_closed_form_recovers_k_from_noise_free_plate_images() {
    let carm = CArm::default_paper();
    let plate = CalibrationPhantom::default_plate();
    let setup = CalibrationSetup::new(&carm, &plate, SetupOptions::default()).unwrap();
    let k = spinedrr::calibration::zhang::closed_form(&setup.ideal, &plate.points(), 1024, 1024)
        .unwrap();
    assert!(k_err(&k, &truth_k()) < 1e-6, "{k:?}");
}
