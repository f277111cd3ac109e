//! Cohort studies (`[[anatomy.dataset]]`): the cohort statistics against a hand computation on a
//! three-case table; a case with a truncated CT skipped and listed (stderr, `cohort_left_out.csv`, the
//! report), and with `strict = true` the run stopping before any work with the file named; the VerSe
//! layout and TotalSegmentator per-structure masks read into cases.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use spinedrr::anatomy::ct::{read_labels, write_labels};
use spinedrr::study::StudyConfig;
use spinedrr::study::config::RegistrationMethod;
use spinedrr::study::schema::cohort::{CohortRow, cohort_rows};
use spinedrr::study::schema::{
    Family, LandmarkRow, ProjectionRow, RegistrationSummaryRow, StudyTables,
};

use crate::common::Spinedrr;

fn projection(target: &str, dice: f64) -> ProjectionRow {
    ProjectionRow {
        target: target.into(),
        view: "ap".into(),
        family: Family::Focal,
        df_px: 100.0,
        dcx_px: 0.0,
        dcy_px: 0.0,
        skew_px: 0.0,
        sy: 1.0,
        cut_by_edge: false,
        dice,
        iou: 0.5,
        chamfer_mean_px: 1.0,
        hausdorff_px: 2.0,
        hd95_px: 2.0,
        edge_distance_mean_px: 1.0,
        ncc: 0.9,
        ssim: 0.9,
        mutual_information_nats: 1.0,
        gradient_correlation: 0.8,
        region_margin_px: 10,
        region_px: 100,
        ncc_detector: 0.95,
        ssim_detector: 0.95,
        mutual_information_nats_detector: 1.0,
        gradient_correlation_detector: 0.9,
        mean_abs_diff: 0.1,
    }
}

fn landmark(target: &str, name: &str, shift: f64) -> LandmarkRow {
    LandmarkRow {
        target: target.into(),
        view: "lat".into(),
        family: Family::Focal,
        df_px: 500.0,
        dcx_px: 0.0,
        dcy_px: 0.0,
        landmark: name.into(),
        ref_u_px: 0.0,
        ref_v_px: 0.0,
        meas_u_px: shift,
        meas_v_px: 0.0,
        shift_px: shift,
        pred_u_px: shift,
        pred_v_px: 0.0,
        pred_shift_px: shift,
        pred_error_px: 0.0,
    }
}

fn summary(target: &str, trans: f64) -> RegistrationSummaryRow {
    RegistrationSummaryRow {
        target: target.into(),
        method: RegistrationMethod::Kabsch,
        df_px: 500.0,
        piercing_px: 0.0,
        trials: 3,
        failed: 0,
        n: 3,
        deterministic: true,
        rot_err_deg_mean: 0.1,
        rot_err_deg_sd: 0.0,
        rot_err_deg_ci95: 0.0,
        trans_err_mm_mean: trans,
        trans_err_mm_sd: 0.0,
        trans_err_mm_ci95: 0.0,
        residual_px_mean: 0.0,
        residual_px_sd: 0.0,
        residual_px_ci95: 0.0,
    }
}

fn find<'a>(rows: &'a [CohortRow], scope: &str, metric: &str, landmark: &str) -> &'a CohortRow {
    rows.iter()
        .find(|r| r.scope == scope && r.metric == metric && r.landmark == landmark)
        .unwrap_or_else(|| panic!("no row {scope} {metric} {landmark}"))
}

fn close(a: f64, b: f64) {
    assert!((a - b).abs() < 1e-12, "{a} vs {b}");
}

