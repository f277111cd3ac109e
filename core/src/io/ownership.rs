//! Which existing files an output may replace: only files spinedrr wrote itself. Every command checks
//! each file it is about to write over before it writes anything, and refuses by name a file it cannot
//! tell for its own (the user's photo `OUT.png` beside a DRR, hand-placed `L1_landmarks.json` beside a
//! mesh, a real CT named as the phantom's `--ct`, someone's `calibrations.csv`).
//!
//! spinedrr's own files are told by their content, each format by what spinedrr writes into it, and a
//! file is replaced only by one of its kind (a render's sidecar never replaces spinedrr's landmarks):
//!
//! | file | spinedrr's own when |
//! |---|---|
//! | `.json` | an object whose `tool` is `spinedrr` (sidecars, `metrics.json`, records) or an earlier version's `metrics.json`; for landmarks ([`check_ours_landmarks`]) a file whose every level says `"tool": "spinedrr"`, or 3D Slicer markups whose every control point's description is spinedrr's |
//! | `.stl`, `.obj`, `.ply` | the header names spinedrr (binary STL's 80-byte header, OBJ's first comment, a PLY `comment`) |
//! | `.nii`, `.nii.gz` | the NIfTI header's `descrip` names spinedrr |
//! | `.png`, `.tif`, `.tiff` | the sidecar beside it (`NAME.json`) is spinedrr's |
//!
//! A file of no such format (a CSV table) is spinedrr's when its output set's record lists it among its
//! `companions` ([`super::check_output_paths`]).

use std::io::Read;
use std::path::Path;

use serde_json::Value;

use super::sidecar_path;
use crate::{Error, Result};

/// What spinedrr writes into the `tool` of its JSON records and landmark levels, and at the start of
/// its mesh headers and NIfTI `descrip`.
pub const TOOL: &str = "spinedrr";

/// The description spinedrr gives each control point of a 3D Slicer markups file it writes.
pub const SLICER_DESCRIPTION: &str = "written by spinedrr";

/// Refuses to replace an existing file at `path` that spinedrr did not write (see the module
/// documentation for how its own are told), naming what it appears to be. A path where no file is passes.
pub fn check_ours(path: &Path) -> Result<()> {
    match foreign(path) {
        None => Ok(()),
        Some(what) => Err(refusal(path, what)),
    }
}

/// The refusal of `path`, which holds `what`.
pub(super) fn refusal(path: &Path, what: &str) -> Error {
    Error::invalid(
        format!("output {}", path.display()),
        format!(
            "would replace an existing file that spinedrr did not write ({what}); nothing was written \
             (choose another output name, or move that file)"
        ),
    )
}

/// `None` when nothing is at `path` or spinedrr wrote the file there, else what the file appears to be.
pub(super) fn foreign(path: &Path) -> Option<&'static str> {
    if !path.is_file() {
        return None;
    }
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let ext = name.rsplit('.').next().unwrap_or_default();
    match ext {
        "json" => foreign_json(path),
        "stl" | "obj" | "ply" => {
            (!mesh_is_ours(path, ext)).then_some("a mesh whose header does not name spinedrr")
        }
        "nii" => (!nifti_is_ours(path, false))
            .then_some("a NIfTI volume whose descrip does not name spinedrr"),
        "gz" if name.ends_with(".nii.gz") => (!nifti_is_ours(path, true))
            .then_some("a NIfTI volume whose descrip does not name spinedrr"),
        "png" | "tif" | "tiff" => foreign_json(&sidecar_path(path))
            .map(|_| "an image without a spinedrr sidecar beside it"),
        _ => Some("no record of spinedrr's beside it lists it"),
    }
}

/// Refuses to replace the spinedrr record at `path` with a record of `kind` when it is a record of
/// another kind (a render's sidecar over a comparison's `metrics.json`, a registration's `R.json` or a
/// calibration's `phantom.json`). A record that states no kind (an earlier version's) passes.
pub fn check_kind(path: &Path, kind: &str) -> Result<()> {
    let found = read_json(path)
        .filter(|v| v.get("tool").and_then(Value::as_str) == Some(TOOL))
        .and_then(|v| v.get("kind").and_then(Value::as_str).map(str::to_string));
    match found {
        Some(found) if found != kind => Err(Error::invalid(
            format!("output {}", path.display()),
            format!(
                "would replace spinedrr's {found} record there with a {kind} record (another product \
                 of the same name); nothing was written (choose another output name)"
            ),
        )),
        _ => Ok(()),
    }
}

/// The `companions` of the spinedrr record at `path` (an output set's marker), empty when there is no
/// such record.
pub(super) fn companions_of(path: &Path) -> Vec<String> {
    let json = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    if !json || !path.is_file() || foreign_json(path).is_some() {
        return Vec::new();
    }
    read_json(path)
        .as_ref()
        .and_then(|v| v.get("companions"))
        .and_then(Value::as_array)
        .map(|a| {
            a.iter()
                .filter_map(Value::as_str)
                .map(str::to_string)
                .collect()
        })
        .unwrap_or_default()
}

fn read_json(path: &Path) -> Option<Value> {
    serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()
}

