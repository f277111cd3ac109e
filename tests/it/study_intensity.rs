//! The study's intensity-registration experiment end to end on a small grid (phantom L3, AP+LAT and AP,
//! Δf {0, 300}, one start per bin of 0–4 and 4–8 mm): every trial's recorded pose re-evaluated through the library gives
//! its recorded mTRE; at the true K the landmark registration is exact and the intensity one near it;
//! the summary agrees with the trials; an interrupted run resumed gives the same bytes; bad values of
//! `[intensity_registration]` are refused naming the key before anything is written.

use std::path::Path;

use glam::DVec3;
use spinedrr::anatomy::{Level, PhantomOptions};
use spinedrr::geometry::{RigidTransform, rotation_exp};
use spinedrr::registration::intensity::{level_targets, mtre_mm};
use spinedrr::study::StudyTables;

use crate::common::{Spinedrr, csv_tables};

const CONFIG: &str = r#"seed = 11
experiments = ["intensity-registration"]
[anatomy]
levels = ["L3"]
segment = false
voxel_mm = 0.8
[intensity_registration]
targets = ["L3"]
views = ["ap+lat", "ap"]
levels = [16, 8]
df_px = [0.0, 300.0]
piercing_px = [0.0]
init_mtre_mm = [0.0, 4.0, 8.0]
starts_per_bin = 1
"#;

/// The target points of a freshly built L3 (the configs' `voxel_mm = 0.8`), where the study measures mTRE.
fn l3_targets() -> Vec<DVec3> {
    let phantom = crate::common::phantom(&PhantomOptions {
        levels: vec![Level::L3],
        voxel_mm: 0.8,
        discs: false,
        soft_tissue: false,
        ..PhantomOptions::default()
    })
    .unwrap();
    level_targets(&phantom, Level::L3).unwrap()
}

fn study(cfg: &Path, out: &Path, extra: &[&str]) -> (bool, String) {
    Spinedrr::new()
        .args(["study", "--config", cfg.to_str().unwrap(), "--out"])
        .arg(out)
        .args(extra)
        .outcome()
}