/// Cases a (L1), b (L1) and c (L1, L2) and c's segment (not a sample). By hand, Dice samples
/// {0.9, 0.8, 0.6, 0.7}: mean 0.75, sd √(0.05/3), median 0.75, p5 at position 0.15 of the sorted
/// values 0.6 + 0.15·0.1 = 0.615, p95 at 2.85: 0.8 + 0.85·0.1 = 0.885; case c {0.6, 0.7}: mean 0.65,
/// sd 0.1/√2, p5 0.605, p95 0.695.
#[test]
fn cohort_statistics_match_a_hand_computation() {
    let mut t = StudyTables::default();
    for (target, dice) in [
        ("d-a-L1", 0.9),
        ("d-b-L1", 0.8),
        ("d-c-L1", 0.6),
        ("d-c-L2", 0.7),
        ("d-c-segment", 0.1),
    ] {
        t.projection.push(projection(target, dice));
    }
    // Landmark `*` samples are each target's mean shift: a (1 + 3)/2 = 2, b 4, c-L1 6 (NaN dropped).
    for (target, name, shift) in [
        ("d-a-L1", "center", 1.0),
        ("d-a-L1", "tip", 3.0),
        ("d-b-L1", "center", 4.0),
        ("d-b-L1", "tip", 4.0),
        ("d-c-L1", "center", 6.0),
        ("d-c-L1", "tip", f64::NAN),
    ] {
        t.landmarks.push(landmark(target, name, shift));
    }
    for (target, trans) in [("d-a-L1", 1.0), ("d-b-L1", 2.0), ("d-c-L1", 4.0)] {
        t.registration_summary.push(summary(target, trans));
    }
    let case_of: BTreeMap<String, String> = [
        ("d-a-L1", "d/a"),
        ("d-b-L1", "d/b"),
        ("d-c-L1", "d/c"),
        ("d-c-L2", "d/c"),
    ]
    .iter()
    .map(|(t, c)| (t.to_string(), c.to_string()))
    .collect();
    let rows = cohort_rows(&t, &case_of);

    let d = find(&rows, "pooled", "dice", "");
    assert_eq!(
        (d.n, d.view.as_str(), d.family.as_str()),
        (4, "ap", "focal")
    );
    close(d.mean, 0.75);
    close(d.sd, (0.05f64 / 3.0).sqrt());
    close(d.median, 0.75);
    close(d.p5, 0.615);
    close(d.p95, 0.885);
    let c = find(&rows, "d/c", "dice", "");
    assert_eq!(c.n, 2);
    close(c.mean, 0.65);
    close(c.sd, 0.1 / 2f64.sqrt());
    close(c.p5, 0.605);
    close(c.p95, 0.695);
    let a = find(&rows, "d/a", "dice", "");
    assert_eq!((a.n, a.mean, a.sd, a.p5, a.p95), (1, 0.9, 0.0, 0.9, 0.9));

    // `*`: {2, 4, 6}: median 4, p5 2 + 0.1·2 = 2.2, p95 4 + 0.9·2 = 5.8.
    let all = find(&rows, "pooled", "shift_px", "*");
    assert_eq!(all.n, 3);
    close(all.mean, 4.0);
    close(all.median, 4.0);
    close(all.p5, 2.2);
    close(all.p95, 5.8);
    // Per landmark: `tip` {3, 4} (c's NaN is not counted).
    let tip = find(&rows, "pooled", "shift_px", "tip");
    assert_eq!(tip.n, 2);
    close(tip.mean, 3.5);

    // Registration, per target the mean over trials: {1, 2, 4}; sd √((1.33² + 0.33² + 1.67²)/2).
    let r = find(&rows, "pooled", "trans_err_mm", "");
    assert_eq!((r.n, r.method.as_str(), r.dcx_px), (3, "kabsch", 0.0));
    close(r.mean, 7.0 / 3.0);
    close(
        r.sd,
        (((4.0f64 / 3.0).powi(2) + (1.0f64 / 3.0).powi(2) + (5.0f64 / 3.0).powi(2)) / 2.0).sqrt(),
    );
    close(r.median, 2.0);
    // The table through the csv crate and back is the same.
    let dir = tempfile::tempdir().unwrap();
    spinedrr::study::schema::write_rows(dir.path(), &rows).unwrap();
    let back: Vec<CohortRow> = spinedrr::study::schema::read_rows(dir.path()).unwrap();
    assert_eq!(back.len(), rows.len());
    assert_eq!(back[0], rows[0]);
}

