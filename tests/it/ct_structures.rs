//! Structures on CT vertebrae: the label surface of the phantom's synthetic CT, split into the phantom's
//! structures from its automatic landmark frame, against the structure labels the phantom's own mesh
//! carries (where the truth is known); `spinedrr mesh --structures` and Slicer landmarks end to end; and
//! a CT study target with VerSe landmarks that gets per-structure rows.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use glam::DVec3;
use spinedrr::anatomy::ct::{LabelMap, SurfaceOptions, label_surface, write_ct, write_labels};
use spinedrr::anatomy::decimate::SurfaceDistance;
use spinedrr::anatomy::structure_split::split_structures;
use spinedrr::anatomy::synthetic_ct::{SyntheticCtOptions, synthetic_ct};
use spinedrr::anatomy::vertebra::Level;
use spinedrr::anatomy::{
    Landmarks, Phantom, PhantomOptions, Structure, TriMesh, auto_landmarks, read_landmarks,
    read_mesh,
};

use crate::common::Spinedrr;

/// Two levels far apart in shape (L1: narrow pedicles; L5: wide, tilted by the lordosis), no discs, their
/// synthetic CT's label map (TotalSegmentator: L1 = 31, L5 = 27) and the files on disk.
struct Fixture {
    phantom: Phantom,
    seg: LabelMap,
    _dir: tempfile::TempDir,
    dir: PathBuf,
}

/// The phantom's synthetic CT and label map at 0.8 mm, one sample per voxel.
fn synthetic_ct_08(phantom: &Phantom) -> (spinedrr::anatomy::ct::CtVolume, LabelMap) {
    synthetic_ct(
        phantom,
        &SyntheticCtOptions {
            voxel_mm: 0.8,
            supersample: 1,
            ..Default::default()
        },
    )
    .expect("synthetic CT")
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let phantom = crate::common::phantom(&PhantomOptions {
            levels: vec![Level::L1, Level::L5],
            voxel_mm: 0.8,
            discs: false,
            ..Default::default()
        })
        .expect("phantom");
        let (ct, seg) = synthetic_ct_08(&phantom);
        let dir = tempfile::tempdir().expect("temp dir");
        write_ct(&dir.path().join("ct.nii"), &ct).expect("write CT");
        write_labels(&dir.path().join("seg.nii"), &seg).expect("write labels");
        let path = dir.path().to_path_buf();
        Fixture {
            phantom,
            seg,
            _dir: dir,
            dir: path,
        }
    })
}

fn area(m: &TriMesh, i: usize) -> f64 {
    let [a, b, c] = m.corners(i);
    0.5 * (b - a).cross(c - a).length()
}

/// Area-weighted share of `labels` (on `mesh`) that agree with the label of the nearest triangle of
/// `truth`, the per-structure areas (mm²: labelled, agreeing) and the largest disagreements
/// (labelled as, truth, mm²).
struct Agreement {
    share: f64,
    per: Vec<(Structure, f64, f64)>,
    confused: Vec<(Structure, Structure, f64)>,
}

fn agreement(mesh: &TriMesh, labels: &[u8], truth: &TriMesh) -> Agreement {
    let sd = SurfaceDistance::new(truth);
    let (mut total, mut same) = (0.0, 0.0);
    let n = Structure::ALL.len();
    let mut per = vec![(0.0, 0.0); n];
    let mut conf = vec![0.0; n * n];
    for (i, &l) in labels.iter().enumerate() {
        let [a, b, c] = mesh.corners(i);
        let (t, _) = sd.nearest((a + b + c) / 3.0).expect("truth has triangles");
        let w = area(mesh, i);
        total += w;
        per[l as usize].0 += w;
        let tl = truth.labels[t];
        if tl == l {
            same += w;
            per[l as usize].1 += w;
        } else {
            conf[l as usize * n + tl as usize] += w;
        }
    }
    let s = |k: usize| Structure::ALL[k];
    let mut confused: Vec<_> = (0..n * n).map(|k| (s(k / n), s(k % n), conf[k])).collect();
    confused.sort_by(|a, b| b.2.total_cmp(&a.2));
    confused.truncate(6);
    Agreement {
        share: same / total,
        per: Structure::ALL
            .iter()
            .map(|&s| (s, per[s as usize].0, per[s as usize].1))
            .collect(),
        confused,
    }
}

