//! `spinedrr study --quick` end to end: every table and figure exists, and the CSVs obey the physics of
//! an intrinsic perturbation (homography law, piercing translation, AP vs LAT, registration at zero
//! perturbation and growth with Δf).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use spinedrr::study::StudyTables;
use spinedrr::study::config::RegistrationMethod;
use spinedrr::study::schema::{Family, LandmarkRow};

use crate::common::Spinedrr;

fn quick_out() -> &'static Path {
    static OUT: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &OUT.get_or_init(|| {
        let dir = tempfile::tempdir().expect("temp dir");
        let out = dir.path().join("study");
        // The quick study without landmark noise: the registration laws below are exact at σ = 0.
        let cfg = dir.path().join("study.toml");
        std::fs::write(
            &cfg,
            "[anatomy]\nlevels = [\"L1\"]\nsegment = false\nvoxel_mm = 1.0\nmarker_radius_mm = 4.0\n\
             [registration]\nnoise_px = 0.0\n",
        )
        .unwrap();
        let st = Spinedrr::new()
            .args(["study", "--quick", "--config"])
            .arg(&cfg)
            .arg("--out")
            .arg(&out)
            .status();
        assert!(st.success(), "spinedrr study --quick failed");
        (dir, out)
    })
    .1
}

fn tables() -> &'static StudyTables {
    static T: OnceLock<StudyTables> = OnceLock::new();
    T.get_or_init(|| StudyTables::load(quick_out()).expect("tables"))
}

#[test]
fn quick_study_writes_every_table_figure_and_report() {
    let out = quick_out();
    let t = StudyTables::load(out).expect("tables");
    for (name, n) in [
        ("projection", t.projection.len()),
        ("structures", t.structures.len()),
        ("landmarks", t.landmarks.len()),
        ("registration", t.registration.len()),
        ("registration_summary", t.registration_summary.len()),
    ] {
        assert!(
            out.join(format!("tables/{name}.csv")).is_file() && n > 0,
            "{name}"
        );
    }
    let mut figures = vec![
        "dice_vs_perturbation.png".to_string(),
        "iou_vs_perturbation.png".into(),
        "chamfer_vs_perturbation.png".into(),
        "ssim_vs_perturbation.png".into(),
        "landmark_shift_vs_df.png".into(),
        "landmark_overlay_L1_ap.png".into(),
        "landmark_overlay_L1_lat.png".into(),
        "structures_dice_L1.png".into(),
    ];
    for v in ["ap", "lat"] {
        for df in [100, 500] {
            figures.push(format!("heatmap_L1_{v}_df{df}.png"));
        }
    }
    // Registration: one multi-panel figure (a panel per method) per target and error quantity.
    for q in ["rot", "trans", "residual"] {
        figures.push(format!("registration_L1_{q}.png"));
    }
    for f in figures {
        let img = image::open(out.join("figures").join(&f)).unwrap_or_else(|e| panic!("{f}: {e}"));
        assert!(img.width() > 100 && img.height() > 100, "{f}");
    }
    let report = crate::common::read_report(out);
    assert!(report.contains("dice_vs_perturbation.png") && report.contains("paper"));
    assert!(report.contains("registration_L1_trans.png"));
    assert!(report.contains("## Where the time goes"));
    let timings = std::fs::read_to_string(out.join("timings.csv")).expect("timings.csv");
    assert!(timings.starts_with("phase,clock,seconds,count,count_of\n"));
    assert!(timings.contains("registration,threads,") && timings.contains("\ntotal,wall,"));
    let html = std::fs::read_to_string(out.join("report.html")).expect("report.html");
    let embedded = html.matches("data:image/png;base64,").count();
    let pngs = report.matches("![").count();
    assert!(
        embedded > 0 && embedded == pngs,
        "report.html embeds {embedded} of {pngs} figures"
    );
}

/// Per (view, landmark): Δf → measured shift, focal family.
fn focal_shifts(t: &[LandmarkRow]) -> BTreeMap<(String, String), Vec<(f64, f64)>> {
    let mut m: BTreeMap<(String, String), Vec<(f64, f64)>> = BTreeMap::new();
    for r in t {
        if r.family == Family::Focal {
            let key = (r.view.clone(), r.landmark.clone());
            m.entry(key).or_default().push((r.df_px, r.shift_px));
        }
    }
    m
}