/// `spinedrr phantom --ct` of L1–L2 into `dir` as `ct.nii.gz` and a label map named `seg` in
/// convention `labels`.
fn synthetic_case(dir: &Path, seg: &str, labels: &str) {
    std::fs::create_dir_all(dir).unwrap();
    let (ok, err) = Spinedrr::new()
        .args([
            "phantom",
            "--levels",
            "L1-L2",
            "--no-discs",
            "--voxel-mm",
            "1.5",
        ])
        .args(["--ct-voxel-mm", "1.5", "--labels", labels, "--ct"])
        .arg(dir.join("ct.nii.gz"))
        .arg("--labels-out")
        .arg(dir.join(seg))
        .arg("--out")
        .arg(dir.join("mesh"))
        .outcome();
    assert!(ok, "{err}");
}

/// A TotalSegmentator-layout dataset of `good` and `bad` (its CT cut to 20 000 bytes) and a
/// one-unit-per-case config with `strict`.
fn truncated_dataset(dir: &Path, strict: bool) -> PathBuf {
    let ds = dir.join("ds");
    synthetic_case(&ds.join("good"), "segmentations.nii.gz", "totalseg");
    std::fs::create_dir_all(ds.join("bad")).unwrap();
    let ct = std::fs::read(ds.join("good/ct.nii.gz")).unwrap();
    std::fs::write(ds.join("bad/ct.nii.gz"), &ct[..20_000]).unwrap();
    std::fs::copy(
        ds.join("good/segmentations.nii.gz"),
        ds.join("bad/segmentations.nii.gz"),
    )
    .unwrap();
    let config = dir.join(format!("study-{strict}.toml"));
    std::fs::write(
        &config,
        format!(
            r#"experiments = ["projection"]
heatmaps_df_px = [500.0]
[anatomy]
levels = []
[[anatomy.dataset]]
name = "syn"
folder = "ds"
layout = "totalseg"
levels = ["L1"]
strict = {strict}
[geometry]
binning = 4
views = ["ap"]
[perturbations]
df_px = [500]
piercing_px = [0]
skew_px = []
pixel_scale = []
"#
        ),
    )
    .unwrap();
    config
}

