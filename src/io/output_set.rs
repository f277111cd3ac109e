//! Output sets: every file of a product is checked before the first is written, so a run that cannot
//! write all of them writes none; then the files are written with the set's marker (the main sidecar or
//! `metrics.json`) last, after the previous marker was removed, so a reader can tell a complete set (marker
//! present, listing its companions) from one a killed run left behind (no marker).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use crate::{Error, Result};

/// The folder `path` is written into (`.` for a bare file name).
pub(super) fn folder_of(path: &Path) -> &Path {
    path.parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// Checks that every path of an output set can be written: its folder exists and accepts new files, the
/// path is not a directory, and an existing JSON file there is one spinedrr wrote ([`check_ours`]: a
/// sidecar never replaces a landmarks file or any other file of the user's). Nothing is written when any
/// check fails (a probe file is created and removed in each folder).
pub fn check_output_paths(paths: &[PathBuf]) -> Result<()> {
    let mut folders = BTreeSet::new();
    for p in paths {
        if p.is_dir() {
            return Err(Error::invalid(
                format!("output {}", p.display()),
                "is a directory, not a file; nothing was written",
            ));
        }
        check_ours(p)?;
        let dir = folder_of(p);
        if !dir.is_dir() {
            return Err(Error::invalid(
                format!("output {}", p.display()),
                format!(
                    "its folder {} does not exist; nothing was written",
                    dir.display()
                ),
            ));
        }
        folders.insert(dir.to_path_buf());
    }
    for dir in folders {
        let probe = dir.join(format!(".spinedrr-probe-{}", std::process::id()));
        std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&probe)
            .map_err(|e| {
                Error::io(
                    &dir,
                    std::io::Error::new(e.kind(), format!("cannot write into this folder: {e}")),
                )
            })?;
        std::fs::remove_file(&probe).map_err(|e| Error::io(&probe, e))?;
    }
    Ok(())
}

/// Refuses to replace an existing `.json` file at `path` that spinedrr did not write (a JSON object whose
/// `tool` is `spinedrr`: every sidecar and `metrics.json`), naming what it appears to be.
pub fn check_ours(path: &Path) -> Result<()> {
    if path.extension().is_none_or(|e| e != "json") || !path.is_file() {
        return Ok(());
    }
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let value: Option<serde_json::Value> = serde_json::from_str(&text).ok();
    let tool = value
        .as_ref()
        .and_then(|v| v.get("tool"))
        .and_then(|t| t.as_str());
    if tool == Some("spinedrr") {
        return Ok(());
    }
    let first = match &value {
        Some(serde_json::Value::Array(a)) => a.first(),
        v => v.as_ref(),
    };
    let what = match &value {
        _ if first.is_some_and(|f| f.get("landmarks").is_some()) => "a landmarks file",
        Some(v) if v.get("markups").is_some() => "a 3D Slicer markups file",
        Some(serde_json::Value::Object(_)) => "a JSON file spinedrr did not write",
        Some(_) => "JSON that is not an object",
        None => "not JSON",
    };
    Err(Error::invalid(
        format!("output {}", path.display()),
        format!(
            "would replace an existing file that is {what}, not a spinedrr sidecar; nothing was written \
             (choose another output name, or move that file)"
        ),
    ))
}

/// Whether `a` and `b` name the same file: the same device and inode when both exist, else the same
/// canonical location (the folder resolved, the file name kept).
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
        return x.dev() == y.dev() && x.ino() == y.ino();
    }
    let place = |p: &Path| -> Option<PathBuf> {
        let dir = std::fs::canonicalize(folder_of(p)).ok()?;
        Some(dir.join(p.file_name()?))
    };
    matches!((place(a), place(b)), (Some(x), Some(y)) if x == y)
}

/// Refuses an output that would replace an input of the same run: every `(what, path)` of `outputs`
/// against every one of `inputs` ([`same_file`]); the error names both and the file. Nothing is written.
pub fn check_spares_inputs(
    outputs: &[(String, PathBuf)],
    inputs: &[(String, PathBuf)],
) -> Result<()> {
    for (out_what, out) in outputs {
        for (in_what, input) in inputs {
            if same_file(out, input) {
                return Err(Error::invalid(
                    out_what.clone(),
                    format!(
                        "{} is also {in_what}: the output would replace an input of this run; nothing \
                         was written (choose another output)",
                        out.display()
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Removes the marker `path` of an earlier output set before a new set is written (a missing file is
/// fine).
pub(super) fn remove_marker(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::io(path, e)),
    }
}

/// The file names of `paths` (for a marker's `companions`).
pub(super) fn file_names(paths: &[PathBuf]) -> Vec<String> {
    paths
        .iter()
        .filter_map(|p| p.file_name())
        .map(|n| n.to_string_lossy().into_owned())
        .collect()
}
