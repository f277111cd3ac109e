//! A study of the user's own anatomy: a box mesh file plus a landmarks JSON through `[[anatomy.meshes]]`.
//! The homography law and the exact piercing translation must hold for it too.

use std::path::Path;
use std::process::Output;

use glam::DVec3;
use spinedrr::anatomy::{Structure, TriMesh, write_mesh};
use spinedrr::study::schema::Family;
use spinedrr::study::{StudyConfig, StudyTables};

use crate::common::{Spinedrr, all_but_intensity};

/// Runs `spinedrr study --config CFG --out OUT [EXTRA…]`.
fn run_study(cfg: &Path, out: &Path, extra: &[&str]) -> Output {
    Spinedrr::new()
        .args([
            "study",
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .args(extra)
        .output()
}

/// The box's corner landmarks: names and positions (mm).
fn box_corners(names: &[&str; 5]) -> Vec<(String, DVec3)> {
    let (lo, hi) = (
        DVec3::new(-20.0, -15.0, -12.0),
        DVec3::new(20.0, 15.0, 12.0),
    );
    [
        (lo.x, lo.y, lo.z),
        (hi.x, lo.y, lo.z),
        (lo.x, hi.y, lo.z),
        (lo.x, lo.y, hi.z),
        (hi.x, hi.y, hi.z),
    ]
    .iter()
    .zip(names)
    .map(|(&(x, y, z), n)| (n.to_string(), DVec3::new(x, y, z)))
    .collect()
}

/// A 40 × 30 × 24 mm box and five of its corners as landmarks in `dir`, studied on a small grid; returns
/// the config file.
fn box_study(dir: &Path) -> std::path::PathBuf {
    box_study_named(dir, &["c0", "c1", "c2", "c3", "c4"])
}

/// [`box_study`] with the corner landmarks called `names`.
fn box_study_named(dir: &Path, names: &[&str; 5]) -> std::path::PathBuf {
    let (lo, hi) = (
        DVec3::new(-20.0, -15.0, -12.0),
        DVec3::new(20.0, 15.0, 12.0),
    );
    let stl = dir.join("box.stl");
    write_mesh(&stl, &TriMesh::cuboid("box", lo, hi)).expect("write box.stl");
    let mut lm = String::from("{\"level\": \"box\", \"units\": \"mm\", \"landmarks\": {");
    let corners: Vec<String> = box_corners(names)
        .iter()
        .map(|(n, p)| format!("{}: [{}, {}, {}]", serde_json::json!(n), p.x, p.y, p.z))
        .collect();
    lm.push_str(&corners.join(", "));
    lm.push_str("}}");
    let lm_path = dir.join("box-landmarks.json");
    std::fs::write(&lm_path, lm).unwrap();
    let cfg = format!(
        "[anatomy]\nlevels = []\nsegment = false\nmarker_radius_mm = 5.0\n\
[[anatomy.meshes]]\nname = \"box\"\nfiles = [{:?}]\nlandmarks = {:?}\n\
[geometry]\nbinning = 2\n[perturbations]\ndf_px = [100.0, 500.0]\npiercing_px = [0.0, 20.0]\nskew_px = []\npixel_scale = []\n\
[registration]\nmethods = [\"kabsch\"]\ndf_px = [0.0, 300.0]\npiercing_px = [0.0]\ntrials = 2\nnoise_px = 0.0\n",
        stl.to_str().unwrap(),
        lm_path.to_str().unwrap()
    );
    let cfg_path = dir.join("study.toml");
    std::fs::write(&cfg_path, cfg).unwrap();
    cfg_path
}

#[test]
fn mesh_target_study_obeys_the_homography_law() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cfg_path = box_study(dir.path());
    // The box through every experiment but the intensity registration (the phantom's L3, not the box:
    // measured, this test took 39 CPU-seconds with it, 3 without).
    let text = std::fs::read_to_string(&cfg_path).unwrap();
    std::fs::write(&cfg_path, format!("{}\n{text}", all_but_intensity())).unwrap();
    let out = dir.path().join("out");
    let o = run_study(&cfg_path, &out, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The provenance names each input file by its BLAKE3 digest (as b3sum computes it), and
    // inputs.csv beside the report lists them with their paths and sizes.
    let md = crate::common::read_report(&out);
    let line = md
        .lines()
        .find(|l| l.starts_with(spinedrr::study::report::PROVENANCE))
        .expect("provenance");
    let csv = std::fs::read_to_string(out.join("inputs.csv")).unwrap();
    assert!(csv.starts_with("file,bytes,blake3\n"), "{csv}");
    assert_eq!(csv.lines().count(), 3, "{csv}");
    for name in ["box.stl", "box-landmarks.json"] {
        let path = dir.path().join(name);
        let bytes = std::fs::read(&path).unwrap();
        let hash = blake3::hash(&bytes).to_hex().to_string();
        assert!(
            line.contains(&format!("`{name}` (BLAKE3 `{hash}`)")),
            "{line}"
        );
        assert!(
            csv.lines()
                .any(|l| l.ends_with(&format!(",{},{hash}", bytes.len()))
                    && l.starts_with(path.to_str().unwrap())),
            "{name}: {csv}"
        );
    }
    let tables = StudyTables::load(&out).expect("tables");
    let t = &tables.landmarks;
    assert_eq!(
        t.len(),
        5 * 2 * 4,
        "5 landmarks × 2 views × 4 perturbations (focal 100, 500; piercing 20; joint (100, 20))"
    );
    for r in t {
        assert_eq!(r.target, "box");
        assert!(r.pred_error_px <= 0.05, "{r:?}");
        if r.family == Family::Piercing {
            let du = r.meas_u_px - r.ref_u_px;
            assert!((du - 20.0).abs() < 1e-6, "{r:?}");
        }
    }
    assert!(tables.projection.iter().all(|r| r.dice < 1.0));
    let zero = tables
        .registration_summary
        .iter()
        .find(|r| r.df_px == 0.0)
        .expect("Δf 0");
    assert!(zero.rot_err_deg_mean < 1e-6);
    // Without observation noise every trial of a cell converges to one answer: one value in the report.
    assert!(tables.registration_summary.iter().all(|r| r.deterministic));
    let md = crate::common::read_report(&out);
    assert!(
        md.contains("(all 2 agree)"),
        "no one-value cell in the report"
    );
    let pm: Vec<&str> = md.lines().filter(|l| l.contains('±')).collect();
    assert!(
        pm.is_empty(),
        "a ± in a report over identical trials: {pm:?}"
    );
}

/// The report's *Setup* flags a target whose silhouette the detector cuts: the box moved 100 mm to the
/// patient's right reaches past the AP detector's edge (u = 255.5 + 2250·x/1000 > 511 for x > 114 mm on
/// the 2× binned detector), and stays whole in LAT, where x is depth.
#[test]
fn a_target_cut_by_the_detector_edge_is_flagged_in_the_setup() {
    let dir = tempfile::tempdir().expect("temp dir");
    let base = std::fs::read_to_string(box_study(dir.path())).unwrap();
    let (lo, hi) = (
        DVec3::new(80.0, -15.0, -12.0),
        DVec3::new(120.0, 15.0, 12.0),
    );
    write_mesh(&dir.path().join("box.stl"), &TriMesh::cuboid("box", lo, hi)).unwrap();
    let cfg = dir.path().join("shifted.toml");
    std::fs::write(
        &cfg,
        format!("experiments = [\"projection\", \"landmarks\"]\n{base}"),
    )
    .unwrap();
    let out = dir.path().join("out");
    let o = run_study(&cfg, &out, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = crate::common::read_report(&out);
    let row = |view: &str| {
        md.lines()
            .find(|l| l.starts_with(&format!("| box | {view} |")))
            .unwrap_or_else(|| panic!("no Setup row for box {view}"))
            .to_string()
    };
    // Cut in the reference and in every perturbed cell: the Setup says both.
    assert!(
        row("AP").ends_with("| **cut by the edge**; **cut in 4 of 4 perturbed cells** |"),
        "{}",
        row("AP")
    );
    assert!(row("LAT").ends_with("| whole |"), "{}", row("LAT"));
}

/// A box whose x faces are labelled `pedicle_left` and the rest `body` (binary STL keeps the labels), so
/// the structures table has two rows per cell.
fn labelled_cuboid(name: &str, lo: DVec3, hi: DVec3) -> TriMesh {
    let mut m = TriMesh::cuboid(name, lo, hi);
    m.labels = (0..m.triangles.len())
        .map(|i| {
            if i >= 8 {
                Structure::PedicleLeft as u8
            } else {
                Structure::Body as u8
            }
        })
        .collect();
    m
}

/// A cut target is left out of pooled numbers: beside two whole boxes `a` and `b`, the shifted box's
/// Dice is reported apart and flagged, the structures' means leave it out and say so, and no claim of
/// `findings.json` pools it with them — but registration, which observes its landmarks analytically
/// (wherever the detector's edge is), pools all three levels.
#[test]
fn a_target_cut_by_the_detector_edge_is_left_out_of_pooled_findings() {
    let dir = tempfile::tempdir().expect("temp dir");
    let base = std::fs::read_to_string(box_study(dir.path())).unwrap();
    let lm = std::fs::read_to_string(dir.path().join("box-landmarks.json")).unwrap();
    write_mesh(
        &dir.path().join("box.stl"),
        &labelled_cuboid(
            "box",
            DVec3::new(80.0, -15.0, -12.0),
            DVec3::new(120.0, 15.0, 12.0),
        ),
    )
    .unwrap();
    let mut extra = String::new();
    for (name, half) in [("a", 20.0), ("b", 25.0)] {
        let stl = dir.path().join(format!("{name}.stl"));
        let h = DVec3::new(half, 15.0, 12.0);
        write_mesh(&stl, &labelled_cuboid(name, -h, h)).unwrap();
        let json = dir.path().join(format!("{name}.json"));
        std::fs::write(&json, lm.replace("\"box\"", &format!("{name:?}"))).unwrap();
        extra.push_str(&format!(
            "[[anatomy.meshes]]\nname = {name:?}\nfiles = [{:?}]\nlandmarks = {:?}\n",
            stl.to_str().unwrap(),
            json.to_str().unwrap()
        ));
    }
    let cfg = dir.path().join("three.toml");
    std::fs::write(
        &cfg,
        format!("experiments = [\"projection\", \"registration\"]\n{base}{extra}"),
    )
    .unwrap();
    let out = dir.path().join("out");
    let o = run_study(&cfg, &out, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("tables/findings.json")).unwrap())
            .unwrap();
    let findings = json["findings"].as_array().unwrap();
    let text = |id: &str| {
        findings
            .iter()
            .find(|f| f["id"] == id)
            .unwrap_or_else(|| panic!("no finding {id}"))["text"]
            .as_str()
            .unwrap()
            .to_string()
    };
    let dice = text("dice_by_family");
    assert!(
        dice.contains("box AP")
            && dice.contains("(cut by the detector edge in AP here: not comparable)"),
        "{dice}"
    );
    let structures = text("structures");
    assert!(
        structures.contains("over the single levels")
            && structures
                .contains("; box, cut by the detector edge in some cell, is left out of the means"),
        "{structures}"
    );
    assert!(
        text("registration_by_family").contains("a range over the 3 single levels"),
        "{}",
        text("registration_by_family")
    );
    let (mut pooled, mut registration) = (0, 0);
    for f in findings {
        for c in f["claims"].as_array().unwrap() {
            let mut targets: Vec<&str> = c["source"]["where"]["target"]
                .as_array()
                .map(|t| t.iter().filter_map(|x| x.as_str()).collect())
                .unwrap_or_default();
            targets.sort_unstable();
            if targets.len() > 1 {
                if c["source"]["table"] == "registration_summary.csv" {
                    registration += 1;
                    assert_eq!(targets, ["a", "b", "box"], "{}", c["id"]);
                } else {
                    pooled += 1;
                    assert_eq!(targets, ["a", "b"], "{}", c["id"]);
                }
            }
        }
    }
    assert!(pooled > 0, "no pooled claim over a and b");
    assert!(registration > 0, "no registration claim over the levels");
}

/// With landmark noise the trials of a cell differ; the 95 % CI of the mean is Student's, shrinks with
/// more trials, and the report shows it (never the one-value form).
#[test]
fn observation_noise_gives_each_cell_a_confidence_interval_that_shrinks_with_n() {
    let dir = tempfile::tempdir().expect("temp dir");
    let base = std::fs::read_to_string(box_study(dir.path())).unwrap();
    let mut half = Vec::new();
    for n in [5usize, 40] {
        let cfg = dir.path().join(format!("noise{n}.toml"));
        let text = format!("experiments = [\"registration\"]\n{base}").replace(
            "trials = 2\nnoise_px = 0.0\n",
            &format!("trials = {n}\nnoise_px = 0.5\n"),
        );
        std::fs::write(&cfg, text).unwrap();
        let out = dir.path().join(format!("out{n}"));
        let o = run_study(&cfg, &out, &[]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let t = StudyTables::load(&out).expect("tables");
        let trials = &t.registration;
        for s in &t.registration_summary {
            let v: Vec<f64> = trials
                .iter()
                .filter(|r| r.df_px == s.df_px && r.piercing_px == s.piercing_px)
                .map(|r| r.trans_err_mm)
                .collect();
            assert_eq!((s.n, v.len()), (n, n));
            assert!(!s.deterministic, "{s:?}");
            // Recomputed here: mean, sample sd, and t(0.975, n − 1) from the standard table.
            let mean = v.iter().sum::<f64>() / n as f64;
            let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt();
            let t975 = if n == 5 { 2.776 } else { 2.023 };
            assert!((s.trans_err_mm_mean - mean).abs() < 1e-9);
            assert!(sd > 1e-3, "noise σ 0.5 px left the trials equal: {v:?}");
            let h = t975 * sd / (n as f64).sqrt();
            assert!(
                (s.trans_err_mm_ci95 - h).abs() < 1e-3 * h,
                "{} vs {h}",
                s.trans_err_mm_ci95
            );
        }
        let md = crate::common::read_report(&out);
        assert!(!md.contains(" agree)"), "a noisy cell shown as one value");
        half.push(
            t.registration_summary
                .iter()
                .map(|s| s.trans_err_mm_ci95)
                .collect::<Vec<_>>(),
        );
    }
    for (a, b) in half[0].iter().zip(&half[1]) {
        assert!(
            b < a,
            "CI with 40 trials ({b}) not narrower than with 5 ({a})"
        );
    }
}

#[test]
fn missing_mesh_file_is_named_before_work() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cfg_path = dir.path().join("study.toml");
    std::fs::write(
        &cfg_path,
        "[anatomy]\nlevels = []\n[[anatomy.meshes]]\nname = \"mine\"\nfiles = [\"/nonexistent/x.stl\"]\nlandmarks = \"/nonexistent/l.json\"\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    let o = run_study(&cfg_path, &out, &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("anatomy.meshes") && err.contains("/nonexistent/x.stl"),
        "{err}"
    );
    assert!(!out.exists());
}

/// `--quick` with `--config`: the config's own target on the quick grid (piercing 50 px instead of the
/// config's 20, registration at Δf {0, 100, 500} instead of {0, 300}).
#[test]
fn quick_runs_a_config_on_the_quick_grid() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cfg_path = box_study(dir.path());
    let out = dir.path().join("out");
    let o = run_study(&cfg_path, &out, &["--quick"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let tables = StudyTables::load(&out).expect("tables");
    let t = &tables.landmarks;
    assert_eq!(t.len(), 5 * 2 * 4);
    for r in t {
        assert_eq!(r.target, "box");
        if r.family == Family::Piercing {
            let du = r.meas_u_px - r.ref_u_px;
            assert!((du - 50.0).abs() < 1e-6, "{r:?}");
        }
    }
    let s = &tables.registration_summary;
    let mut df: Vec<f64> = s.iter().map(|r| r.df_px).collect();
    df.sort_by(f64::total_cmp);
    df.dedup();
    assert_eq!(df, [0.0, 100.0, 500.0]);
}

/// Landmark names with a comma and a double quote run through the whole study, and its tables parse
/// with a standard CSV reader (the csv crate, not the study's own schema) to the right values: the names
/// come back exactly, and each reference position is the projection of the 3-D corner through the view.
#[test]
fn landmark_names_with_commas_and_quotes_survive_the_tables() {
    let names = [
        "corner, low",
        "say \"hi\"",
        "a,\"b\",c",
        "plain",
        "tab\tand, comma",
    ];
    let dir = tempfile::tempdir().expect("temp dir");
    let cfg_path = box_study_named(dir.path(), &names);
    let out = dir.path().join("out");
    let o = run_study(&cfg_path, &out, &["--quick"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut rdr = csv::Reader::from_path(out.join("tables/landmarks.csv")).expect("landmarks.csv");
    let header = rdr.headers().expect("header").clone();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| h == name)
            .unwrap_or_else(|| panic!("no column {name}"))
    };
    let (view_c, family_c, name_c) = (col("view"), col("family"), col("landmark"));
    let (u_c, v_c) = (col("ref_u_px"), col("ref_v_px"));
    let carm = StudyConfig::from_file(&cfg_path)
        .expect("config")
        .with_quick_grid()
        .carm()
        .expect("C-arm");
    let corners = box_corners(&names);
    let mut seen = std::collections::BTreeSet::new();
    let mut rows = 0;
    for rec in rdr.records() {
        let rec = rec.expect("a well-formed CSV record");
        assert_eq!(rec.len(), header.len(), "{rec:?}");
        let name = &rec[name_c];
        let (_, p) = corners
            .iter()
            .find(|(n, _)| n == name)
            .unwrap_or_else(|| panic!("landmark {name:?} is not one of the given names"));
        let expected = carm.view(&rec[view_c]).expect("view").project(*p);
        let (u, v): (f64, f64) = (rec[u_c].parse().unwrap(), rec[v_c].parse().unwrap());
        assert!(
            (u - expected.x).abs() < 0.05 && (v - expected.y).abs() < 0.05,
            "{name:?} {}: reference ({u}, {v}) vs projected {expected}",
            &rec[view_c]
        );
        assert!(["focal", "piercing", "joint"].contains(&&rec[family_c]));
        seen.insert(name.to_string());
        rows += 1;
    }
    assert_eq!(rows, 5 * 2 * 4);
    let given: std::collections::BTreeSet<String> = names.iter().map(|n| n.to_string()).collect();
    assert_eq!(seen, given);
    // The overlay and the report are written for these names too.
    assert!(out.join("figures/landmark_overlay_box_lat.png").is_file());
    assert!(out.join("report.html").is_file());
}

/// A landmark 100 mm beside the box, near the detector's edge in AP: its marker is cut by the edge in
/// some perturbed views, so those rows of `landmarks.csv` are NaN, and the report's sentence about them
/// states the counts a reader gets from the CSV (per target, view and landmark; the reference whole).
#[test]
fn unmeasured_landmarks_are_counted_in_the_report_as_in_the_table() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cfg_path = box_study(dir.path());
    let lm_path = dir.path().join("box-landmarks.json");
    let mut lm: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&lm_path).unwrap()).unwrap();
    lm["landmarks"]["edge"] = serde_json::json!([100.0, 0.0, 0.0]);
    std::fs::write(&lm_path, lm.to_string()).unwrap();
    let out = dir.path().join("out");
    let o = run_study(&cfg_path, &out, &["--quick"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut rdr = csv::Reader::from_path(out.join("tables/landmarks.csv")).expect("landmarks.csv");
    let header = rdr.headers().expect("header").clone();
    let col = |name: &str| header.iter().position(|h| h == name).unwrap();
    let (view_c, name_c, ref_c, shift_c) = (
        col("view"),
        col("landmark"),
        col("ref_u_px"),
        col("shift_px"),
    );
    let mut total = 0;
    let mut missing = std::collections::BTreeMap::<(String, String), usize>::new();
    for rec in rdr.records() {
        let rec = rec.expect("record");
        total += 1;
        if rec[shift_c].parse::<f64>().unwrap().is_nan() {
            assert!(rec[ref_c].parse::<f64>().unwrap().is_finite(), "{rec:?}");
            *missing
                .entry((rec[view_c].to_string(), rec[name_c].to_string()))
                .or_default() += 1;
        }
    }
    let n: usize = missing.values().sum();
    assert!(n > 0, "no marker was cut: the test lost its case");
    assert_eq!(
        missing
            .keys()
            .map(|(v, l)| (v.as_str(), l.as_str()))
            .collect::<Vec<_>>(),
        [("ap", "edge")],
        "only the edge landmark in AP is near the detector's edge: {missing:?}"
    );
    let cells = missing[&("ap".to_string(), "edge".to_string())];
    let md = crate::common::read_report(&out);
    let expected = format!(
        "{n} of {total} rows of landmarks.csv have NaN measurements, box AP: edge in {cells} cell{} \
         (each whole in the reference view and cut in the perturbed one).",
        if cells == 1 { "" } else { "s" }
    );
    assert!(
        md.contains(&expected),
        "{expected}\nnot in the report:\n{md}"
    );
}