#[test]
fn intensity_study_tables_agree_with_the_library_and_resume_byte_identically() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("study.toml");
    std::fs::write(&cfg, CONFIG).unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    let (ok, err) = study(&cfg, &a, &["--threads", "2"]);
    assert!(ok, "{err}");
    let t = StudyTables::load(&a).unwrap();
    // 2 view sets × 2 Δf × 2 bins × 1 start.
    assert_eq!(t.intensity.len(), 8);
    assert_eq!(t.intensity_summary.len(), 4);
    assert_eq!(t.intensity_bins.len(), 8);

    // Each trial's recorded pose, re-evaluated on target points of a freshly built L3, gives its
    // recorded mTRE.
    let targets = l3_targets();
    for r in &t.intensity {
        let pose = RigidTransform::new(
            rotation_exp(DVec3::new(r.rx, r.ry, r.rz)),
            DVec3::new(r.tx_mm, r.ty_mm, r.tz_mm),
        );
        let m = mtre_mm(&pose, &RigidTransform::IDENTITY, &targets);
        assert!(
            (m - r.final_mtre_mm).abs() <= 1e-6 * (1.0 + m),
            "{} {} start {}: pose gives {m} mm, table says {}",
            r.views,
            r.df_px,
            r.start,
            r.final_mtre_mm
        );
        assert!(r.initial_mtre_mm >= r.bin_lo_mm && r.initial_mtre_mm <= r.bin_hi_mm);
        assert_eq!(r.success, r.final_mtre_mm < 2.0);
        assert!(r.evaluations > 0);
    }
    // At the true K: noise-free landmarks registered from the truth stay there, and AP+LAT intensity
    // registration from ≤ 8 mm ends near the truth.
    for r in t.intensity.iter().filter(|r| r.df_px == 0.0) {
        assert!(
            r.landmark_mtre_mm < 1e-6,
            "landmark at K true: {}",
            r.landmark_mtre_mm
        );
    }
    for r in t
        .intensity
        .iter()
        .filter(|r| r.df_px == 0.0 && r.views == "ap+lat")
    {
        assert!(
            r.final_mtre_mm < 0.5,
            "AP+LAT at K true ended at {} mm",
            r.final_mtre_mm
        );
        assert!(r.optimum_mtre_mm < 0.5, "{}", r.optimum_mtre_mm);
        assert!(
            r.optimum_to_landmark_mm < 0.5,
            "{}",
            r.optimum_to_landmark_mm
        );
    }
    // The distance between the two optima bounds the difference of their biases (the triangle
    // inequality, point by point over the same targets).
    for r in &t.intensity {
        let gap = (r.optimum_mtre_mm - r.landmark_mtre_mm).abs();
        assert!(
            gap <= r.optimum_to_landmark_mm + 1e-9,
            "{} Δf {} piercing {}: biases differ by {gap}, optima {} mm apart",
            r.views,
            r.df_px,
            r.piercing_px,
            r.optimum_to_landmark_mm
        );
        assert!(r.optimum_to_landmark_rot_deg >= 0.0 && r.optimum_to_landmark_centre_mm >= 0.0);
    }
    // A focal offset biases every registration: the landmark one by a lot in a single view (depth).
    let ap300 = t
        .intensity_summary
        .iter()
        .find(|r| r.views == "ap" && r.df_px == 300.0)
        .unwrap();
    assert!(ap300.landmark_mtre_mm > 5.0, "{}", ap300.landmark_mtre_mm);
    // The summary is the trials counted.
    for s in &t.intensity_summary {
        let cell: Vec<_> = t
            .intensity
            .iter()
            .filter(|r| r.views == s.views && r.df_px == s.df_px)
            .collect();
        assert_eq!(s.trials, cell.len());
        assert_eq!(s.successes, cell.iter().filter(|r| r.success).count());
        let reached = cell.iter().filter(|r| r.reached_optimum).count();
        assert!((s.reached_optimum_rate - reached as f64 / cell.len() as f64).abs() < 1e-12);
        // The optimum is searched once per bin, the first from the truth and the second 0.5 mm away; the
        // summary's bias is the first search's, its spread the two searches' range.
        let of_bin = |b: usize| cell.iter().find(|r| r.bin == b).unwrap();
        assert_eq!(of_bin(0).optimum_start_mtre_mm, 0.0);
        assert_eq!(of_bin(1).optimum_start_mtre_mm, 0.5);
        assert_eq!(s.optimum_searches, 2);
        assert_eq!(s.optimum_mtre_mm, of_bin(0).optimum_mtre_mm);
        let spread = (of_bin(0).optimum_mtre_mm - of_bin(1).optimum_mtre_mm).abs();
        assert!(
            (s.optimum_spread_mm - spread).abs() < 1e-12,
            "{} Δf {}: spread {} against {spread}",
            s.views,
            s.df_px,
            s.optimum_spread_mm
        );
    }
    // At the true K in AP+LAT the search from 0.5 mm away returns to the truth as the one from it does.
    for s in t
        .intensity_summary
        .iter()
        .filter(|s| s.df_px == 0.0 && s.views == "ap+lat")
    {
        assert!(s.optimum_spread_mm < 0.5, "{}", s.optimum_spread_mm);
    }
    let report = crate::common::read_report(&a);
    assert!(report.contains("## Intensity-based registration"));
    for f in ["intensity_mtre_L3.png", "intensity_success_L3.png"] {
        assert!(a.join("figures").join(f).is_file(), "{f}");
    }

    // Interrupted after 3 units, resumed on 1 thread: the same tables, byte for byte.
    let (ok, err) = study(&cfg, &b, &["--threads", "2", "--max-units", "3"]);
    assert!(ok, "{err}");
    let (ok, err) = study(&cfg, &b, &["--threads", "1"]);
    assert!(ok, "{err}");
    assert!(csv_tables(&a) == csv_tables(&b), "resumed tables differ");
}

fn refused(section: &str, key: &str) {
    refused_with(section, &format!("intensity_registration.{key}"));
}

