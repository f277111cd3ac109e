//! A study of CT + segmentation anatomy (`[[anatomy.ct]]`): a synthetic CT of the L1–L2 phantom at a
//! coarse voxel size, placed off the world origin as a scanner would, with its TotalSegmentator label map.
//! The CSVs must obey the same physics as for the phantom (homography law, exact piercing shift, growth
//! with Δf, registration exact with the true K), each target must be centred where the views aim, and
//! bad inputs must be named before any output exists.

use std::path::{Path, PathBuf};
use std::process::Output;
use std::sync::OnceLock;

use glam::{DMat4, DVec3};
use spinedrr::anatomy::ct::{write_ct, write_labels};
use spinedrr::anatomy::labels::LabelConvention;
use spinedrr::anatomy::synthetic_ct::{SyntheticCtOptions, synthetic_ct};
use spinedrr::anatomy::vertebra::Level;
use spinedrr::anatomy::{Landmarks, PhantomOptions, write_landmarks};
use spinedrr::study::StudyTables;
use spinedrr::study::config::RegistrationMethod;
use spinedrr::study::schema::{Family, ProjectionRow};

use crate::common::{Spinedrr, all_but_intensity};

/// Where the scanner puts the phantom's origin (mm): far from where the views aim.
const SCANNER_OFFSET: [f64; 3] = [30.0, -20.0, 400.0];

/// The sagittal tilt (degrees, about the scanner's x axis) of the tilted copy of the CT.
const TILT_DEG: f64 = 12.0;

struct Inputs {
    _dir: tempfile::TempDir,
    dir: PathBuf,
}

/// `ct.nii`, `seg.nii` (TotalSegmentator labels L1 = 31, L2 = 30) and `given.json` (the phantom's L1
/// landmarks, renamed, in scanner coordinates), written once.
pub(crate) fn inputs() -> &'static Path {
    static IN: OnceLock<Inputs> = OnceLock::new();
    &IN.get_or_init(|| {
        let dir = tempfile::tempdir().expect("temp dir");
        let phantom = crate::common::phantom(&PhantomOptions {
            levels: vec![Level::L1, Level::L2],
            voxel_mm: 1.0,
            discs: false,
            ..Default::default()
        })
        .expect("phantom");
        let opts = SyntheticCtOptions {
            voxel_mm: 1.0,
            supersample: 1,
            labels: LabelConvention::TotalSegmentator,
            ..Default::default()
        };
        let (mut ct, mut seg) = synthetic_ct(&phantom, &opts).expect("synthetic CT");
        let offset = DVec3::from_array(SCANNER_OFFSET);
        ct.index_to_world = DMat4::from_translation(offset) * ct.index_to_world;
        seg.index_to_world = ct.index_to_world;
        write_ct(&dir.path().join("ct.nii"), &ct).expect("write CT");
        write_labels(&dir.path().join("seg.nii"), &seg).expect("write labels");
        // The same voxels tilted by TILT_DEG about the left–right axis (a flexed patient).
        ct.index_to_world = DMat4::from_rotation_x(TILT_DEG.to_radians()) * ct.index_to_world;
        seg.index_to_world = ct.index_to_world;
        write_ct(&dir.path().join("tilt.nii"), &ct).expect("write CT");
        write_labels(&dir.path().join("tilt_seg.nii"), &seg).expect("write labels");
        let l1 = &phantom.vertebrae[0].landmarks;
        let given = Landmarks {
            level: "vertebrae_L1".into(),
            points: ["center", "spinous_tip", "left_pedicle", "right_pedicle"]
                .iter()
                .map(|n| (format!("given_{n}"), l1.get(n).expect("landmark") + offset))
                .chain([("center".to_string(), l1.get("center").unwrap() + offset)])
                .collect(),
        };
        write_landmarks(&dir.path().join("given.json"), &[given]).expect("write landmarks");
        let path = dir.path().to_path_buf();
        Inputs {
            _dir: dir,
            dir: path,
        }
    })
    .dir
}