/// Splits each level's label surface of `seg` (TotalSegmentator ids: L1 = 31 … L5 = 27) from its
/// automatic landmarks and checks it against the phantom mesh's own labels: at least 90 % of the area
/// agrees, and every structure of the phantom's set is found, on both sides.
fn check_split_against_the_phantom(phantom: &Phantom, seg: &LabelMap) {
    let mut failures = Vec::new();
    for v in &phantom.vertebrae {
        let id = 31 - v.level.index() as u16;
        let mesh = label_surface(seg, id, &SurfaceOptions::default()).expect("label surface");
        let lm = auto_landmarks(&mesh, v.level.name()).expect("auto landmarks");
        let labels = split_structures(&mesh, &lm).expect("split");
        assert_eq!(labels.len(), mesh.triangles.len());
        let Agreement {
            share,
            per,
            confused,
        } = agreement(&mesh, &labels, &v.cortical);
        let table: Vec<String> = per
            .iter()
            .filter(|p| p.1 > 0.0)
            .map(|(s, a, ok)| format!("{} {:.0} mm² ({:.0}% agree)", s.name(), a, 100.0 * ok / a))
            .collect();
        let worst: Vec<String> = confused
            .iter()
            .map(|(a, b, w)| format!("{} for {}: {w:.0} mm²", a.name(), b.name()))
            .collect();
        eprintln!(
            "{}: {:.1}% agree; {table:?}; {worst:?}",
            v.level,
            100.0 * share
        );
        if share < 0.90 {
            failures.push(format!(
                "{}: {:.1}% of the area agrees: {table:?}; largest confusions {worst:?}",
                v.level,
                100.0 * share
            ));
        }
        // Every structure of the phantom's set is found, on both sides.
        for s in &Structure::ALL[1..10] {
            if per[*s as usize].1 <= 0.0 {
                failures.push(format!("{}: no {} in {table:?}", v.level, s.name()));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn synthetic_ct_surfaces_are_labelled_as_the_phantom_mesh_says() {
    let f = fixture();
    check_split_against_the_phantom(&f.phantom, &f.seg);
}

#[test]
fn every_level_of_the_default_l1_l5_segment_is_labelled_as_the_phantom_mesh_says() {
    // The built-in segment as `PhantomOptions::default()` builds it (discs, lordosis, 0.6 mm mesh), its
    // synthetic CT at 0.8 mm: neighbours close together, each level's surface cut from one label map.
    let phantom = crate::common::default_phantom();
    let (_, seg) = synthetic_ct_08(phantom);
    check_split_against_the_phantom(phantom, &seg);
}

#[test]
fn the_split_follows_the_landmark_frame_not_the_world_axes() {
    // The phantom's own landmarks, and the whole vertebra turned 90° about the anterior axis and moved:
    // the labels must not change.
    let f = fixture();
    let v = &f.phantom.vertebrae[0];
    let mesh = label_surface(&f.seg, 31, &SurfaceOptions::default()).unwrap();
    let base = split_structures(&mesh, &v.landmarks).unwrap();
    let rot = glam::DQuat::from_axis_angle(DVec3::Y, std::f64::consts::FRAC_PI_2);
    let t = spinedrr::geometry::RigidTransform::new(
        glam::DMat3::from_quat(rot),
        DVec3::new(40.0, -7.0, 300.0),
    );
    let mut moved = mesh.clone();
    moved.transform(&t);
    let moved_lm = Landmarks {
        level: v.landmarks.level.clone(),
        points: v
            .landmarks
            .points
            .iter()
            .map(|(k, p)| (k.clone(), t.apply(*p)))
            .collect(),
    };
    let turned = split_structures(&moved, &moved_lm).unwrap();
    let differ: f64 = (0..base.len())
        .filter(|&i| base[i] != turned[i])
        .map(|i| area(&mesh, i))
        .sum();
    assert!(differ / mesh.area() < 0.005, "{differ} mm² relabelled");
}

#[test]
fn landmarks_that_give_no_frame_are_refused_by_name() {
    let f = fixture();
    let mesh = label_surface(&f.seg, 31, &SurfaceOptions::default()).unwrap();
    let mut lm = f.phantom.vertebrae[0].landmarks.clone();
    lm.points.remove("right_pedicle");
    let e = split_structures(&mesh, &lm).unwrap_err().to_string();
    assert!(e.contains("right_pedicle"), "{e}");
    let mut swapped = f.phantom.vertebrae[0].landmarks.clone();
    let (l, r) = (
        swapped.get("left_pedicle").unwrap(),
        swapped.get("right_pedicle").unwrap(),
    );
    swapped.points.insert("left_pedicle".into(), r);
    swapped.points.insert("right_pedicle".into(), l);
    let e = split_structures(&mesh, &swapped).unwrap_err().to_string();
    assert!(e.contains("spinous_tip") && e.contains("swapped"), "{e}");
}

#[test]
fn mesh_writes_structures_and_slicer_landmarks_that_read_back() {
    let f = fixture();
    let seg = f.dir.join("seg.nii");
    let d = tempfile::tempdir().unwrap();
    let ply = d.path().join("L1.ply");
    let (ok, err) = Spinedrr::new()
        .args(["mesh", "--seg"])
        .arg(&seg)
        .args(["--label", "L1", "--structures", "--landmarks", "auto"])
        .args(["--landmarks-format", "slicer", "--out"])
        .arg(&ply)
        .outcome();
    assert!(ok, "{err}");
    assert!(err.contains("structures: body"), "{err}");
    let m = read_mesh(&ply).unwrap();
    assert_eq!(m.labels.len(), m.triangles.len());
    let mrk = d.path().join("L1_landmarks.mrk.json");
    let slicer = read_landmarks(&mrk).unwrap();
    // The same landmarks in our JSON, from a second run writing to a chosen name.
    let json = d.path().join("mine.json");
    let (ok, err) = Spinedrr::new()
        .args(["mesh", "--seg"])
        .arg(&seg)
        .args(["--label", "L1", "--landmarks", "auto", "--landmarks-out"])
        .arg(&json)
        .arg("--out")
        .arg(d.path().join("plain.stl"))
        .outcome();
    assert!(ok, "{err}");
    assert_eq!(read_landmarks(&json).unwrap(), slicer);
    assert!(std::fs::read_to_string(&mrk).unwrap().contains("\"LPS\""));
    // Flags that cannot work are refused before any work.
    let (ok, err) = Spinedrr::new()
        .args(["mesh", "--seg"])
        .arg(&seg)
        .args(["--label", "L1", "--landmarks-format", "slicer", "--out"])
        .arg(d.path().join("x.ply"))
        .outcome();
    assert!(!ok && err.contains("--landmarks auto"), "{err}");
    let (ok, err) = Spinedrr::new()
        .args(["mesh", "--seg"])
        .arg(&seg)
        .args([
            "--label",
            "L1",
            "--landmarks",
            "auto",
            "--landmarks-format",
            "verse",
        ])
        .arg("--out")
        .arg(d.path().join("x.ply"))
        .outcome();
    assert!(!ok && err.contains("read, not written"), "{err}");
}

/// A VerSe centroid file for `seg.nii` (axis codes R, A, S: the synthetic CT's own) with L1's centre.
fn verse_file(dir: &Path, f: &Fixture, label: u16) -> PathBuf {
    let c = f.phantom.vertebrae[0].landmarks.get("center").unwrap();
    let idx = f.seg.world_to_index().transform_point3(c);
    let p = dir.join("ctd.json");
    let doc = format!(
        r#"[{{"direction": ["R", "A", "S"]}}, {{"label": {label}, "X": {}, "Y": {}, "Z": {}}}]"#,
        idx.x, idx.y, idx.z
    );
    std::fs::write(&p, doc).unwrap();
    p
}

fn study(dir: &Path, f: &Fixture, landmarks: &Path) -> std::process::Output {
    let cfg = format!(
        "experiments = [\"projection\", \"landmarks\"]\nheatmaps_df_px = []\n\
[anatomy]\nlevels = [\"L1\"]\nsegment = false\nvoxel_mm = 1.0\nmarker_radius_mm = 4.0\n\
[[anatomy.ct]]\nname = \"syn\"\nct = {ct:?}\nseg = {seg:?}\nlabels = \"totalseg\"\n\
levels = [\"L1\"]\nsegment = false\nlandmarks = {lm:?}\n\
[geometry]\nbinning = 4\n[perturbations]\ndf_px = [100.0, 500.0]\npiercing_px = [0.0]\n",
        ct = f.dir.join("ct.nii").to_str().unwrap(),
        seg = f.dir.join("seg.nii").to_str().unwrap(),
        lm = landmarks.to_str().unwrap(),
    );
    let cfg_path = dir.join("study.toml");
    std::fs::write(&cfg_path, cfg).unwrap();
    Spinedrr::new()
        .args(["study", "--config"])
        .arg(&cfg_path)
        .arg("--out")
        .arg(dir.join("out"))
        .output()
}

#[test]
fn a_ct_target_with_verse_landmarks_gets_per_structure_rows() {
    let f = fixture();
    let d = tempfile::tempdir().unwrap();
    let ctd = verse_file(d.path(), f, 20); // VerSe L1 = 20, the map's L1 = 31
    let o = study(d.path(), f, &ctd);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let t = spinedrr::study::StudyTables::load(&d.path().join("out")).expect("tables");
    let rows: Vec<_> = t
        .structures
        .iter()
        .filter(|r| r.target == "syn-L1")
        .collect();
    for s in [
        "body",
        "pedicle_left",
        "pedicle_right",
        "lamina",
        "spinous",
        "transverse",
    ] {
        for view in ["ap", "lat"] {
            assert!(
                rows.iter().any(|r| r.structure == s && r.view == view),
                "no {s} row in {view} for the CT target"
            );
        }
    }
    // Dice falls as Δf grows, as for the phantom.
    let dice = |df: f64| {
        rows.iter()
            .find(|r| r.structure == "body" && r.view == "lat" && r.df_px == df)
            .map(|r| r.dice)
            .unwrap()
    };
    assert!(
        dice(100.0) > dice(500.0) && dice(100.0) < 1.0,
        "{} {}",
        dice(100.0),
        dice(500.0)
    );
    // The VerSe centroid is the one landmark of the target, and it sits where the views aim.
    let lm: Vec<_> = t
        .landmarks
        .iter()
        .filter(|r| r.target == "syn-L1")
        .collect();
    assert!(!lm.is_empty() && lm.iter().all(|r| r.landmark == "center"));

    // A VerSe file naming a level the label map lacks (L3 = 22) stops the study before any output.
    let d2 = tempfile::tempdir().unwrap();
    let bad = verse_file(d2.path(), f, 22);
    let o = study(d2.path(), f, &bad);
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{e}");
    assert!(
        e.contains("ctd.json") && e.contains("L3") && e.contains("anatomy.ct.landmarks"),
        "{e}"
    );
    assert!(!d2.path().join("out").exists());
}
