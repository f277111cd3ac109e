//! The calibration experiment end to end: protocol (a) — K_est with the true extrinsics — moves
//! rendered landmark markers exactly as the homography law `H = K_est K⁻¹` predicts, trial by trial;
//! and a small study writes the calibration tables, figures and report section, whose landmark shifts
//! agree with the law recomputed from each row's K.

use std::sync::Arc;

use glam::{DVec2, DVec3};
use spinedrr::analysis::marker_centroid;
use spinedrr::anatomy::{Level, PhantomOptions, TriMesh};
use spinedrr::calibration::output::trial_seed;
use spinedrr::calibration::{CalibrationPhantom, CalibrationSetup, SetupOptions, run_trial};
use spinedrr::geometry::{CArm, Intrinsics, apply_homography};
use spinedrr::render::{Backend, RenderScene, SceneMesh};

fn l1_landmarks() -> Vec<(String, DVec3)> {
    let p = crate::common::phantom(&PhantomOptions {
        levels: vec![Level::L1],
        voxel_mm: 1.0,
        discs: false,
        ..PhantomOptions::default()
    })
    .unwrap();
    p.landmarks()
        .into_iter()
        .flat_map(|s| s.points.into_iter())
        .collect()
}

#[test]
fn protocol_intrinsic_moves_rendered_markers_as_the_homography_law_predicts() {
    let carm = CArm::default_paper();
    let setup = CalibrationSetup::new(
        &carm,
        &CalibrationPhantom::default_plate(),
        SetupOptions::default(),
    )
    .unwrap();
    let radius = 2.0;
    let markers: Vec<_> = l1_landmarks()
        .into_iter()
        .map(|(name, p)| {
            let scene = RenderScene::new(vec![SceneMesh {
                mesh: Arc::new(TriMesh::icosphere(&name, p, radius, 3)),
                mu_per_mm: 1.0,
                object: "marker".into(),
            }])
            .unwrap();
            (p, Backend::Raster.renderer(scene).unwrap())
        })
        .collect();
    let mut compared = 0;
    for trial in 0..4 {
        let r = run_trial(&setup, 0.5, trial_seed(3, trial)).unwrap();
        for (truth, est) in carm.views.iter().zip(&r.intrinsic_only) {
            let h = truth.homography_to(est);
            for (p, renderer) in &markers {
                let x = marker_centroid(renderer, truth, *p, radius).unwrap();
                let y = marker_centroid(renderer, est, *p, radius).unwrap();
                let (Some(x), Some(y)) = (x, y) else { continue };
                let predicted = apply_homography(&h, x);
                let e = (y - predicted).length();
                assert!(
                    e <= 0.05,
                    "trial {trial} view {}: measured {y} vs H·x {predicted} ({e} px), shift {}",
                    truth.name,
                    (y - x).length()
                );
                compared += 1;
            }
        }
        // A real calibration error: the landmarks do move.
        let dk = (r.k().fx - 4500.0).abs() + (r.k().cx - 511.5).abs();
        assert!(dk > 0.05, "{dk}");
    }
    assert!(compared >= 4 * 2 * 8, "{compared} comparisons");
}

