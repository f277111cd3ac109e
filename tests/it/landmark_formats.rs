//! Landmarks in the formats users have: 3D Slicer markups (`.mrk.json`, LPS or RAS) and VerSe centroid
//! lists, read through the one reader beside our own JSON. Checked by round trips, by files written by
//! hand in both coordinate systems, and by a VerSe file whose voxel coordinates are worked out by hand
//! on a label map with a known, permuted and flipped affine.

use std::path::{Path, PathBuf};

use glam::{DMat4, DVec3, DVec4};
use spinedrr::anatomy::Landmarks;
use spinedrr::anatomy::ct::LabelMap;
use spinedrr::anatomy::labels::{LabelConvention, Level};
use spinedrr::anatomy::markups::{
    ImageGrid, LandmarkContext, VerseUnits, read_landmarks, read_landmarks_with,
    read_verse_centroids, write_landmarks,
};

fn two_levels() -> Vec<Landmarks> {
    let set = |level: &str, pts: &[(&str, [f64; 3])]| Landmarks {
        level: level.into(),
        points: pts
            .iter()
            .map(|(n, p)| (n.to_string(), DVec3::from_array(*p)))
            .collect(),
    };
    vec![
        set(
            "L3",
            &[
                ("center", [1.25, -2.5, 3.0625]),
                ("spinous_tip", [0.1, -64.3, -6.7]),
                ("left_pedicle", [-16.5, -21.5, 4.25]),
            ],
        ),
        set("L4", &[("center", [-0.3, 4.0e-3, -31.9])]),
    ]
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn ours_to_slicer_to_ours_round_trips_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let sets = two_levels();
    let mrk = dir.path().join("lm.mrk.json");
    write_landmarks(&mrk, &sets).unwrap();
    // The file is what Slicer expects: one Fiducial node per level, LPS positions (x, y negated).
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&mrk).unwrap()).unwrap();
    assert!(
        v["@schema"]
            .as_str()
            .unwrap()
            .contains("markups-schema-v1.0.3.json")
    );
    let node = &v["markups"][0];
    assert_eq!(node["type"], "Fiducial");
    assert_eq!(node["name"], "L3");
    assert_eq!(node["coordinateSystem"], "LPS");
    let cp = node["controlPoints"].as_array().unwrap();
    let center = cp.iter().find(|p| p["label"] == "center").unwrap();
    assert_eq!(center["position"], serde_json::json!([-1.25, 2.5, 3.0625]));
    assert_eq!(v["markups"][1]["name"], "L4");
    // Back, then through our own JSON and back again: nothing moves by a bit.
    let back = read_landmarks(&mrk).unwrap();
    assert_eq!(back, sets);
    let ours = dir.path().join("lm.json");
    write_landmarks(&ours, &back).unwrap();
    assert!(
        std::fs::read_to_string(&ours)
            .unwrap()
            .contains("\"units\"")
    );
    assert_eq!(read_landmarks(&ours).unwrap(), sets);
}

#[test]
fn an_lps_file_lands_where_the_ras_file_does() {
    let dir = tempfile::tempdir().unwrap();
    let doc = |system: &str, p: [f64; 3], units: &str| {
        format!(
            r#"{{"@schema": "x", "markups": [{{"type": "Fiducial", "name": "L1", {system}
            {units} "controlPoints": [{{"label": "center", "position": [{}, {}, {}]}},
            {{"label": "ghost", "positionStatus": "undefined"}}]}}]}}"#,
            p[0], p[1], p[2]
        )
    };
    let ras = write(
        dir.path(),
        "ras.mrk.json",
        &doc(r#""coordinateSystem": "RAS","#, [12.5, -40.0, 7.0], ""),
    );
    let lps = write(
        dir.path(),
        "lps.json",
        &doc(r#""coordinateSystem": "LPS","#, [-12.5, 40.0, 7.0], ""),
    );
    // Without the field the schema's default applies: LPS.
    let default = write(dir.path(), "d.mrk.json", &doc("", [-12.5, 40.0, 7.0], ""));
    let micrometres = write(
        dir.path(),
        "um.mrk.json",
        &doc(
            "",
            [-12500.0, 40000.0, 7000.0],
            r#""coordinateUnits": "um","#,
        ),
    );
    let want = DVec3::new(12.5, -40.0, 7.0);
    for p in [&ras, &lps, &default, &micrometres] {
        let sets = read_landmarks(p).unwrap();
        assert_eq!(sets.len(), 1, "{}", p.display());
        assert_eq!(sets[0].level, "L1");
        // The undefined point has no position and is skipped.
        assert_eq!(sets[0].points.len(), 1, "{}", p.display());
        let got = sets[0].get("center").unwrap();
        assert!((got - want).length() < 1e-12, "{}: {got}", p.display());
    }
}

#[test]
fn slicer_labels_with_a_level_prefix_and_compare_naming() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "F.mrk.json",
        r#"{"markups": [{"type": "Fiducial", "name": "F", "coordinateSystem": "RAS",
        "controlPoints": [{"label": "L1/center", "position": [1, 2, 3]},
                          {"label": "L2/center", "position": [4, 5, 6]}]}]}"#,
    );
    let sets = read_landmarks(&p).unwrap();
    let levels: Vec<&str> = sets.iter().map(|s| s.level.as_str()).collect();
    assert_eq!(levels, ["L1", "L2"]);
    // `compare --landmarks` names landmarks of several levels LEVEL/name, as for our own files.
    let flat = spinedrr::analysis::read_landmarks(&p).unwrap();
    let names: Vec<&str> = flat.iter().map(|l| l.name.as_str()).collect();
    assert_eq!(names, ["L1/center", "L2/center"]);
    assert_eq!(flat[1].position, DVec3::new(4.0, 5.0, 6.0));
}

