//! The readers under fuzz, one function per target: each feeds raw bytes to the same public entry point
//! the CLI uses and checks only what must hold for *any* input (no panic, no runaway; a parsed value that
//! prints back must parse to itself). `fuzz_targets/*.rs` call these under libFuzzer (nightly), and
//! `tests/it/fuzz_regressions.rs` includes this file to replay the kept corpora under stable `cargo test`.

use std::io::Write;
use std::path::Path;

use spinedrr::anatomy::MeshFormat;
use spinedrr::anatomy::ct::{LabelMap, read_ct_from, read_labels_from};
use spinedrr::anatomy::labels::LabelConvention;
use spinedrr::anatomy::landmarks::landmarks_from_json;
use spinedrr::anatomy::markups::{
    ImageGrid, LandmarkContext, VerseUnits, parse_landmarks_with, parse_slicer, parse_verse,
};
use spinedrr::anatomy::parse_mesh;
use spinedrr::calibration::CalibrationPhantom;
use spinedrr::geometry::{CArm, Intrinsics, Perturbation};
use spinedrr::io::{Sidecar, decode_drr_tiff};
use spinedrr::registration::LoadedProblem;
use spinedrr::registration::intensity::LoadedIntensityProblem;
use spinedrr::study::StudyConfig;
use spinedrr::study::units::UnitFile;

/// A fuzz target: it takes any bytes and must return (not panic, not hang).
pub type Target = fn(&[u8]);

/// Every target: its name (the folder under `fuzz/corpus/`) and its function.
pub const TARGETS: &[(&str, Target)] = &[
    ("stl_binary", stl_binary),
    ("stl_ascii", stl_ascii),
    ("obj", obj),
    ("ply_ascii", ply_ascii),
    ("ply_binary", ply_binary),
    ("nifti", nifti),
    ("nifti_gz", nifti_gz),
    ("geometry_toml", geometry_toml),
    ("study_toml", study_toml),
    ("problem_json", problem_json),
    ("landmarks_json", landmarks_json),
    ("perturb", perturb),
    ("markups", markups),
    ("calib_phantom", calib_phantom),
    ("intensity_problem", intensity_problem),
    ("cohort_dataset", cohort_dataset),
    ("drr_tiff", drr_tiff),
    ("sidecar_json", sidecar_json),
    ("unit_file", unit_file),
];

fn origin() -> &'static Path {
    Path::new("fuzz-input")
}

/// Binary STL: the input's length is cut to `84 + 50·n` and the count word set to `n`, so every input
/// takes the binary decoder (a raw input almost never has a matching count).
pub fn stl_binary(data: &[u8]) {
    let mut bytes = data.to_vec();
    if bytes.len() >= 84 {
        let n = (bytes.len() - 84) / 50;
        bytes.truncate(84 + 50 * n);
        bytes[80..84].copy_from_slice(&(n as u32).to_le_bytes());
    }
    let _ = parse_mesh(&bytes, MeshFormat::StlBinary, origin());
}

/// ASCII STL: the input follows `solid `, so the ASCII decoder runs; also the raw input (either flavour).
pub fn stl_ascii(data: &[u8]) {
    let mut bytes = b"solid ".to_vec();
    bytes.extend_from_slice(data);
    let _ = parse_mesh(&bytes, MeshFormat::StlAscii, origin());
    let _ = parse_mesh(data, MeshFormat::StlAscii, origin());
}

pub fn obj(data: &[u8]) {
    let _ = parse_mesh(data, MeshFormat::Obj, origin());
}

/// PLY with the magic and format line given, the header's elements and the body from the input.
fn ply(prefix: &[u8], data: &[u8]) {
    let mut bytes = prefix.to_vec();
    bytes.extend_from_slice(data);
    let _ = parse_mesh(&bytes, MeshFormat::PlyBinary, origin());
    let _ = parse_mesh(data, MeshFormat::PlyBinary, origin());
}

pub fn ply_ascii(data: &[u8]) {
    ply(b"ply\nformat ascii 1.0\n", data);
}

pub fn ply_binary(data: &[u8]) {
    ply(b"ply\nformat binary_little_endian 1.0\n", data);
}

/// NIfTI as stored (plain, or gzip when the input starts with its magic), as CT and as labels.
pub fn nifti(data: &[u8]) {
    let _ = read_ct_from(data, origin());
    let _ = read_labels_from(data, origin());
}