fn spinedrr(cfg: &str, dir: &Path) -> (Output, PathBuf) {
    let cfg_path = dir.join("study.toml");
    std::fs::write(&cfg_path, cfg).unwrap();
    let out = dir.join("out");
    let o = Spinedrr::new()
        .args(["study", "--config"])
        .arg(&cfg_path)
        .arg("--out")
        .arg(&out)
        .output();
    (o, out)
}

const GRID: &str = "[geometry]\nbinning = 2\n\
[perturbations]\ndf_px = [100.0, 500.0]\npiercing_px = [0.0, 50.0]\n\
[registration]\nmethods = [\"kabsch\", \"direct-ap+lat\"]\ndf_px = [0.0, 100.0, 500.0]\n\
piercing_px = [0.0]\ntrials = 2\nnoise_px = 0.0\n";

fn study_out() -> &'static Path {
    static OUT: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &OUT.get_or_init(|| {
        let i = inputs();
        let dir = tempfile::tempdir().expect("temp dir");
        // The CT targets through every experiment but the intensity registration (which studies the
        // phantom's L3: measured, this module's tests took 57 CPU-seconds with it, 15 without).
        let cfg = format!(
            "{experiments}\n\
[anatomy]\nlevels = [\"L1\"]\nsegment = false\nvoxel_mm = 1.0\nmarker_radius_mm = 4.0\n\
[[anatomy.ct]]\nname = \"syn\"\nct = {ct:?}\nseg = {seg:?}\nlabels = \"totalseg\"\n\
levels = [\"L1\", \"L2\"]\nsegment = true\n\
[[anatomy.ct]]\nname = \"given\"\nct = {ct:?}\nseg = {seg:?}\nlevels = [\"31\"]\nlandmarks = {lm:?}\n\
[[anatomy.ct]]\nname = \"upright\"\nct = {ct:?}\nseg = {seg:?}\nlevels = [\"L1\"]\nalign = \"anatomical\"\n\
[[anatomy.ct]]\nname = \"tilt\"\nct = {tct:?}\nseg = {tseg:?}\nlevels = [\"L1\"]\nalign = \"anatomical\"\n\
{GRID}",
            experiments = all_but_intensity(),
            ct = i.join("ct.nii").to_str().unwrap(),
            seg = i.join("seg.nii").to_str().unwrap(),
            tct = i.join("tilt.nii").to_str().unwrap(),
            tseg = i.join("tilt_seg.nii").to_str().unwrap(),
            lm = i.join("given.json").to_str().unwrap(),
        );
        let (o, out) = spinedrr(&cfg, dir.path());
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        (dir, out)
    })
    .1
}

fn tables() -> &'static StudyTables {
    static T: OnceLock<StudyTables> = OnceLock::new();
    T.get_or_init(|| StudyTables::load(study_out()).expect("tables"))
}

const TARGETS: [&str; 4] = ["syn-L1", "syn-L2", "syn-segment", "given-id31"];

#[test]
fn every_ct_target_has_rows_figures_and_a_report_section() {
    let out = study_out();
    let lm = &tables().landmarks;
    let proj = &tables().projection;
    for t in TARGETS {
        assert!(lm.iter().any(|r| r.target == t), "no landmark rows for {t}");
        assert!(
            proj.iter().any(|r| r.target == t),
            "no projection rows for {t}"
        );
        for f in [
            format!("heatmap_{t}_ap_df100.png"),
            format!("heatmap_{t}_lat_df500.png"),
            format!("registration_{t}_rot.png"),
            format!("registration_{t}_trans.png"),
        ] {
            let img =
                image::open(out.join("figures").join(&f)).unwrap_or_else(|e| panic!("{f}: {e}"));
            assert!(img.width() > 100, "{f}");
        }
    }
    // The landmark file's names are used as given; the segment's are prefixed with the level.
    assert!(
        lm.iter()
            .any(|r| r.target == "given-id31" && r.landmark == "given_spinous_tip")
    );
    assert!(
        lm.iter()
            .any(|r| r.target == "syn-segment" && r.landmark == "L2/spinous_tip")
    );
    let report = crate::common::read_report(out);
    assert!(report.contains("CT volume DRR") && report.contains("registration_syn-L2_rot.png"));
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert_eq!(
        html.matches("data:image/png;base64,").count(),
        report.matches("![").count()
    );
}