/// What a JSON file is, as far as replacing it goes.
enum Json {
    /// A record of spinedrr's: an object whose `tool` is `spinedrr` (a sidecar, `metrics.json`, a
    /// registration or calibration record), or an earlier version's `metrics.json`.
    OurRecord,
    /// Landmarks spinedrr wrote: every level says `"tool": "spinedrr"`, or 3D Slicer markups whose every
    /// control point carries [`SLICER_DESCRIPTION`].
    OurLandmarks,
    /// Anything else (a missing file too: an image's sidecar must be there), with what it appears to be.
    Foreign(&'static str),
}

fn classify_json(path: &Path) -> Json {
    let value = read_json(path);
    let tool_of = |v: &Value| v.get("tool").and_then(Value::as_str) == Some(TOOL);
    // `metrics.json` of a spinedrr before it named its tool: the comparison record's own keys.
    let old_metrics = |v: &Value| v.get("image").is_some() && v.get("silhouettes").is_some();
    // A level of our landmarks format (`level` and `landmarks`; `metrics.json` has `landmarks` alone).
    let is_landmarks = |v: &Value| v.get("landmarks").is_some() && v.get("level").is_some();
    let slicer_ours = |v: &Value| {
        let points: Vec<&Value> = v
            .get("markups")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
            .flat_map(|m| {
                m.get("controlPoints")
                    .and_then(Value::as_array)
                    .into_iter()
                    .flatten()
            })
            .collect();
        !points.is_empty()
            && points
                .iter()
                .all(|p| p.get("description").and_then(Value::as_str) == Some(SLICER_DESCRIPTION))
    };
    let levels: &[Value] = match &value {
        Some(Value::Array(a)) => a,
        Some(v) if is_landmarks(v) => std::slice::from_ref(v),
        _ => &[],
    };
    match &value {
        _ if !levels.is_empty() && levels.iter().all(|l| is_landmarks(l) && tool_of(l)) => {
            Json::OurLandmarks
        }
        Some(v) if v.get("markups").is_some() && slicer_ours(v) => Json::OurLandmarks,
        _ if levels.first().is_some_and(is_landmarks) => Json::Foreign("a landmarks file"),
        Some(v) if v.get("markups").is_some() => Json::Foreign("a 3D Slicer markups file"),
        Some(v) if tool_of(v) || old_metrics(v) => Json::OurRecord,
        Some(Value::Object(_)) => Json::Foreign("a JSON object without `\"tool\": \"spinedrr\"`"),
        Some(_) => Json::Foreign("JSON that is not an object"),
        None if path.is_file() => Json::Foreign("not JSON"),
        None => Json::Foreign("missing"),
    }
}

/// [`foreign`] of a JSON file that a record (a sidecar, `metrics.json`) would replace.
fn foreign_json(path: &Path) -> Option<&'static str> {
    match classify_json(path) {
        Json::OurRecord => None,
        Json::OurLandmarks => Some("a landmarks file of spinedrr's, not a record"),
        Json::Foreign(what) => Some(what),
    }
}

/// Refuses to replace an existing file at `path` with landmarks unless it holds landmarks spinedrr
/// wrote (never a hand-placed file, never a record of spinedrr's such as a sidecar).
pub fn check_ours_landmarks(path: &Path) -> Result<()> {
    if !path.is_file() {
        return Ok(());
    }
    match classify_json(path) {
        Json::OurLandmarks => Ok(()),
        Json::OurRecord => Err(refusal(
            path,
            "a record of spinedrr's, not a landmarks file",
        )),
        Json::Foreign(what) => Err(refusal(path, what)),
    }
}

/// The first `n` bytes of `path` (fewer when it is shorter).
fn head(path: &Path, n: u64) -> Vec<u8> {
    let mut bytes = Vec::new();
    if let Ok(f) = std::fs::File::open(path) {
        let _ = f.take(n).read_to_end(&mut bytes);
    }
    bytes
}

/// Whether the mesh file names spinedrr in its header (what the writers of [`crate::anatomy`] put
/// there: binary STL's header text, OBJ's first comment, a PLY comment line).
fn mesh_is_ours(path: &Path, ext: &str) -> bool {
    let bytes = head(path, 4096);
    let tag = format!("{TOOL} ");
    match ext {
        "stl" => bytes.starts_with(tag.as_bytes()),
        "obj" => bytes.starts_with(format!("# {tag}").as_bytes()),
        _ => {
            let text = String::from_utf8_lossy(&bytes);
            let header = text.split("end_header").next().unwrap_or_default();
            bytes.starts_with(b"ply")
                && header
                    .lines()
                    .any(|l| l.starts_with(&format!("comment {tag}")))
        }
    }
}