/// NIfTI behind gzip: the input compressed (the decoder sees well-formed gzip of arbitrary NIfTI bytes),
/// and the input after a bare gzip magic (corrupt streams).
pub fn nifti_gz(data: &[u8]) {
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    if gz.write_all(data).is_ok()
        && let Ok(bytes) = gz.finish()
    {
        let _ = read_ct_from(&bytes[..], origin());
        let _ = read_labels_from(&bytes[..], origin());
    }
    let mut raw = vec![0x1f, 0x8b];
    raw.extend_from_slice(data);
    let _ = read_ct_from(&raw[..], origin());
}

fn text(data: &[u8]) -> Option<&str> {
    std::str::from_utf8(data).ok()
}

pub fn geometry_toml(data: &[u8]) {
    if let Some(t) = text(data) {
        let _ = CArm::from_toml_str(t, "fuzz-input");
    }
}

pub fn study_toml(data: &[u8]) {
    if let Some(t) = text(data) {
        let _ = StudyConfig::from_toml_str(t, "fuzz-input");
    }
}

pub fn problem_json(data: &[u8]) {
    if let Some(t) = text(data) {
        let _ = LoadedProblem::from_json_str(t, "fuzz-input");
    }
}

/// Both landmark readers: the per-level file (`study`, `phantom`) and `compare --landmarks`.
pub fn landmarks_json(data: &[u8]) {
    if let Some(t) = text(data) {
        let _ = landmarks_from_json(t, origin());
        let _ = spinedrr::analysis::parse_landmarks(t, "fuzz-input");
    }
}

/// The `--perturb` spec: a spec that parses prints back to one that parses to the same value, and
/// applying it to the default detector never panics.
pub fn perturb(data: &[u8]) {
    let Some(t) = text(data) else { return };
    let Ok(p) = Perturbation::parse(t) else {
        return;
    };
    let back = Perturbation::parse(&p.to_string());
    assert_eq!(back.ok(), Some(p), "spec {t:?} printed as {p}");
    if let Ok(k) = Intrinsics::from_detector(1350.0, [0.3, 0.3], 1024, 1024) {
        let _ = p.apply(&k);
    }
}

/// A 32 × 32 × 32 label map (1 mm voxels, x and y flipped as a LPS-stored CT) holding the VerSe labels of
/// L1–L5 (20–24) in five slabs along z: the image a VerSe centroid file is read beside.
fn verse_seg() -> &'static LabelMap {
    static SEG: std::sync::OnceLock<LabelMap> = std::sync::OnceLock::new();
    SEG.get_or_init(|| {
        let n = 32;
        let values = (0..n * n * n)
            .map(|i| 20 + ((i / (n * n)) * 5 / n) as u16)
            .collect();
        let affine = glam::DMat4::from_cols_array(&[
            -1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 15.5, 15.5, -15.5, 1.0,
        ]);
        LabelMap::new([n; 3], values, affine)
            .unwrap_or_else(|e| panic!("the fuzz label map is valid: {e}"))
    })
}

/// The landmark reader that picks the format from the content (`parse_landmarks_with`, as `study`,
/// `phantom`, `compare` and `auto` call it): as a `.json` and as a `.mrk.json`, without an image and beside
/// a label map in both VerSe units; then each format's own parser (`parse_slicer`, `parse_verse`), which
/// the CLI reaches past the detector's checks.
pub fn markups(data: &[u8]) {
    let Some(t) = text(data) else { return };
    let seg = verse_seg();
    for units in [VerseUnits::Voxels, VerseUnits::Millimetres] {
        let ctx = LandmarkContext {
            seg: Some((seg, LabelConvention::Verse)),
            verse_units: units,
        };
        let _ = parse_landmarks_with(t, Path::new("fuzz-input.json"), &ctx);
        let _ = parse_verse(t, origin(), &ImageGrid::of(seg), units);
    }
    let none = LandmarkContext::default();
    let _ = parse_landmarks_with(t, Path::new("fuzz-input.mrk.json"), &none);
    let _ = parse_slicer(t, origin());
}

/// The calibration phantom JSON (`calibrate --phantom FILE`, a study's `phantoms = ["FILE"]`).
pub fn calib_phantom(data: &[u8]) {
    if let Some(t) = text(data) {
        let _ = CalibrationPhantom::from_json_str(t, "fuzz-input");
    }
}