#[test]
fn each_target_is_centred_where_the_ap_view_aims() {
    // The AP central ray passes through the world origin, where each target's body centre is moved:
    // its marker lands on the principal point ((1024 / 2 + 0.5) / 2 − 0.5 = 255.5 after 2× binning).
    let lm = &tables().landmarks;
    for t in ["syn-L1", "syn-L2", "given-id31"] {
        let r = lm
            .iter()
            .find(|r| r.target == t && r.view == "ap" && r.landmark == "center")
            .unwrap_or_else(|| panic!("no AP center row for {t}"));
        let (u, v) = (r.ref_u_px, r.ref_v_px);
        assert!(
            (u - 255.5).abs() < 0.05 && (v - 255.5).abs() < 0.05,
            "{t}: center at ({u}, {v})"
        );
    }
}

#[test]
fn ct_landmarks_obey_the_homography_law_and_the_piercing_shift() {
    let t = &tables().landmarks;
    let (mut n, mut off_detector) = (0, 0);
    for r in t {
        let e = r.pred_error_px;
        if e.is_nan() {
            // A marker pushed off the detector (the segment in LAT at Δf 500) is recorded as NaN.
            assert_eq!(r.target, "syn-segment", "{r:?}");
            off_detector += 1;
            continue;
        }
        assert!(e <= 0.05, "{r:?}: measured − H·x = {e} px");
        if r.family == Family::Piercing {
            let du = r.meas_u_px - r.ref_u_px;
            let dv = r.meas_v_px - r.ref_v_px;
            assert!(
                (du - 50.0).abs() < 1e-6 && (dv - 50.0).abs() < 1e-6,
                "{r:?}"
            );
            n += 1;
        }
    }
    assert!(n > 0, "no piercing rows");
    assert!(
        off_detector * 10 < t.len(),
        "{off_detector} of {} rows off the detector",
        t.len()
    );
    // Focal shifts grow with Δf for every landmark off the central ray.
    for r in t
        .iter()
        .filter(|r| r.family == Family::Focal && r.df_px == 500.0)
    {
        let small = t
            .iter()
            .find(|s| {
                s.target == r.target
                    && s.view == r.view
                    && s.family == Family::Focal
                    && s.df_px == 100.0
                    && s.landmark == r.landmark
            })
            .expect("Δf 100 row");
        let (s1, s5) = (small.shift_px, r.shift_px);
        assert!(s5 > s1 || s5 < 0.05 || s5.is_nan(), "{r:?}: {s1} → {s5}");
    }
}

#[test]
fn silhouette_and_volume_drr_similarity_fall_with_focal_offset() {
    let t = &tables().projection;
    type Col = fn(&ProjectionRow) -> f64;
    let cols: [(&str, Col); 5] = [
        ("dice", |r| r.dice),
        ("iou", |r| r.iou),
        ("ncc", |r| r.ncc),
        ("ssim", |r| r.ssim),
        ("gradient_correlation", |r| r.gradient_correlation),
    ];
    for target in TARGETS {
        for view in ["ap", "lat"] {
            let at = |df: f64, col: Col| {
                let r = t
                    .iter()
                    .find(|r| {
                        r.target == target
                            && r.view == view
                            && r.family == Family::Focal
                            && r.df_px == df
                    })
                    .unwrap_or_else(|| panic!("{target} {view} Δf {df}"));
                col(r)
            };
            for (col, value) in cols {
                let (a, b) = (at(100.0, value), at(500.0, value));
                assert!(b < a && a < 1.0, "{target} {view} {col}: {a} → {b}");
            }
            let (h1, h5) = (at(100.0, |r| r.hausdorff_px), at(500.0, |r| r.hausdorff_px));
            assert!(h5 > h1 && h1 > 0.0, "{target} {view} Hausdorff {h1} → {h5}");
        }
    }
}