#[test]
fn landmark_shifts_grow_with_focal_offset() {
    let t = &tables().landmarks;
    let shifts = focal_shifts(t);
    assert!(!shifts.is_empty());
    for ((view, name), mut v) in shifts {
        v.sort_by(|a, b| a.0.total_cmp(&b.0));
        for w in v.windows(2) {
            // A landmark on the central ray does not move; all others move further for a larger Δf.
            if w[1].1 > 0.05 {
                assert!(
                    w[1].1 > w[0].1,
                    "{view} {name}: shift {:?} then {:?}",
                    w[0],
                    w[1]
                );
            }
        }
    }
}

#[test]
fn measured_landmark_shifts_equal_the_homography_prediction() {
    let t = &tables().landmarks;
    for r in t {
        let e = r.pred_error_px;
        assert!(e <= 0.05, "{r:?}: measured − H·x = {e} px");
    }
}

#[test]
fn piercing_shift_moves_every_landmark_by_exactly_the_shift() {
    let t = &tables().landmarks;
    let mut n = 0;
    for r in t.iter().filter(|r| r.family == Family::Piercing) {
        let du = r.meas_u_px - r.ref_u_px;
        let dv = r.meas_v_px - r.ref_v_px;
        let (cx, cy) = (r.dcx_px, r.dcy_px);
        assert!(
            (du - cx).abs() < 1e-6 && (dv - cy).abs() < 1e-6,
            "{r:?}: moved ({du}, {dv})"
        );
        n += 1;
    }
    assert!(n > 0, "no piercing rows");
}

#[test]
fn lat_is_more_sensitive_than_ap() {
    let lm = &tables().landmarks;
    let proj = &tables().projection;
    for df in [100.0, 500.0] {
        let mean_shift = |view: &str| {
            let v: Vec<f64> = lm
                .iter()
                .filter(|r| r.family == Family::Focal && r.view == view)
                .filter(|r| r.df_px == df)
                .map(|r| r.shift_px)
                .collect();
            v.iter().sum::<f64>() / v.len() as f64
        };
        assert!(
            mean_shift("lat") > mean_shift("ap"),
            "Δf {df}: LAT shifts ≤ AP shifts"
        );
        let dice = |view: &str| {
            let r = proj
                .iter()
                .find(|r| r.family == Family::Focal && r.view == view && r.df_px == df)
                .expect("row");
            r.dice
        };
        assert!(dice("lat") < dice("ap"), "Δf {df}: LAT Dice ≥ AP Dice");
        assert!(
            dice("ap") < 1.0,
            "Δf {df}: a focal change must shrink the overlap"
        );
    }
}