/// A label map whose voxel axes run posterior, inferior and right (codes P, I, R) with unequal
/// spacings, carrying VerSe labels 20 (L1) and 21 (L2).
fn pir_grid() -> LabelMap {
    let a = DMat4::from_cols(
        DVec4::new(0.0, -0.9, 0.0, 0.0),
        DVec4::new(0.0, 0.0, -1.2, 0.0),
        DVec4::new(0.7, 0.0, 0.0, 0.0),
        DVec4::new(12.0, 80.0, -30.0, 1.0),
    );
    let mut seg = LabelMap::filled([40, 50, 30], 0, a).unwrap();
    let n = seg.linear(3, 4, 5);
    seg.values[n] = 20;
    let n = seg.linear(6, 7, 8);
    seg.values[n] = 21;
    seg
}

/// World point of continuous index (i, j, k) of [`pir_grid`], written out by hand.
fn pir_world(i: f64, j: f64, k: f64) -> DVec3 {
    DVec3::new(12.0 + 0.7 * k, 80.0 - 0.9 * i, -30.0 - 1.2 * j)
}

fn verse_doc(codes: &str, rows: &[(u16, [f64; 3])]) -> String {
    let mut s = format!(r#"[{{"direction": {codes}}}"#);
    for (l, p) in rows {
        s += &format!(
            r#", {{"label": {l}, "X": {}, "Y": {}, "Z": {}}}"#,
            p[0], p[1], p[2]
        );
    }
    s + "]"
}

#[test]
fn verse_centroids_land_where_the_hand_worked_affine_puts_them() {
    let dir = tempfile::tempdir().unwrap();
    let seg = pir_grid();
    let grid = ImageGrid::of(&seg);
    // The image's own codes: the coordinates are its voxel indices.
    let (l1, l2) = ([10.5, 20.25, 7.0], [30.0, 44.5, 22.75]);
    let want = [pir_world(10.5, 20.25, 7.0), pir_world(30.0, 44.5, 22.75)];
    let own = write(
        dir.path(),
        "own_ctd.json",
        &verse_doc(r#"["P", "I", "R"]"#, &[(20, l1), (21, l2)]),
    );
    // The same centroids for the image reoriented to A, S, L (every axis flipped: n − 1 − i) …
    let flip = |p: [f64; 3]| [39.0 - p[0], 49.0 - p[1], 29.0 - p[2]];
    let flipped = write(
        dir.path(),
        "asl_ctd.json",
        &verse_doc(r#"["A", "S", "L"]"#, &[(20, flip(l1)), (21, flip(l2))]),
    );
    // … and to I, R, P (axes permuted): X along I is the old Y, and so on.
    let perm = |p: [f64; 3]| [p[1], p[2], p[0]];
    let permuted = write(
        dir.path(),
        "irp_ctd.json",
        &verse_doc(r#"["I", "R", "P"]"#, &[(20, perm(l1)), (21, perm(l2))]),
    );
    for p in [&own, &flipped, &permuted] {
        let c = read_verse_centroids(p, &grid, VerseUnits::Voxels).unwrap();
        assert_eq!(c.len(), 2);
        assert_eq!((c[0].label, c[0].level), (20, Level::L(1)));
        assert_eq!((c[1].label, c[1].level), (21, Level::L(2)));
        for (got, w) in c.iter().zip(want) {
            let e = (got.world_mm - w).length();
            assert!(e < 1e-9, "{}: {} vs {w}", p.display(), got.world_mm);
        }
    }
    // Millimetres from the first voxel along each stated axis (index × spacing).
    let mm = |p: [f64; 3]| [p[0] * 0.9, p[1] * 1.2, p[2] * 0.7];
    let in_mm = write(
        dir.path(),
        "mm_ctd.json",
        &verse_doc(r#"["P", "I", "R"]"#, &[(20, mm(l1)), (21, mm(l2))]),
    );
    let c = read_verse_centroids(&in_mm, &grid, VerseUnits::Millimetres).unwrap();
    assert!((c[1].world_mm - want[1]).length() < 1e-9);
    // Through the one reader, beside the label map: a `center` landmark per level.
    let ctx = LandmarkContext {
        seg: Some((&seg, LabelConvention::Verse)),
        ..Default::default()
    };
    let sets = read_landmarks_with(&flipped, &ctx).unwrap();
    assert_eq!(sets[0].level, "L1");
    assert!((sets[1].get("center").unwrap() - want[1]).length() < 1e-9);
    // A TotalSegmentator map of the same image (L1 = 31, L2 = 30) matches the levels by name.
    let ts = seg.map(|v| match v {
        20 => 31,
        21 => 30,
        x => x,
    });
    let ctx = LandmarkContext {
        seg: Some((&ts, LabelConvention::TotalSegmentator)),
        ..Default::default()
    };
    assert_eq!(read_landmarks_with(&own, &ctx).unwrap().len(), 2);
}

#[test]
fn bad_landmark_files_name_the_file_and_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let err =
        |p: &Path, ctx: &LandmarkContext| read_landmarks_with(p, ctx).unwrap_err().to_string();
    let none = LandmarkContext::default();
    let seg = pir_grid();
    let with_seg = LandmarkContext {
        seg: Some((&seg, LabelConvention::Verse)),
        ..Default::default()
    };

    let p = write(
        dir.path(),
        "ijk.mrk.json",
        r#"{"markups": [{"type": "Fiducial", "coordinateSystem": "IJK",
        "controlPoints": [{"label": "a", "position": [1, 2, 3]}]}]}"#,
    );
    let e = err(&p, &none);
    assert!(
        e.contains("ijk.mrk.json")
            && e.contains("markups[0].coordinateSystem")
            && e.contains("IJK"),
        "{e}"
    );
    let p = write(
        dir.path(),
        "nopos.mrk.json",
        r#"{"markups": [{"name": "L1", "controlPoints": [{"label": "a"}]}]}"#,
    );
    let e = err(&p, &none);
    assert!(e.contains("markups[0].controlPoints[0].position"), "{e}");
    let p = write(
        dir.path(),
        "twice.mrk.json",
        r#"{"markups": [{"name": "L1", "controlPoints": [{"label": "a", "position": [1, 2, 3]},
        {"label": "a", "position": [1, 2, 4]}]}]}"#,
    );
    assert!(err(&p, &none).contains("\"a\" of level \"L1\" appears twice"));

    // Malformed JSON, whatever the format.
    for name in ["broken.mrk.json", "broken.json"] {
        let p = write(dir.path(), name, r#"{"markups": [{"name": "L1", "#);
        let e = err(&p, &none);
        assert!(e.contains(name) && e.contains("not JSON"), "{e}");
    }

    // A VerSe file naming a level the label map lacks (L3 = 22).
    let p = write(
        dir.path(),
        "l3_ctd.json",
        &verse_doc(
            r#"["P", "I", "R"]"#,
            &[(20, [1.0, 2.0, 3.0]), (22, [5.0, 5.0, 5.0])],
        ),
    );
    let e = err(&p, &with_seg);
    assert!(
        e.contains("l3_ctd.json") && e.contains("label 22") && e.contains("L3"),
        "{e}"
    );
    // … read without any image, it cannot be placed at all.
    let e = err(&p, &none);
    assert!(
        e.contains("l3_ctd.json") && e.contains("voxel coordinates"),
        "{e}"
    );
    // Axis codes that do not name three axes; a label outside VerSe's; a centroid off the image.
    for (name, doc, field) in [
        (
            "pp_ctd.json",
            verse_doc(r#"["P", "P", "R"]"#, &[(20, [1.0, 2.0, 3.0])]),
            "[0].direction",
        ),
        (
            "xx_ctd.json",
            verse_doc(r#"["P", "X", "R"]"#, &[(20, [1.0, 2.0, 3.0])]),
            "[0].direction",
        ),
        (
            "label_ctd.json",
            verse_doc(r#"["P", "I", "R"]"#, &[(29, [1.0, 2.0, 3.0])]),
            "[1].label",
        ),
        (
            "off_ctd.json",
            verse_doc(r#"["P", "I", "R"]"#, &[(20, [1.0, 200.0, 3.0])]),
            "outside",
        ),
    ] {
        let p = write(dir.path(), name, &doc);
        let e = err(&p, &with_seg);
        assert!(e.contains(name) && e.contains(field), "{e}");
    }
}