#[test]
fn ct_registration_is_exact_with_the_true_k_and_degrades_with_focal_offset() {
    let t = &tables().registration_summary;
    for target in TARGETS {
        for m in [RegistrationMethod::Kabsch, RegistrationMethod::DirectApLat] {
            let cell = |df: f64| {
                let r = t
                    .iter()
                    .find(|r| r.target == target && r.method == m && r.df_px == df)
                    .unwrap_or_else(|| panic!("{target} {m} Δf {df}"));
                r.trans_err_mm_mean
            };
            assert!(cell(0.0) < 1e-6, "{target} {m}: error with the true K");
            assert!(
                cell(500.0) > cell(100.0) && cell(100.0) > 1e-3,
                "{target} {m}"
            );
        }
    }
}

#[test]
fn ct_level_agrees_with_the_phantom_level_it_was_voxelized_from() {
    // Two renderers on one anatomy: the label surface vs the phantom's mesh for silhouettes, the CT
    // volume DRR (Siddon) vs the thickness DRR for image similarity. They differ by the 1 mm voxels only.
    // Over the whole detector SSIM agrees within 0.03; over the anatomy's region (`ssim`) the voxels'
    // texture shows: measured 0.03–0.07 lower for the CT, so its bound is 0.1 (NCC agrees within 0.01
    // in both).
    let t = &tables().projection;
    type Col = fn(&ProjectionRow) -> f64;
    let cols: [(&str, f64, Col); 6] = [
        ("dice", 0.02, |r| r.dice),
        ("iou", 0.03, |r| r.iou),
        ("ncc", 0.03, |r| r.ncc),
        ("ncc_detector", 0.03, |r| r.ncc_detector),
        ("ssim_detector", 0.03, |r| r.ssim_detector),
        ("ssim", 0.1, |r| r.ssim),
    ];
    for view in ["ap", "lat"] {
        for df in [100.0, 500.0] {
            let row = |target: &str| {
                t.iter()
                    .find(|r| {
                        r.target == target
                            && r.view == view
                            && r.family == Family::Focal
                            && r.df_px == df
                    })
                    .unwrap_or_else(|| panic!("{target} {view} Δf {df}"))
            };
            let (ct, ph) = (row("syn-L1"), row("L1"));
            for (col, tol, value) in cols {
                let (a, b) = (value(ct), value(ph));
                assert!(
                    (a - b).abs() < tol,
                    "{view} Δf {df} {col}: CT {a} vs phantom {b}"
                );
            }
        }
    }
}

/// The rotation a target's reference sidecar records (`details.placement.rotation`, rows).
fn recorded_rotation(target: &str) -> glam::DMat3 {
    let path = study_out().join(format!("references/{target}_ap.json"));
    let side = spinedrr::io::Sidecar::read(&path).expect("reference sidecar");
    let p = &side.details["placement"];
    assert_eq!(p["mode"], "body-centre", "{target}: {p}");
    let row = |r: usize| -> DVec3 {
        DVec3::from_array(serde_json::from_value(p["rotation"][r].clone()).expect("rotation row"))
    };
    glam::DMat3::from_cols(row(0), row(1), row(2)).transpose()
}

#[test]
fn anatomical_alignment_undoes_a_scanner_tilt() {
    // The tilted CT holds the same voxels as the upright one, turned by TILT_DEG about x. Aligned to its
    // own landmark frame, each is turned upright: the two rotations differ by the tilt, and every
    // landmark projects where the upright copy's does.
    let (upright, tilt) = (
        recorded_rotation("upright-L1"),
        recorded_rotation("tilt-L1"),
    );
    // Frame(tilted) = Rx · frame(upright), so R(tilted) = R(upright) · Rxᵀ.
    let off = (upright.transpose() * tilt) * glam::DMat3::from_rotation_x(TILT_DEG.to_radians());
    let err = (off.x_axis.x + off.y_axis.y + off.z_axis.z - 1.0) / 2.0;
    let err_deg = err.clamp(-1.0, 1.0).acos().to_degrees();
    assert!(
        err_deg < 0.5,
        "alignment rotations differ from the tilt by {err_deg}°"
    );
    let translation_only = recorded_rotation("syn-L1");
    let d = (translation_only - glam::DMat3::IDENTITY).to_cols_array();
    assert!(
        d.iter().all(|v| v.abs() < 1e-12),
        "syn-L1 (align none) was rotated"
    );
    let lm = &tables().landmarks;
    let mut n = 0;
    for r in lm
        .iter()
        .filter(|r| r.target == "tilt-L1" && r.df_px == 100.0)
    {
        let u = lm
            .iter()
            .find(|s| {
                s.target == "upright-L1"
                    && s.view == r.view
                    && s.landmark == r.landmark
                    && s.family == r.family
                    && s.df_px == r.df_px
            })
            .expect("upright row");
        let d = (r.ref_u_px - u.ref_u_px).hypot(r.ref_v_px - u.ref_v_px);
        assert!(d < 0.5, "{} {}: {d} px apart", r.view, r.landmark);
        n += 1;
    }
    assert!(n >= 10, "{n} landmark rows compared");
    let report = crate::common::read_report(study_out());
    assert!(
        report.contains("`upright`, `tilt`: `anatomical`")
            && report.contains("`syn`, `given`: `none`"),
        "the report does not say which alignment was used"
    );
}