fn refused_with(section: &str, needle: &str) {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("study.toml");
    std::fs::write(
        &cfg,
        format!(
            "experiments = [\"intensity-registration\"]\n[intensity_registration]\n{section}\n"
        ),
    )
    .unwrap();
    let out = dir.path().join("out");
    let (ok, err) = study(&cfg, &out, &[]);
    assert!(!ok, "accepted: {section}");
    assert!(
        err.contains(needle),
        "{section:?}: the error does not name {needle}: {err}"
    );
    assert!(
        !out.exists(),
        "{section:?}: output written before validation"
    );
}

/// Spectral fixed images: each model's cell starts from the same poses (a paired comparison); the
/// spectrum alone keeps the registration at the truth, and the titanium the moving DRR lacks moves the
/// intensity optimum further from it than the spectrum does.
#[test]
fn spectral_fixed_images_are_paired_with_the_monochromatic_ones() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("study.toml");
    std::fs::write(
        &cfg,
        r#"seed = 11
experiments = ["intensity-registration"]
[anatomy]
levels = ["L3"]
segment = false
voxel_mm = 0.8
[intensity_registration]
targets = ["L3"]
views = ["ap+lat"]
levels = [16, 8]
df_px = [0.0]
piercing_px = [0.0]
init_mtre_mm = [0.0, 4.0]
starts_per_bin = 1
images = ["mono", "spectral", "spectral+screws"]
"#,
    )
    .unwrap();
    let out = dir.path().join("out");
    let (ok, err) = study(&cfg, &out, &[]);
    assert!(ok, "{err}");
    let t = StudyTables::load(&out).unwrap();
    let row = |m: &str| t.intensity.iter().find(|r| r.fixed_image == m).unwrap();
    let (mono, spectral, screws) = (row("mono"), row("spectral"), row("spectral+screws"));
    assert_eq!(t.intensity.len(), 3);
    assert_eq!(t.intensity_summary.len(), 3);
    for r in [spectral, screws] {
        assert_eq!(r.initial_mtre_mm, mono.initial_mtre_mm, "unpaired start");
    }
    assert!(mono.final_mtre_mm < 0.5, "{}", mono.final_mtre_mm);
    assert!(spectral.final_mtre_mm < 2.0, "{}", spectral.final_mtre_mm);
    assert!(
        screws.optimum_mtre_mm > spectral.optimum_mtre_mm,
        "screws {} mm, spectrum alone {} mm",
        screws.optimum_mtre_mm,
        spectral.optimum_mtre_mm
    );
    let report = crate::common::read_report(&out);
    assert!(report.contains("### Spectral fixed images: the spectrum and the screws"));
}

#[test]
fn bad_intensity_values_are_refused_naming_the_key() {
    refused("images = []", "images");
    refused("images = [\"mono\", \"mono\"]", "images");
    refused(
        "images = [\"spectral\"]\n[intensity_registration.spectral]\nspectrum = \"200\"",
        "spectral",
    );
    refused(
        "images = [\"spectral+screws\"]\n[intensity_registration.spectral]\ndetector = \"csi\"",
        "spectral",
    );
    refused_with("images = [\"xray\"]", "images = [\"xray\"]");
    refused("levels = [8, 16]", "levels");
    refused("levels = [0]", "levels");
    refused("views = [\"ap+oblique\"]", "views");
    refused("views = [\"ap+ap\"]", "views");
    refused("similarity = \"mutual-information\"", "similarity");
    refused("init_mtre_mm = [5.0, 2.0]", "init_mtre_mm");
    refused("init_mtre_mm = [5.0]", "init_mtre_mm");
    refused("starts_per_bin = 0", "starts_per_bin");
    refused("photons = -1.0", "photons");
    refused("blur_px = 1.0", "blur_px");
    refused("targets = [\"L9\"]", "targets");
    refused("targets = []", "targets");
    refused("df_px = [100.0, 100.0]", "df_px");
    refused("piercing_px = [nan]", "piercing_px");
    refused("df_px = [-5000.0]", "df_px");
    refused(
        "[intensity_registration.physical]\ndet_dz_mm = [0.0]",
        "physical.det_dz_mm",
    );
    refused(
        "[intensity_registration.physical]\ndet_roll_deg = [90.0]",
        "physical.det_roll_deg",
    );
    // An unknown spelling is a TOML parse error that quotes the line.
    refused_with("fixed = \"everything\"", "fixed = \"everything\"");
}