#[test]
fn truncated_case_is_skipped_and_listed_or_stops_a_strict_run() {
    let dir = tempfile::tempdir().unwrap();
    let lenient = truncated_dataset(dir.path(), false);
    let strict = dir.path().join("study-true.toml");
    std::fs::write(
        &strict,
        std::fs::read_to_string(&lenient)
            .unwrap()
            .replace("strict = false", "strict = true"),
    )
    .unwrap();
    let bad = dir.path().join("ds/bad/ct.nii.gz");

    let out = dir.path().join("out");
    let (ok, err) = Spinedrr::new()
        .args(["study", "--threads", "2", "--config"])
        .arg(&lenient)
        .arg("--out")
        .arg(&out)
        .outcome();
    assert!(ok, "{err}");
    assert!(
        err.contains("case 'bad' left out") && err.contains(&bad.display().to_string()),
        "{err}"
    );
    let left = std::fs::read_to_string(out.join("tables/cohort_left_out.csv")).unwrap();
    assert!(
        left.starts_with("dataset,case,file,reason\nsyn,bad,"),
        "{left}"
    );
    assert!(left.contains("truncated"), "{left}");
    let report = crate::common::read_report(&out);
    let section = &report[report.find("### Cases left out").expect("left-out table")..];
    assert!(section.contains("| syn | bad |"), "{section}");
    let units: Vec<String> = std::fs::read_dir(out.join("units"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        units,
        ["proj_syn-good-L1_ap_focal_df500_cx0_cy0_s0_sy1.json"]
    );
    let cohort = std::fs::read_to_string(out.join("tables/cohort.csv")).unwrap();
    assert!(
        cohort.contains("\nsyn/good,projection,dice,ap,,focal,500,"),
        "{cohort}"
    );

    let out = dir.path().join("strict-out");
    let (ok, err) = Spinedrr::new()
        .args(["study", "--threads", "2", "--config"])
        .arg(&strict)
        .arg("--out")
        .arg(&out)
        .outcome();
    assert!(!ok, "a strict dataset with a truncated case must fail");
    assert!(
        err.contains("strict = true") && err.contains(&bad.display().to_string()),
        "{err}"
    );
    assert!(!out.join("units").exists(), "no work may start");
    assert!(!out.join("cohort/manifest.json").exists());
}

/// The VerSe layout (`rawdata/sub-*/…_ct.nii.gz`, `derivatives/sub-*/…_seg-vert_msk.nii.gz`, labels
/// 20/21 = L1/L2) and TotalSegmentator per-structure masks (`segmentations/vertebrae_L1.nii.gz`,
/// merged into one label map with L1 = 31, L2 = 30) both become cases.
#[test]
fn verse_layout_and_totalseg_structure_masks_become_cases() {
    let dir = tempfile::tempdir().unwrap();
    let tmp = dir.path().join("tmp");
    synthetic_case(&tmp, "verse.nii.gz", "verse");
    let verse = dir.path().join("verse");
    let stem = "sub-gl003_dir-ax";
    for (from, to) in [
        ("ct.nii.gz", format!("rawdata/sub-gl003/{stem}_ct.nii.gz")),
        (
            "verse.nii.gz",
            format!("derivatives/sub-gl003/{stem}_seg-vert_msk.nii.gz"),
        ),
    ] {
        let to = verse.join(to);
        std::fs::create_dir_all(to.parent().unwrap()).unwrap();
        std::fs::copy(tmp.join(from), &to).unwrap();
    }
    // Per-structure masks of the same CT, as the TotalSegmentator dataset ships them.
    let ts = dir.path().join("ts").join("s0001");
    std::fs::create_dir_all(ts.join("segmentations")).unwrap();
    std::fs::copy(tmp.join("ct.nii.gz"), ts.join("ct.nii.gz")).unwrap();
    let seg = read_labels(&tmp.join("verse.nii.gz")).unwrap();
    for (name, id) in [("L1", 20u16), ("L2", 21)] {
        let mut m = seg.clone();
        m.values.iter_mut().for_each(|v| *v = u16::from(*v == id));
        write_labels(
            &ts.join(format!("segmentations/vertebrae_{name}.nii.gz")),
            &m,
        )
        .unwrap();
    }
    let config = dir.path().join("study.toml");
    std::fs::write(
        &config,
        r#"[anatomy]
levels = []
[[anatomy.dataset]]
name = "verse"
folder = "verse"
layout = "verse"
levels = ["L1", "L2"]
strict = true
[[anatomy.dataset]]
name = "ts"
folder = "ts"
layout = "totalseg"
levels = ["L1", "L2"]
strict = true
"#,
    )
    .unwrap();
    let cfg = StudyConfig::from_file(&config).unwrap();
    let out = dir.path().join("out");
    let expanded = spinedrr::study::cohort::resolve(&cfg, &out).unwrap();
    let names: Vec<&str> = expanded
        .anatomy
        .ct
        .iter()
        .map(|c| c.name.as_str())
        .collect();
    assert_eq!(names, ["verse-sub-gl003-dir-ax", "ts-s0001"]);
    let targets = spinedrr::study::units::targets(&expanded);
    assert!(
        targets.contains(&"verse-sub-gl003-dir-ax-L2".to_string()),
        "{targets:?}"
    );
    // The merged map: TotalSegmentator ids where the VerSe map had L1 and L2, zero elsewhere.
    let merged = read_labels(&expanded.anatomy.ct[1].seg).unwrap();
    assert!(merged.values.iter().zip(&seg.values).all(|(&m, &v)| m
        == match v {
            20 => 31,
            21 => 30,
            _ => 0,
        }));
    assert!(
        expanded.anatomy.ct[1]
            .seg
            .starts_with(out.join("cohort/labels"))
    );
}
