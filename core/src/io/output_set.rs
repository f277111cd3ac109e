//! Output sets: every file of a product is checked before the first is written, so a run that cannot
//! write all of them writes none. The files are then written aside, into a staging folder beside the set
//! ([`Staging`]); only when every one is on disk is the set committed: under the set's lock, the previous
//! marker (the main sidecar or `metrics.json`) is removed, the files are renamed into place and the new
//! marker comes last. A run that fails while writing (a full disk) leaves the previous set whole; two runs
//! writing one set commit one after the other, so the set is one run's; and a reader can tell a complete
//! set (marker present, listing its companions) from one a killed run left behind (no marker).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use super::ownership::{check_kind, companions_of, foreign, refusal};
use crate::{Error, Result};

/// The folder `path` is written into (`.` for a bare file name).
pub(super) fn folder_of(path: &Path) -> &Path {
    path.parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// Checks that every path of an output set can be written: its folder exists and accepts new files, the
/// path is not a directory, and a file already there is one spinedrr wrote: listed among the `companions`
/// of the set's record (the last path, when it is spinedrr's), or told by its own content
/// ([`super::ownership`]: a sidecar never replaces a landmarks file, a preview never the user's photo).
/// Nothing is written when any check fails (a probe file is created and removed in each folder).
pub fn check_output_paths(paths: &[PathBuf]) -> Result<()> {
    check_output_set(paths, |_| None)
}

/// [`check_output_paths`] of a set whose JSON records have kinds: an existing spinedrr record at a path
/// for which `kind_of` gives a kind must be of that kind ([`check_kind`]).
pub fn check_output_set(
    paths: &[PathBuf],
    kind_of: impl Fn(&Path) -> Option<&'static str>,
) -> Result<()> {
    for p in paths {
        if let Some(kind) = kind_of(p) {
            check_kind(p, kind)?;
        }
    }
    // Another run committing a set here removes its record first and renames it into place last (under
    // the set's lock): meanwhile its images stand without their sidecar. Wait for that commit, as the
    // commit itself would ([`SetLock::WAIT`]), before judging whose files they are.
    let start = std::time::Instant::now();
    let judge = || {
        let listed = paths
            .last()
            .map(|marker| companions_of(marker))
            .unwrap_or_default();
        paths.iter().find_map(|p| {
            let name = p.file_name().unwrap_or_default().to_string_lossy();
            (!p.is_dir() && !listed.iter().any(|c| *c == name))
                .then(|| foreign(p).map(|what| (p, what)))
                .flatten()
        })
    };
    let committing = || paths.iter().any(|p| commit_in_progress(folder_of(p)));
    let foreign_file = loop {
        let found = judge();
        if found.is_none() || start.elapsed() > SetLock::WAIT {
            break found;
        }
        if committing() {
            std::thread::sleep(std::time::Duration::from_millis(20));
            continue;
        }
        // No commit now: the one that made the file look foreign may have ended just before; judge
        // again, and refuse only what is still foreign with no commit under way.
        let again = judge();
        if again.is_none() || !committing() {
            break again;
        }
    };
    if let Some(p) = paths.iter().find(|p| p.is_dir()) {
        return Err(Error::invalid(
            format!("output {}", p.display()),
            "is a directory, not a file; nothing was written",
        ));
    }
    let mut folders = BTreeSet::new();
    if let Some((p, what)) = foreign_file {
        return Err(refusal(p, what));
    }
    for p in paths {
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

/// Creates the output folder `dir` (and its parents) named by `what` (a flag such as `--out`); a path that
/// exists as a file is refused by name, not reported as the OS's "File exists".
pub fn create_output_dir(dir: &Path, what: &str) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        return Err(Error::invalid(
            what,
            format!(
                "{} is a file, not a folder: {what} names a folder (created when missing); give another \
                 path, or move that file",
                dir.display()
            ),
        ));
    }
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))
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

