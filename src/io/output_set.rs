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

/// Checks that every path of an output set can be written: its folder exists and accepts new files, and
/// the path is not a directory. Nothing is written when any check fails (a probe file is created and
/// removed in each folder).
pub fn check_output_paths(paths: &[PathBuf]) -> Result<()> {
    let mut folders = BTreeSet::new();
    for p in paths {
        if p.is_dir() {
            return Err(Error::invalid(
                format!("output {}", p.display()),
                "is a directory, not a file; nothing was written",
            ));
        }
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
