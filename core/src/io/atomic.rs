//! Atomic file output: write to a temporary name beside the target, then rename over it, so a reader
//! never sees a half-written file and an interrupted run leaves the previous file intact.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::{Error, Result};

fn temp_name(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
}

/// The process id of a temporary named by [`write_atomic`] (`.NAME.tmp-PID`) or a staging folder of an
/// output set (`.NAME.staging-PID`, [`super::output_set::Staging`]), else `None`.
fn temp_owner(file_name: &str) -> Option<u32> {
    let rest = file_name.strip_prefix('.')?;
    let (name, pid) = rest
        .rsplit_once(".tmp-")
        .or_else(|| rest.rsplit_once(".staging-"))?;
    if name.is_empty() || pid.is_empty() || !pid.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    pid.parse().ok()
}

/// Whether process `pid` runs on this host, as `/proc` says; where there is no `/proc`, every PID counts
/// as running, so nothing of a live run is ever taken for stale.
pub fn process_running(pid: u32) -> bool {
    let proc = Path::new("/proc");
    !proc.join("self").exists() || proc.join(pid.to_string()).exists()
}

/// Removes the temporaries (`.NAME.tmp-PID`) that [`write_atomic`] calls, and the staging folders of
/// output sets (`.NAME.staging-PID/`), of processes no longer running (a killed run) from `dir`, and
/// returns their paths. Liveness is read from `/proc`; where there is no `/proc`, nothing is removed. A
/// temporary of a live process (another run writing now) is kept.
pub fn remove_stale_temporaries(dir: &Path) -> Vec<PathBuf> {
    if !Path::new("/proc/self").exists() {
        return Vec::new();
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    entries
        .flatten()
        .filter(|e| {
            let name = e.file_name();
            let Some(pid) = temp_owner(&name.to_string_lossy()) else {
                return false;
            };
            pid != std::process::id() && !process_running(pid)
        })
        .filter_map(|e| {
            let p = e.path();
            let removed = match e.file_type() {
                Ok(t) if t.is_file() => std::fs::remove_file(&p).is_ok(),
                Ok(t) if t.is_dir() => std::fs::remove_dir_all(&p).is_ok(),
                _ => false,
            };
            removed.then_some(p)
        })
        .collect()
}

/// Writes `path` atomically through `fill`, which receives a buffered writer.
pub fn write_atomic<F>(path: &Path, fill: F) -> Result<()>
where
    F: FnOnce(&mut BufWriter<File>) -> Result<()>,
{
    let tmp = temp_name(path);
    let result = (|| {
        let file = File::create(&tmp).map_err(|e| Error::io(path, e))?;
        let mut w = BufWriter::new(file);
        fill(&mut w)?;
        let file = w
            .into_inner()
            .map_err(|e| Error::io(path, e.into_error()))?;
        file.sync_all().map_err(|e| Error::io(path, e))?;
        std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// Creates `path` holding `bytes`, but only if it does not exist yet: `Ok(true)` when this call created it,
/// `Ok(false)` when it was already there. The bytes are written and synced under a temporary name first
/// and then hard-linked into place, so another process sees either no file or the whole content — never
/// an empty lock (linking is also how locks stay exclusive on NFS). On a file system without hard links
/// it falls back to `create_new` and a write, where a reader may briefly see the file empty.
pub fn create_new_with(path: &Path, bytes: &[u8]) -> std::io::Result<bool> {
    // One temporary per call (threads of one process may race for the same lock).
    static CALLS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let tmp = temp_name(&path.with_extension(format!("{n}.link")));
    let linked = (|| {
        let mut f = File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::hard_link(&tmp, path)
    })();
    let _ = std::fs::remove_file(&tmp);
    match linked {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(false),
        Err(e)
            if matches!(
                e.kind(),
                std::io::ErrorKind::Unsupported | std::io::ErrorKind::PermissionDenied
            ) && !path.exists() =>
        {
            match std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(path)
            {
                Ok(mut f) => f
                    .write_all(bytes)
                    .and_then(|()| f.sync_all())
                    .map(|()| true),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(false),
                Err(e) => Err(e),
            }
        }
        Err(e) => Err(e),
    }
}

/// Writes `value` to `path` atomically as pretty-printed JSON.
pub fn write_json(path: &Path, value: &impl serde::Serialize) -> Result<()> {
    let text = serde_json::to_string_pretty(value)
        .map_err(|e| Error::encode(path.display().to_string(), e))?;
    write_atomic_bytes(path, text.as_bytes())
}

/// Writes `bytes` to `path` atomically.
pub fn write_atomic_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic(path, |w| w.write_all(bytes).map_err(|e| Error::io(path, e)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temporaries_of_dead_processes_are_removed_and_others_kept() {
        let dir = tempfile::tempdir().unwrap();
        // Process ids above the kernel's pid_max (2²² at most) are never alive.
        let dead = dir.path().join(".a.tiff.tmp-4999999");
        let live = dir
            .path()
            .join(format!(".a.json.tmp-{}", std::process::id()));
        let other = dir.path().join(".notes.tmp-x1");
        for p in [&dead, &live, &other] {
            std::fs::write(p, b"x").unwrap();
        }
        assert_eq!(temp_owner(".a.tiff.tmp-4999999"), Some(4_999_999));
        assert_eq!(temp_owner("a.tiff.tmp-12"), None);
        assert_eq!(remove_stale_temporaries(dir.path()), vec![dead.clone()]);
        assert!(!dead.exists() && live.exists() && other.exists());
    }

    #[test]
    fn create_new_with_never_replaces_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(".x.lock");
        assert!(create_new_with(&p, b"first").unwrap());
        assert!(!create_new_with(&p, b"second").unwrap());
        assert_eq!(std::fs::read(&p).unwrap(), b"first");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