#[test]
fn a_label_map_off_the_cts_grid_is_named() {
    let seg = inputs().join("tilt_seg.nii");
    bad(
        &format!("seg = {:?}\nlevels = [\"L1\"]", seg.to_str().unwrap()),
        &["anatomy.ct.seg", "tilt_seg.nii", "affine", "voxel axis j"],
    );
}

fn bad(cfg_tail: &str, must_name: &[&str]) {
    let i = inputs();
    let dir = tempfile::tempdir().expect("temp dir");
    let cfg = format!(
        "[anatomy]\nlevels = []\n[[anatomy.ct]]\nname = \"p\"\nct = {:?}\n{cfg_tail}\n{GRID}",
        i.join("ct.nii").to_str().unwrap()
    );
    let (o, out) = spinedrr(&cfg, dir.path());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "accepted: {cfg_tail}");
    assert!(!err.contains("panicked"), "{err}");
    for k in must_name {
        assert!(
            err.contains(k),
            "error for {cfg_tail:?} does not name {k:?}: {err}"
        );
    }
    assert!(
        !out.exists(),
        "output written before the inputs were checked"
    );
}

#[test]
fn bad_ct_inputs_are_named_before_any_output() {
    let seg = inputs().join("seg.nii");
    let seg = seg.to_str().unwrap();
    bad(
        "seg = \"/nonexistent/seg.nii.gz\"\nlevels = [\"L1\"]",
        &["anatomy.ct.seg", "/nonexistent/seg.nii.gz"],
    );
    bad(
        &format!("seg = {seg:?}\nlevels = [\"L9\"]"),
        &["anatomy.ct.levels", "L9"],
    );
    // L4 is a valid level name but not in this label map (only L1 = 31 and L2 = 30 are).
    bad(
        &format!("seg = {seg:?}\nlevels = [\"L1\", \"L4\"]"),
        &["anatomy.ct.levels", "L4", "seg.nii", "[30, 31]"],
    );
    bad(
        &format!("seg = {seg:?}\nlevels = [\"L1\"]\nlabels = \"mni\""),
        &["anatomy.ct.labels", "mni"],
    );
    bad(
        &format!("seg = {seg:?}\nlevels = [\"L1\"]\nlandmarks = \"/nonexistent/lm.json\""),
        &["anatomy.ct.landmarks", "/nonexistent/lm.json"],
    );
    bad(
        &format!("seg = {seg:?}\nlevels = [\"L1\"]\ncolour = \"red\""),
        &["colour"],
    );
    bad(
        &format!("seg = {seg:?}\nlevels = [\"L1\"]\nalign = \"tilted\""),
        &["anatomy.ct.align", "tilted"],
    );
    bad(
        &format!("seg = {seg:?}\nlevels = [\"L1\"]\nmethod = \"mip\""),
        &["anatomy.ct.method", "mip"],
    );
    bad(
        &format!("seg = {seg:?}\nlevels = [\"L1\"]\nsmooth_iterations = 9999"),
        &["anatomy.ct.smooth_iterations", "9999"],
    );
}
