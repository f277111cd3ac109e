//! The readers under fuzz, one function per target: each feeds raw bytes to the same public entry point
//! the CLI uses and checks only what must hold for *any* input (no panic, no runaway; a parsed value that
//! prints back must parse to itself). `fuzz_targets/*.rs` call these under libFuzzer (nightly), and
//! `tests/fuzz_regressions.rs` includes this file to replay the kept corpora under stable `cargo test`.

use std::io::Write;
use std::path::Path;

use spinedrr::anatomy::MeshFormat;
use spinedrr::anatomy::ct::{read_ct_from, read_labels_from};
use spinedrr::anatomy::landmarks::landmarks_from_json;
use spinedrr::anatomy::parse_mesh;
use spinedrr::geometry::{CArm, Intrinsics, Perturbation};
use spinedrr::registration::LoadedProblem;
use spinedrr::study::StudyConfig;

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