/// The files of one output set, written into a hidden folder beside it (`.STEM.N.staging-PID/`, same
/// file names) and moved into place by [`Staging::commit`]. Dropped uncommitted (an error), the staging folder
/// is removed and the previous set is untouched.
pub struct Staging {
    dir: PathBuf,
    folder: PathBuf,
    stem: String,
}

impl Staging {
    /// A staging folder for the set named `stem` in `folder`.
    pub fn new(folder: &Path, stem: &str) -> Result<Staging> {
        // Unique per process and per call: threads of one run may write sets of one name.
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let dir = folder.join(format!(".{stem}.{n}.staging-{}", std::process::id()));
        if dir.exists() {
            std::fs::remove_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        }
        std::fs::create_dir(&dir).map_err(|e| Error::io(&dir, e))?;
        Ok(Staging {
            dir,
            folder: folder.to_path_buf(),
            stem: stem.to_string(),
        })
    }

    /// The staging folder (a set whose writer takes a folder writes into it).
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Where the set's file `final_path` is written before the commit.
    pub fn path(&self, final_path: &Path) -> PathBuf {
        self.dir.join(final_path.file_name().unwrap_or_default())
    }

    /// Moves the staged files of `paths` (the set, its marker last) into place: under the set's lock
    /// (`.STEM.lock`), the previous marker is removed, every staged file renamed over its target, and the
    /// marker renamed last.
    pub fn commit(self, paths: &[PathBuf]) -> Result<()> {
        let (marker, companions) = paths
            .split_last()
            .ok_or_else(|| Error::Internal("an output set without a marker".into()))?;
        let _lock = SetLock::acquire(&self.folder, &self.stem)?;
        remove_marker(marker)?;
        for p in companions {
            let staged = self.path(p);
            if staged.exists() {
                std::fs::rename(&staged, p).map_err(|e| Error::io(p, e))?;
            }
        }
        std::fs::rename(self.path(marker), marker).map_err(|e| Error::io(marker, e))
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// `.STEM.lock` beside an output set while a run commits it (created exclusively, holding the PID). A
/// lock whose process no longer runs is taken over; a live one is waited for (a commit is renames only).
struct SetLock(PathBuf);

impl SetLock {
    const WAIT: std::time::Duration = std::time::Duration::from_secs(120);

    fn acquire(folder: &Path, stem: &str) -> Result<SetLock> {
        let path = folder.join(format!(".{stem}.lock"));
        let start = std::time::Instant::now();
        loop {
            match super::create_new_with(&path, std::process::id().to_string().as_bytes()) {
                Ok(true) => return Ok(SetLock(path)),
                Ok(false) => {
                    let holder = lock_holder(&path);
                    if holder.is_some_and(|pid| !super::process_running(pid)) {
                        let _ = std::fs::remove_file(&path);
                        continue;
                    }
                    if start.elapsed() > Self::WAIT {
                        return Err(Error::Resource(format!(
                            "{}: another run (PID {}) has been writing this output set for over {} s",
                            path.display(),
                            holder.map_or_else(|| "unknown".to_string(), |p| p.to_string()),
                            Self::WAIT.as_secs()
                        )));
                    }
                    std::thread::sleep(std::time::Duration::from_millis(20));
                }
                Err(e) => return Err(Error::io(&path, e)),
            }
        }
    }
}

/// The PID a set's lock at `path` holds (written whole before the lock appears, [`super::create_new_with`]).
fn lock_holder(path: &Path) -> Option<u32> {
    std::fs::read_to_string(path).ok()?.trim().parse().ok()
}

/// Whether a live run holds a set's lock (`.STEM.lock`) in `folder`: it is committing that set.
fn commit_in_progress(folder: &Path) -> bool {
    std::fs::read_dir(folder)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| {
            let n = e.file_name().to_string_lossy().into_owned();
            n.starts_with('.') && n.ends_with(".lock")
        })
        .filter_map(|e| lock_holder(&e.path()))
        .any(super::process_running)
}

impl Drop for SetLock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}