/// The physical cells of `[intensity_registration.physical]`: a detector rolled θ about the AP central
/// ray (the world's y axis here) turns the one-view camera rigidly about that ray, so the true images are
/// matched exactly by the level turned θ about the y axis. Both the landmark and the intensity optimum
/// must land there: their mTRE is the mean of 2·r·sin(θ/2) over the level's target points, r their
/// distance from the y axis, computed here from a freshly built L3 alone.
#[test]
fn a_detector_roll_moves_the_intensity_and_the_landmark_optimum_to_the_turned_pose() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("study.toml");
    let config = r#"seed = 11
experiments = ["intensity-registration"]
[anatomy]
levels = ["L3"]
segment = false
voxel_mm = 0.8
[intensity_registration]
targets = ["L3"]
views = ["ap"]
levels = [16, 8]
global = false
df_px = [0.0]
piercing_px = [0.0]
init_mtre_mm = [0.0, 1.0]
starts_per_bin = 1
[intensity_registration.physical]
det_roll_deg = [1.5]
det_dx_mm = [3.0]
"#;
    std::fs::write(&cfg, config).unwrap();
    let out = dir.path().join("out");
    let (ok, err) = study(&cfg, &out, &["--threads", "2"]);
    assert!(ok, "{err}");
    let t = StudyTables::load(&out).unwrap();
    let cells: Vec<&str> = t
        .intensity_summary
        .iter()
        .map(|r| r.physical.as_str())
        .collect();
    assert_eq!(cells, ["", "det_dx_mm=3", "det_roll_deg=1.5"]);
    let targets = l3_targets();
    let half = (1.5_f64.to_radians() / 2.0).sin();
    let expected = targets
        .iter()
        .map(|p| 2.0 * DVec3::new(p.x, 0.0, p.z).length() * half)
        .sum::<f64>()
        / targets.len() as f64;
    assert!(expected > 0.3, "{expected}");
    let roll = &t.intensity_summary[2];
    assert!(
        (roll.landmark_mtre_mm - expected).abs() < 1e-4,
        "landmark optimum {} mm, the turned pose {expected} mm",
        roll.landmark_mtre_mm
    );
    assert!(
        (roll.optimum_mtre_mm - expected).abs() < 1e-3 && roll.optimum_to_landmark_mm < 1e-3,
        "intensity optimum {} mm ({} mm from the landmark optimum), the turned pose {expected} mm",
        roll.optimum_mtre_mm,
        roll.optimum_to_landmark_mm
    );
    // The in-plane detector shift is no rigid motion of the camera: its optimum is elsewhere.
    assert!(t.intensity_summary[1].landmark_mtre_mm > 0.5);
    let report = crate::common::read_report(&out);
    assert!(
        report.contains("| L3 | ap | mono | — | — | det_roll_deg = 1.5 | 1 |"),
        "{report}"
    );
    // The prose applies its agreement rule to every perturbed cell, not only the worst it describes:
    // the optima agree within the largest of 10 % of the landmark bias, the floor at the true K and the
    // optimum's spread — recomputed here from the summary table.
    let floor = t.intensity_summary[0].optimum_mtre_mm.max(0.0);
    let differ: Vec<&str> = t.intensity_summary[1..]
        .iter()
        .filter(|r| {
            r.optimum_to_landmark_mm > floor.max(0.1 * r.landmark_mtre_mm).max(r.optimum_spread_mm)
        })
        .map(|r| r.physical.as_str())
        .collect();
    let said = if differ.is_empty() {
        "By the same rule the two optima agree in every one of the 2 perturbed cells.".to_string()
    } else {
        format!(
            "By the same rule the two optima agree in {} of the 2 perturbed cells and differ in {}: the \
             physical error `{}`",
            2 - differ.len(),
            differ.len(),
            differ[0]
        )
    };
    assert!(report.contains(&said), "{said}: {report}");
}
