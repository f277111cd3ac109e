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
use spinedrr::anatomy::{Landmarks, PhantomOptions, build_phantom, write_landmarks};
use spinedrr::study::tables::Table;

mod common;
use common::Spinedrr;

/// Where the scanner puts the phantom's origin (mm): far from where the views aim.
const SCANNER_OFFSET: [f64; 3] = [30.0, -20.0, 400.0];

struct Inputs {
    _dir: tempfile::TempDir,
    dir: PathBuf,
}

/// `ct.nii`, `seg.nii` (TotalSegmentator labels L1 = 31, L2 = 30) and `given.json` (the phantom's L1
/// landmarks, renamed, in scanner coordinates), written once.
fn inputs() -> &'static Path {
    static IN: OnceLock<Inputs> = OnceLock::new();
    &IN.get_or_init(|| {
        let dir = tempfile::tempdir().expect("temp dir");
        let phantom = build_phantom(&PhantomOptions {
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
piercing_px = [0.0]\ntrials = 2\n";

fn study_out() -> &'static Path {
    static OUT: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &OUT.get_or_init(|| {
        let i = inputs();
        let dir = tempfile::tempdir().expect("temp dir");
        let cfg = format!(
            "[anatomy]\nlevels = [\"L1\"]\nsegment = false\nvoxel_mm = 1.0\nmarker_radius_mm = 4.0\n\
[[anatomy.ct]]\nname = \"syn\"\nct = {ct:?}\nseg = {seg:?}\nlabels = \"totalseg\"\n\
levels = [\"L1\", \"L2\"]\nsegment = true\n\
[[anatomy.ct]]\nname = \"given\"\nct = {ct:?}\nseg = {seg:?}\nlevels = [\"31\"]\nlandmarks = {lm:?}\n\
{GRID}",
            ct = i.join("ct.nii").to_str().unwrap(),
            seg = i.join("seg.nii").to_str().unwrap(),
            lm = i.join("given.json").to_str().unwrap(),
        );
        let (o, out) = spinedrr(&cfg, dir.path());
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        (dir, out)
    })
    .1
}

fn table(name: &str) -> Table {
    Table::read(&study_out().join("tables").join(format!("{name}.csv"))).expect("table")
}

const TARGETS: [&str; 4] = ["syn-L1", "syn-L2", "syn-segment", "given-id31"];

#[test]
fn every_ct_target_has_rows_figures_and_a_report_section() {
    let out = study_out();
    let lm = table("landmarks");
    let proj = table("projection");
    for t in TARGETS {
        assert!(
            lm.rows.iter().any(|r| r[0] == t),
            "no landmark rows for {t}"
        );
        assert!(
            proj.rows.iter().any(|r| r[0] == t),
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
        lm.rows
            .iter()
            .any(|r| r[0] == "given-id31" && r[6] == "given_spinous_tip")
    );
    assert!(
        lm.rows
            .iter()
            .any(|r| r[0] == "syn-segment" && r[6] == "L2/spinous_tip")
    );
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
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
    let lm = table("landmarks");
    for t in ["syn-L1", "syn-L2", "given-id31"] {
        let r = lm
            .rows
            .iter()
            .find(|r| r[0] == t && r[1] == "ap" && r[6] == "center")
            .unwrap_or_else(|| panic!("no AP center row for {t}"));
        let (u, v) = (
            lm.num(r, "ref_u_px").unwrap(),
            lm.num(r, "ref_v_px").unwrap(),
        );
        assert!(
            (u - 255.5).abs() < 0.05 && (v - 255.5).abs() < 0.05,
            "{t}: center at ({u}, {v})"
        );
    }
}

#[test]
fn ct_landmarks_obey_the_homography_law_and_the_piercing_shift() {
    let t = table("landmarks");
    let (mut n, mut off_detector) = (0, 0);
    for r in &t.rows {
        let e = t.num(r, "pred_error_px").unwrap();
        if e.is_nan() {
            // A marker pushed off the detector (the segment in LAT at Δf 500) is recorded as NaN.
            assert_eq!(r[0], "syn-segment", "{r:?}");
            off_detector += 1;
            continue;
        }
        assert!(e <= 0.05, "{r:?}: measured − H·x = {e} px");
        if t.str(r, "family").unwrap() == "piercing" {
            let du = t.num(r, "meas_u_px").unwrap() - t.num(r, "ref_u_px").unwrap();
            let dv = t.num(r, "meas_v_px").unwrap() - t.num(r, "ref_v_px").unwrap();
            assert!(
                (du - 50.0).abs() < 1e-6 && (dv - 50.0).abs() < 1e-6,
                "{r:?}"
            );
            n += 1;
        }
    }
    assert!(n > 0, "no piercing rows");
    assert!(
        off_detector * 10 < t.rows.len(),
        "{off_detector} of {} rows off the detector",
        t.rows.len()
    );
    // Focal shifts grow with Δf for every landmark off the central ray.
    for r in t.rows.iter().filter(|r| r[2] == "focal" && r[3] == "500") {
        let small = t
            .rows
            .iter()
            .find(|s| {
                s[0] == r[0] && s[1] == r[1] && s[2] == "focal" && s[3] == "100" && s[6] == r[6]
            })
            .expect("Δf 100 row");
        let (s1, s5) = (
            t.num(small, "shift_px").unwrap(),
            t.num(r, "shift_px").unwrap(),
        );
        assert!(s5 > s1 || s5 < 0.05 || s5.is_nan(), "{r:?}: {s1} → {s5}");
    }
}

#[test]
fn silhouette_and_volume_drr_similarity_fall_with_focal_offset() {
    let t = table("projection");
    for target in TARGETS {
        for view in ["ap", "lat"] {
            let at = |df: &str, col: &str| {
                let r = t
                    .rows
                    .iter()
                    .find(|r| r[0] == target && r[1] == view && r[2] == "focal" && r[3] == df)
                    .unwrap_or_else(|| panic!("{target} {view} Δf {df}"));
                t.num(r, col).unwrap()
            };
            for col in ["dice", "iou", "ncc", "ssim", "gradient_correlation"] {
                let (a, b) = (at("100", col), at("500", col));
                assert!(b < a && a < 1.0, "{target} {view} {col}: {a} → {b}");
            }
            let (h1, h5) = (at("100", "hausdorff_px"), at("500", "hausdorff_px"));
            assert!(h5 > h1 && h1 > 0.0, "{target} {view} Hausdorff {h1} → {h5}");
        }
    }
}

#[test]
fn ct_registration_is_exact_with_the_true_k_and_degrades_with_focal_offset() {
    let t = table("registration_summary");
    for target in TARGETS {
        for m in ["kabsch", "direct-ap+lat"] {
            let cell = |df: f64| {
                let r = t
                    .rows
                    .iter()
                    .find(|r| r[0] == target && r[1] == m && t.num(r, "df_px").unwrap() == df)
                    .unwrap_or_else(|| panic!("{target} {m} Δf {df}"));
                t.num(r, "trans_err_mm_mean").unwrap()
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
    let t = table("projection");
    for view in ["ap", "lat"] {
        for df in ["100", "500"] {
            let row = |target: &str| {
                t.rows
                    .iter()
                    .find(|r| r[0] == target && r[1] == view && r[2] == "focal" && r[3] == df)
                    .unwrap_or_else(|| panic!("{target} {view} Δf {df}"))
            };
            let (ct, ph) = (row("syn-L1"), row("L1"));
            for (col, tol) in [("dice", 0.02), ("iou", 0.03), ("ncc", 0.03), ("ssim", 0.03)] {
                let (a, b) = (t.num(ct, col).unwrap(), t.num(ph, col).unwrap());
                assert!(
                    (a - b).abs() < tol,
                    "{view} Δf {df} {col}: CT {a} vs phantom {b}"
                );
            }
        }
    }
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
}