/// The intensity registration problem (`register --intensity --problem P.json`). Its reader takes a
/// path and opens the files the problem names, so the input is written to `P.json` in an empty folder
/// of its own, and inputs that could name a file outside it (any `/` or `\\`, hence no escaped one
/// either) are skipped: every fixed image, mesh or CT it names is missing, and the reader must say so.
/// Problems with no view are skipped too: they reach the anatomy, whose phantom takes a second to
/// build (the CLI test of `register --intensity` covers that path).
pub fn intensity_problem(data: &[u8]) {
    let Some(t) = text(data) else { return };
    if t.contains('/') || t.contains('\\') {
        return;
    }
    if let Ok(v) = serde_json::from_str::<serde_json::Value>(t)
        && v.get("views")
            .and_then(|w| w.as_array())
            .is_some_and(|w| w.is_empty())
    {
        return;
    }
    static DIR: std::sync::OnceLock<std::path::PathBuf> = std::sync::OnceLock::new();
    let dir = DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("spinedrr-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display()));
        d
    });
    let path = dir.join("P.json");
    if std::fs::write(&path, data).is_ok() {
        let _ = LoadedIntensityProblem::read(&path, spinedrr::render::Backend::Raster);
    }
}

/// A folder holding one case of each dataset layout (empty files: `discover` lists, it does not read).
fn dataset_folder() -> &'static Path {
    static DIR: std::sync::OnceLock<std::path::PathBuf> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("spinedrr-fuzz-ds-{}", std::process::id()));
        for f in [
            "rawdata/sub-01/sub-01_ct.nii.gz",
            "derivatives/sub-01/sub-01_seg-vert_msk.nii.gz",
            "sub-02/sub-02_ct.nii.gz",
            "sub-02/sub-02_seg-vert_msk.nii.gz",
            "s0001/ct.nii.gz",
            "s0001/segmentations.nii.gz",
            "s0002/ct.nii.gz",
            "s0002/segmentations/vertebrae_L1.nii.gz",
            "c1/image.nii.gz",
            "c1/labels.nii.gz",
            "case-7_ct.nii.gz",
            "case-7_seg.nii.gz",
        ] {
            let p = d.join(f);
            let made = p
                .parent()
                .map_or(Ok(()), std::fs::create_dir_all)
                .and_then(|()| std::fs::write(&p, b""));
            made.unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        }
        d
    })
}

/// A study's cohort section (`[[anatomy.dataset]]`): the study parsed and checked, then each dataset's
/// cases discovered in a folder holding one case of every layout (the input's own `folder` is replaced
/// by it; a pattern with `..` is skipped, it would list folders outside). A checked dataset never takes
/// its CT for its label map.
pub fn cohort_dataset(data: &[u8]) {
    let Some(t) = text(data) else { return };
    let Ok(cfg) = StudyConfig::from_toml_str(t, "fuzz-input") else {
        return;
    };
    for d in &cfg.anatomy.dataset {
        assert!(
            d.ct.is_none() || d.ct != d.seg,
            "dataset {:?} accepted with one pattern for CT and labels",
            d.name
        );
        if [&d.ct, &d.seg]
            .iter()
            .any(|p| p.as_ref().is_some_and(|p| p.contains("..")))
        {
            continue;
        }
        let mut d = d.clone();
        d.folder = dataset_folder().to_path_buf();
        let _ = d.discover();
    }
}

/// A TIFF as `compare` reads a DRR (one page of float samples; integer and multi-page files refused):
/// any bytes; the decoder's limits bound what a header may make it allocate.
pub fn drr_tiff(data: &[u8]) {
    if let Ok(img) = decode_drr_tiff(std::io::Cursor::new(data), origin()) {
        assert_eq!(img.data.len(), img.width as usize * img.height as usize);
    }
}

/// A DRR's JSON sidecar as `compare` reads it: parsed, then its K and world_to_camera checked into the
/// view the image was rendered with.
pub fn sidecar_json(data: &[u8]) {
    if let Some(t) = text(data)
        && let Ok(sc) = Sidecar::from_json_str(t, origin())
    {
        let _ = sc.rendered_view(origin());
    }
}

/// A study's unit file (`units/<id>.json`, what a resumed run reads before reusing a unit): any JSON. One
/// that parses must print back to text that parses and prints the same (its numbers are strings so that
/// NaN and infinities survive; the assembled tables depend on that round trip).
pub fn unit_file(data: &[u8]) {
    let Some(t) = text(data) else { return };
    let Ok(f) = serde_json::from_str::<UnitFile>(t) else {
        return;
    };
    let once = serde_json::to_string(&f).expect("a parsed unit file serialises");
    let back: UnitFile = serde_json::from_str(&once).expect("a written unit file parses");
    assert_eq!(serde_json::to_string(&back).unwrap(), once);
}