/// Whether the NIfTI-1 header's `descrip` (bytes 148–227) starts with spinedrr's name.
fn nifti_is_ours(path: &Path, gz: bool) -> bool {
    let mut header = Vec::new();
    let Ok(f) = std::fs::File::open(path) else {
        return false;
    };
    let read = if gz {
        flate2::read::MultiGzDecoder::new(f)
            .take(348)
            .read_to_end(&mut header)
    } else {
        f.take(348).read_to_end(&mut header)
    };
    read.is_ok() && header.len() == 348 && header[148..228].starts_with(TOOL.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }

    #[test]
    fn only_files_that_name_spinedrr_are_ours() {
        let d = tempfile::tempdir().unwrap();
        let dir = d.path();
        assert_eq!(foreign(&dir.join("absent.json")), None);
        assert!(check_ours_landmarks(&dir.join("absent.json")).is_ok());
        // (name, bytes, a record may replace it, landmarks may replace it)
        let cases: [(&str, &[u8], bool, bool); 14] = [
            // metrics.json: a record with a `landmarks` table, not a landmarks file.
            (
                "metrics.json",
                br#"{"tool": "spinedrr", "landmarks": {"c": {}}}"#,
                true,
                false,
            ),
            (
                "a.json",
                br#"{"tool": "spinedrr", "kind": "drr"}"#,
                true,
                false,
            ),
            ("b.json", br#"{"tool": "other"}"#, false, false),
            (
                "lm.json",
                br#"[{"level": "L1", "tool": "spinedrr", "landmarks": {}}]"#,
                false,
                true,
            ),
            (
                "one.json",
                br#"{"level": "L1", "tool": "spinedrr", "landmarks": {}}"#,
                false,
                true,
            ),
            (
                "hand.json",
                br#"[{"level": "L1", "landmarks": {}}]"#,
                false,
                false,
            ),
            (
                "s.mrk.json",
                br#"{"markups": [{"controlPoints": [{"description": "written by spinedrr"}]}]}"#,
                false,
                true,
            ),
            (
                "t.mrk.json",
                br#"{"markups": [{"controlPoints": [{"label": "c"}]}]}"#,
                false,
                false,
            ),
            (
                "m.obj",
                b"# spinedrr 0.1.0, millimetres\nv 0 0 0\n",
                true,
                false,
            ),
            ("n.obj", b"# Blender\nv 0 0 0\n", false, false),
            (
                "p.ply",
                b"ply\nformat ascii 1.0\ncomment spinedrr 0.1.0\nend_header\n",
                true,
                false,
            ),
            (
                "q.ply",
                b"ply\nformat ascii 1.0\nend_header\ncomment spinedrr \n",
                false,
                false,
            ),
            ("notes.csv", b"a,b\n", false, false),
            ("x.txt", b"mine", false, false),
        ];
        for (name, bytes, record, landmarks) in cases {
            let p = write(dir, name, bytes);
            assert_eq!(foreign(&p).is_none(), record, "{name}");
            assert_eq!(check_ours(&p).is_ok(), record, "{name}");
            assert_eq!(check_ours_landmarks(&p).is_ok(), landmarks, "{name}");
        }
        // An STL's 80-byte header.
        let mut stl = [b' '; 84].to_vec();
        stl[..12].copy_from_slice(b"spinedrr 0.1");
        assert_eq!(foreign(&write(dir, "v.stl", &stl)), None);
        stl[..12].copy_from_slice(b"solid Slicer");
        assert!(foreign(&write(dir, "w.stl", &stl)).is_some());
        // An image is ours by its sidecar.
        let png = write(dir, "a.png", b"\x89PNG");
        assert_eq!(foreign(&png), None, "a.json beside it is spinedrr's");
        let photo = write(dir, "photo.png", b"\x89PNG");
        let err = check_ours(&photo).unwrap_err().to_string();
        assert!(
            err.contains("photo.png") && err.contains("without a spinedrr sidecar"),
            "{err}"
        );
        write(dir, "b.tiff", b"II*\0");
        assert!(
            foreign(&dir.join("b.tiff")).is_some(),
            "b.json is not spinedrr's"
        );
    }

    #[test]
    fn a_record_is_replaced_only_by_one_of_its_kind() {
        let d = tempfile::tempdir().unwrap();
        let metrics = write(
            d.path(),
            "metrics.json",
            br#"{"tool": "spinedrr", "kind": "metrics"}"#,
        );
        assert!(check_kind(&metrics, "metrics").is_ok());
        let err = check_kind(&metrics, "drr").unwrap_err().to_string();
        assert!(
            err.contains("metrics.json") && err.contains("metrics record"),
            "{err}"
        );
        // No kind (an earlier version's record), or not spinedrr's (judged by check_ours): passes here.
        let old = write(d.path(), "old.json", br#"{"tool": "spinedrr"}"#);
        assert!(check_kind(&old, "drr").is_ok());
        assert!(check_kind(&d.path().join("absent.json"), "drr").is_ok());
    }

    #[test]
    fn a_record_lists_its_companions() {
        let d = tempfile::tempdir().unwrap();
        let rec = write(
            d.path(),
            "phantom.json",
            br#"{"tool": "spinedrr", "companions": ["calibrations.csv"]}"#,
        );
        assert_eq!(companions_of(&rec), vec!["calibrations.csv".to_string()]);
        let theirs = write(
            d.path(),
            "other.json",
            br#"{"companions": ["calibrations.csv"]}"#,
        );
        assert!(companions_of(&theirs).is_empty());
    }
}