/// The law behind LAT > AP: on the landmarks measured in every focal cell, the LAT/AP ratio of RMS
/// shifts equals the ratio of RMS distances from the piercing point (255.5, 255.5 on the binned
/// detector) within 1 %, and the report's table prints both.
#[test]
fn lat_over_ap_shift_ratio_is_the_ratio_of_distances_from_the_piercing_point() {
    let rows: Vec<&LandmarkRow> = tables()
        .landmarks
        .iter()
        .filter(|r| r.family == Family::Focal && r.target == "L1")
        .collect();
    let df = rows.iter().map(|r| r.df_px).fold(0.0, f64::max);
    let names: std::collections::BTreeSet<&str> =
        rows.iter().map(|r| r.landmark.as_str()).collect();
    let fixed: Vec<&str> = names
        .into_iter()
        .filter(|n| {
            rows.iter()
                .filter(|r| r.landmark == *n)
                .all(|r| r.shift_px.is_finite() && r.ref_u_px.is_finite())
        })
        .collect();
    assert!(fixed.len() >= 5, "{fixed:?}");
    let rms = |view: &str, f: &dyn Fn(&LandmarkRow) -> f64| {
        let v: Vec<f64> = rows
            .iter()
            .filter(|r| r.view == view && r.df_px == df && fixed.contains(&r.landmark.as_str()))
            .map(|r| f(r))
            .collect();
        (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
    };
    let shift = |r: &LandmarkRow| r.shift_px;
    let dist = |r: &LandmarkRow| (r.ref_u_px - 255.5).hypot(r.ref_v_px - 255.5);
    let measured = rms("lat", &shift) / rms("ap", &shift);
    let predicted = rms("lat", &dist) / rms("ap", &dist);
    assert!(
        (measured / predicted - 1.0).abs() < 0.01,
        "{measured} vs {predicted}"
    );
    let md = crate::common::read_report(quick_out());
    let row = md
        .lines()
        .find(|l| l.starts_with("| L1 | ") && l.contains(" | 500 ("))
        .expect("L1 ratio row");
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    // The quick grid bins the built-in 0.3 mm detector 2×: 0.6 mm pixels, so Δf = 500 px is an SDD
    // error of 300 mm (f = SDD / pitch).
    assert_eq!(cells[3], "500 (300 mm)", "{row}");
    assert_eq!(cells[6], format!("{measured:.3}"), "{row}");
    assert_eq!(cells[10], format!("{predicted:.3}"), "{row}");
}

/// Where a piercing shift halves the overlap, the similarities over the anatomy's region say so, while
/// the whole detector's (mostly empty background on both sides) still looks similar.
#[test]
fn region_similarity_sees_what_the_whole_detector_hides() {
    let rows: Vec<_> = tables()
        .projection
        .iter()
        .filter(|r| r.family == Family::Piercing && r.dice <= 0.5)
        .collect();
    assert!(
        !rows.is_empty(),
        "no piercing cell halves Dice in the quick study"
    );
    for r in rows {
        assert!(r.ssim < 0.8 && r.ssim_detector > 0.85, "{r:?}");
        assert!(r.ncc < r.ncc_detector, "{r:?}");
        assert!(r.region_px > 0 && r.region_margin_px > 0, "{r:?}");
    }
    let ap = tables()
        .projection
        .iter()
        .find(|r| r.view == "ap" && r.family == Family::Piercing && r.dice <= 0.5)
        .expect("an AP piercing cell");
    assert!(ap.ssim_detector > 0.9, "{ap:?}");
}

#[test]
fn registration_is_exact_at_zero_perturbation_and_degrades_with_focal_offset() {
    let t = &tables().registration_summary;
    let cell = |method: RegistrationMethod, df: f64| {
        let r = t
            .iter()
            .find(|r| r.method == method && r.df_px == df && r.piercing_px == 0.0)
            .unwrap_or_else(|| panic!("no {method} Δf {df}"));
        (r.rot_err_deg_mean, r.trans_err_mm_mean)
    };
    for m in [
        RegistrationMethod::DirectAp,
        RegistrationMethod::DirectLat,
        RegistrationMethod::DirectApLat,
        RegistrationMethod::Kabsch,
        RegistrationMethod::OpencvAp,
    ] {
        let (rot, trans) = cell(m, 0.0);
        assert!(
            rot < 1e-6 && trans < 1e-6,
            "{m}: error ({rot} deg, {trans} mm) with the true K"
        );
        let (r1, t1) = cell(m, 100.0);
        let (r5, t5) = cell(m, 500.0);
        assert!(
            t5 > t1 && t1 > 1e-3,
            "{m}: translation error does not grow ({t1} → {t5})"
        );
        if m == RegistrationMethod::Kabsch || m == RegistrationMethod::DirectApLat {
            assert!(
                r5 > r1 && r1 > 1e-4,
                "{m}: rotation error does not grow ({r1} → {r5})"
            );
        }
    }
}

/// A single view cannot tell a focal error from depth: at Δf the pose slides along the central ray by
/// about z·Δf/f. The report states each single-view method's translation error at the largest Δf beside
/// that prediction; both are checked here, the prediction from the view's depth of the world origin (where
/// the level sits) and its fx, the measurement from `registration_summary.csv`.
#[test]
fn single_view_translation_error_is_the_depth_slide_the_report_states() {
    let out = quick_out();
    let cfg = spinedrr::study::StudyConfig::from_file(&out.join("study.toml"))
        .expect("config")
        .with_quick_grid();
    let carm = cfg.carm().expect("C-arm");
    let md = crate::common::read_report(out);
    let t = &tables().registration_summary;
    let df = t.iter().map(|r| r.df_px).fold(0.0, f64::max);
    for m in [
        RegistrationMethod::DirectAp,
        RegistrationMethod::DirectLat,
        RegistrationMethod::OpencvAp,
        RegistrationMethod::OpencvLat,
    ] {
        let r = t
            .iter()
            .find(|r| r.method == m && r.df_px == df && r.piercing_px == 0.0)
            .unwrap_or_else(|| panic!("no {m} cell at Δf {df}"));
        let view = carm.view(m.views()[0]).expect("view");
        let z = view.depth(glam::DVec3::ZERO);
        let f = view.intrinsics.fx;
        let predicted = z * df / f;
        assert!(
            (r.trans_err_mm_mean - predicted).abs() < 0.03 * predicted,
            "{m}: {} mm against z·Δf/f = {predicted} mm",
            r.trans_err_mm_mean
        );
        let text = format!(
            "{m} {:.3} mm against {} {z:.0} × {df:.0} / {f:.0} = {predicted:.1} mm",
            r.trans_err_mm_mean,
            m.views()[0].to_uppercase()
        );
        assert!(md.contains(&text), "{text:?} not in the report");
    }
}