/// Writes `config` as `dir/study.toml` and runs the study into `dir/out`: (success, stderr, out).
fn study(dir: &std::path::Path, config: &str) -> (bool, String, std::path::PathBuf) {
    let cfg = dir.join("study.toml");
    std::fs::write(&cfg, config).unwrap();
    let out = dir.join("out");
    let (ok, err) = crate::common::run(&[
        "study",
        "--config",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    (ok, err, out)
}

#[test]
fn a_small_calibration_study_writes_its_tables_figures_and_report() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, err, out) = study(
        dir.path(),
        r#"experiments = ["calibration"]
[anatomy]
levels = ["L1"]
segment = false
voxel_mm = 1.0
[geometry]
binning = 4
[calibration]
phantoms = ["plate", "helix"]
noise_px = [0.25, 0.5]
trials = 6
trials_per_unit = 3
silhouette_trials = 1
intensity_trials = 1
"#,
    );
    assert!(ok, "{err}");
    let mut r = csv::Reader::from_path(out.join("tables/calibration.csv")).unwrap();
    let header = r.headers().unwrap().clone();
    let col = |n: &str| header.iter().position(|h| h == n).unwrap();
    let rows: Vec<csv::StringRecord> = r.records().map(|x| x.unwrap()).collect();
    assert_eq!(
        rows.len(),
        2 * 2 * 6 * 2 * 2,
        "phantoms × σ × trials × protocols × views"
    );
    // The law recomputed from each intrinsic row's K: the largest |H x − x| over the L1 landmarks.
    let carm = CArm::default_paper();
    let landmarks = l1_landmarks();
    let f = |row: &csv::StringRecord, n: &str| row[col(n)].parse::<f64>().unwrap();
    let mut checked = 0;
    for row in rows.iter().filter(|r| &r[col("protocol")] == "intrinsic") {
        let view = carm.view(&row[col("view")]).unwrap();
        // The study's detector is binned ×4: K scales by 1/4 about pixel corners.
        let k0 = view.intrinsics;
        let binned = Intrinsics {
            fx: k0.fx / 4.0,
            fy: k0.fy / 4.0,
            cx: (k0.cx + 0.5) / 4.0 - 0.5,
            cy: (k0.cy + 0.5) / 4.0 - 0.5,
            width: 256,
            height: 256,
            ..k0
        };
        let truth = spinedrr::geometry::View::new("t", binned, view.world_to_camera);
        let est_k = Intrinsics {
            fx: f(row, "fx"),
            fy: f(row, "fy"),
            cx: f(row, "cx"),
            cy: f(row, "cy"),
            skew: f(row, "skew"),
            ..binned
        };
        let est = spinedrr::geometry::View::new("e", est_k, view.world_to_camera);
        let h = truth.homography_to(&est);
        let max = landmarks
            .iter()
            .map(|(_, p)| {
                let x: DVec2 = truth.project(*p);
                (apply_homography(&h, x) - x).length()
            })
            .fold(0.0, f64::max);
        let got = f(row, "landmark_shift_max_px");
        assert!((got - max).abs() <= 1e-6 * max.max(1.0), "{got} vs {max}");
        assert!(f(row, "homography_residual_max_px") < 1e-6);
        checked += 1;
    }
    assert_eq!(checked, 48);
    let dice: Vec<f64> = rows.iter().map(|r| f(r, "dice")).collect();
    // silhouette_trials = 1: trial 0 of each (phantom, σ), in both protocols and views.
    let silhouette_rows = 2 * 2 * 2 * 2;
    assert_eq!(
        dice.iter().filter(|d| d.is_finite()).count(),
        silhouette_rows
    );
    assert!(
        dice.iter()
            .filter(|d| d.is_finite())
            .all(|d| (0.0..=1.0).contains(d))
    );
    // The full estimated geometry compensates on the anatomy what K_est alone does not.
    let mean_dice = |protocol: &str| {
        let v: Vec<f64> = rows
            .iter()
            .filter(|r| &r[col("protocol")] == protocol)
            .map(|r| f(r, "dice"))
            .filter(|d| d.is_finite())
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    assert!(
        mean_dice("full") > mean_dice("intrinsic"),
        "{} {}",
        mean_dice("full"),
        mean_dice("intrinsic")
    );
    assert!(mean_dice("full") > 0.9, "{}", mean_dice("full"));
    // intensity_trials = 1: an intensity registration on trial 0 of each (phantom, σ) and protocol.
    let ireg: Vec<&csv::StringRecord> = rows
        .iter()
        .filter(|r| f(r, "ireg_mtre_mm").is_finite())
        .collect();
    assert_eq!(ireg.len(), 2 * 2 * 2 * 2);
    assert!(ireg.iter().all(|r| &r[col("trial")] == "0"));
    let mut compared = 0;
    let intrinsic = ireg
        .iter()
        .filter(|r| &r[col("protocol")] == "intrinsic")
        .count();
    for r in &ireg {
        let (lm, im) = (f(r, "reg_mtre_mm"), f(r, "ireg_mtre_mm"));
        match &r[col("protocol")] {
            // The estimated geometry reproduces the vertebra's projections: both registrations stay put.
            "full" => assert!(
                im < 0.5 && lm < 0.5,
                "full: intensity {im} landmark {lm} mm"
            ),
            // K_est alone: both registrations absorb the same projective error into the pose, so the
            // intensity registration's bias is the landmark registration's, up to what the image
            // matching weighs differently from 17 landmarks — wherever that optimum lies within a
            // local registration's reach of the true pose (its capture range, ~15 mm).
            _ if lm <= 15.0 => {
                compared += 1;
                assert!(
                    (im - lm).abs() <= 0.25 * lm + 0.25,
                    "intrinsic: intensity {im} vs landmark {lm} mm"
                );
            }
            _ => {}
        }
    }
    assert!(
        2 * compared >= intrinsic,
        "{compared} of {intrinsic} compared"
    );
    let tol = std::fs::read_to_string(out.join("tables/calibration_tolerance.csv")).unwrap();
    assert_eq!(tol.lines().count(), 1 + 2 * 2 * 2 * 3);
    assert!(out.join("tables/calibration_ambiguity.csv").exists());
    for f in [
        "calibration_scatter_ap.png",
        "calibration_scatter_lat.png",
        "calibration_intrinsics.png",
        "calibration_ambiguity.png",
    ] {
        let img = image::open(out.join("figures").join(f)).unwrap();
        assert!(img.width() > 500, "{f}");
    }
    assert!(crate::common::assert_figures_legible(&out.join("figures")) >= 4);
    assert!(crate::common::assert_figures_inside_canvas(&out.join("figures")) >= 4);
    let report = crate::common::read_report(&out);
    assert!(
        report.contains("Calibration in the loop"),
        "report lacks the section"
    );
    assert!(report.contains("Tolerance: how good must the calibration be?"));
    // The intensity registration under the two protocols is compared cell by cell (same phantom, σ and
    // trial), as recomputed here from the CSV (one view's rows: each trial repeats per view).
    let view0 = rows[0][col("view")].to_string();
    let ireg_of = |phantom: &str, noise: &str, protocol: &str| {
        ireg.iter()
            .find(|r| {
                r[col("view")] == *view0
                    && &r[col("phantom")] == phantom
                    && &r[col("noise_px")] == noise
                    && &r[col("protocol")] == protocol
            })
            .map(|r| f(r, "ireg_mtre_mm"))
            .expect("an intensity registration per cell")
    };
    let mut left = Vec::new();
    for r in ireg
        .iter()
        .filter(|r| r[col("view")] == *view0 && &r[col("protocol")] == "intrinsic")
    {
        let (ph, noise) = (&r[col("phantom")], &r[col("noise_px")]);
        left.push(100.0 * ireg_of(ph, noise, "full") / ireg_of(ph, noise, "intrinsic"));
    }
    let (lo, hi) = left
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
    let span = if format!("{lo:.1}") == format!("{hi:.1}") {
        format!("{lo:.1} %")
    } else {
        format!("{lo:.1}–{hi:.1} %")
    };
    let expected = format!(
        "the full geometry leaves {span} of the intrinsic-only mTRE over the {} cells",
        left.len()
    );
    assert!(report.contains(&expected), "{expected}");
    // The section says what ran, as the table shows it: trial 0 of the 6 with a silhouette (finite
    // Dice) and an intensity registration (finite mTRE), on L1.
    let ran = |c: &str| {
        let mut t: Vec<String> = rows
            .iter()
            .filter(|r| r[col(c)].parse::<f64>().is_ok_and(f64::is_finite))
            .map(|r| r[col("trial")].to_string())
            .collect();
        t.sort();
        t.dedup();
        t
    };
    assert_eq!(
        (ran("dice"), ran("ireg_mtre_mm")),
        (vec!["0".to_string()], vec!["0".to_string()])
    );
    for says in [
        "used on the vertebra (L1)",
        "rendered silhouette for the first trial of each cell; and an intensity-based registration",
        "noise-free DRRs through the true views for the first trial of each cell.",
    ] {
        assert!(report.contains(says), "{says}: {report}");
    }
}

/// `[calibration.physical]` at σ = 0 (each calibration exact): a **full** calibration of the displaced
/// C-arm absorbs any error (no landmark shift, no registration error); the **intrinsic** protocol (the
/// estimated K with the nominal poses) absorbs a detector moved along the central ray — a pure change of
/// K, fx × (S + δ)/S — but not a focal spot moved across the beam, which moves the camera centre; the
/// nominal geometry used uncalibrated errs under both. Against the nominal C-arm's rows of the same run.
#[test]
fn a_calibration_absorbs_what_a_physical_error_does_to_its_protocol() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, err, out) = study(
        dir.path(),
        r#"experiments = ["calibration"]
[anatomy]
levels = ["L1"]
segment = false
voxel_mm = 1.0
[geometry]
binning = 4
[calibration]
phantoms = ["helix"]
noise_px = [0.0]
trials = 1
trials_per_unit = 1
silhouette_trials = 0
[calibration.physical]
src_dx_mm = [4.0]
det_dz_mm = [10.0]
"#,
    );
    assert!(ok, "{err}");
    let t = spinedrr::study::StudyTables::load(&out).unwrap();
    // 2 errors × 1 trial × 2 protocols × 2 views.
    assert_eq!(t.calibration_physical.len(), 8);
    assert_eq!(
        t.calibration.len(),
        4,
        "the nominal C-arm's rows stay apart"
    );
    for r in &t.calibration_physical {
        let absorbed = r.protocol.name() == "full" || r.key == "det_dz_mm";
        if absorbed {
            assert!(
                r.landmark_shift_max_px < 1e-3 && r.reg_mtre_mm < 1e-3,
                "{r:?}"
            );
        } else {
            assert!(
                r.landmark_shift_max_px > 1.0 && r.reg_mtre_mm > 0.1,
                "{r:?}"
            );
        }
        assert!(
            r.uncalibrated_shift_max_px > 0.1 && r.uncalibrated_mtre_mm > 0.05,
            "{r:?}"
        );
    }
    let report = crate::common::read_report(&out);
    // Nothing the table lacks is described as run: no Dice, no intensity registration in any row.
    assert!(
        t.calibration
            .iter()
            .all(|r| r.dice.is_nan() && r.ireg_mtre_mm.is_nan())
    );
    assert!(
        report.contains(
            "no silhouette (`silhouette_trials = 0`); and no intensity-based registration \
             (`intensity_trials = 0`)."
        ),
        "{report}"
    );
    // …and its registration table is the landmark registration's alone, each cell's mean from the CSV.
    assert!(
        report.contains("| phantom | σ (px) | protocol | landmark mTRE (mm) | n |")
            && !report.contains("intensity mTRE (mm)"),
        "{report}"
    );
    for protocol in ["intrinsic", "full"] {
        let m: Vec<f64> = t
            .calibration
            .iter()
            .filter(|r| r.protocol.name() == protocol && r.view == "ap")
            .map(|r| r.reg_mtre_mm)
            .collect();
        assert_eq!(m.len(), 1);
        let row = format!("| helix | 0 | {protocol} | {:.3} | 1 |", m[0]);
        assert!(report.contains(&row), "{row}: {report}");
    }
    assert!(report.contains("### Calibrating a C-arm displaced by a physical error"));
    assert!(
        report.contains("| det_dz_mm = 10 | helix | 0 | full | 0 |"),
        "{report}"
    );
}

/// A bad `[calibration.physical]` value is refused before any work, naming the table and key.
#[test]
fn a_bad_calibration_physical_value_is_refused_naming_the_key() {
    for (value, says) in [
        ("det_dz_mm = [0.0]", "0 is no perturbation"),
        ("det_roll_deg = [60.0]", "beyond"),
        ("src_dx_mm = [1.0, 1.0]", "listed twice"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let (ok, err, out) = study(
            dir.path(),
            &format!(
                "experiments = [\"calibration\"]\n[anatomy]\nlevels = [\"L1\"]\nsegment = false\n\
                 [calibration]\nphantoms = [\"helix\"]\n[calibration.physical]\n{value}\n"
            ),
        );
        let key = value.split(' ').next().unwrap();
        assert!(!ok, "{value}: accepted");
        assert!(
            err.contains(&format!("calibration.physical.{key}")) && err.contains(says),
            "{value}: {err}"
        );
        assert!(!out.exists(), "{value}: output written before validation");
    }
}
