//! `OUT/.study.lock`: one run at a time in a study's output folder — also when the folder is on storage
//! that several hosts (or PID namespaces) share.
//!
//! The lock file is created whole or not at all ([`create_new_with`]) and names its owner: host, PID, PID namespace and start
//! time (JSON). While the run lives, a heartbeat thread refreshes the file's modification time every
//! [`HEARTBEAT`]. Another run decides whether the lock is stale by the only evidence it can trust:
//!
//! - same host and same PID namespace: stale exactly when the PID no longer runs (`/proc/PID`);
//! - another host, another PID namespace, or an owner that cannot be read: a PID means nothing there, so
//!   the lock is stale only when its heartbeat has stopped for [`STALE_AFTER`] (the file's modification
//!   time, which the shared file system stamps). A live run on another host is never taken over.
//!
//! A taken-over lock is reported on stderr with its owner and the evidence.

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};

use crate::io::{create_new_with, process_running};
use crate::{Error, Result};

/// The name of the lock file in a study's output folder.
pub const LOCK_FILE: &str = ".study.lock";

/// How often a live run refreshes its lock's modification time.
pub const HEARTBEAT: Duration = Duration::from_secs(10);

/// How long a lock of another host or PID namespace must go without a heartbeat to count as stale
/// (60 missed heartbeats: a stalled file server or a clock skew of minutes does not make it stale).
pub const STALE_AFTER: Duration = Duration::from_secs(600);

/// Who holds a lock.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LockOwner {
    pub host: String,
    pub pid: u32,
    /// `/proc/self/ns/pid` of the owner (`pid:[4026531836]`), when it has one.
    pub pid_namespace: Option<String>,
    /// When the run took the lock (seconds since the Unix epoch).
    pub started_unix_s: u64,
}

impl LockOwner {
    /// This process.
    pub fn current() -> LockOwner {
        LockOwner {
            host: host_name(),
            pid: std::process::id(),
            pid_namespace: pid_namespace(),
            started_unix_s: SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0, |d| d.as_secs()),
        }
    }

    /// Whether this owner's PID can be checked from here: the same host and the same PID namespace.
    fn pid_is_ours_to_check(&self, me: &LockOwner) -> bool {
        self.host == me.host && self.pid_namespace == me.pid_namespace
    }

    fn describe(&self, me: &LockOwner) -> String {
        if self.host != me.host {
            format!("PID {} on host {}", self.pid, self.host)
        } else if self.pid_namespace != me.pid_namespace {
            format!(
                "PID {} in another PID namespace ({}) of this host",
                self.pid,
                self.pid_namespace.as_deref().unwrap_or("unknown")
            )
        } else {
            format!("PID {}", self.pid)
        }
    }
}

/// The host's name (`/proc/sys/kernel/hostname`, else `$HOSTNAME`, else "unknown-host").
fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok().filter(|s| !s.is_empty()))
        .unwrap_or_else(|| "unknown-host".to_string())
}

/// The PID namespace of this process (`pid:[…]`), where `/proc` says.
fn pid_namespace() -> Option<String> {
    std::fs::read_link("/proc/self/ns/pid")
        .ok()
        .map(|p| p.to_string_lossy().into_owned())
}

/// What a lock file says about its owner.
#[derive(Debug, Clone, PartialEq)]
enum Read {
    /// The owner (a lock of an earlier spinedrr holds a bare PID: taken as this host's).
    Owner(LockOwner),
    /// Empty or unreadable (being written, or damaged).
    Unknown,
    /// Gone (released meanwhile).
    Missing,
}

fn read_owner(path: &Path, me: &LockOwner) -> Read {
    for attempt in 0..2 {
        match std::fs::read_to_string(path) {
            Ok(t) if !t.trim().is_empty() => {
                if let Ok(o) = serde_json::from_str::<LockOwner>(&t) {
                    return Read::Owner(o);
                }
                return match t.trim().parse::<u32>() {
                    Ok(pid) => Read::Owner(LockOwner {
                        pid,
                        started_unix_s: 0,
                        ..me.clone()
                    }),
                    Err(_) => Read::Unknown,
                };
            }
            // A lock just created by another run may not hold its owner yet.
            Ok(_) if attempt == 0 => std::thread::sleep(Duration::from_millis(200)),
            Ok(_) => return Read::Unknown,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Read::Missing,
            Err(_) => return Read::Unknown,
        }
    }
    Read::Unknown
}

/// How long ago the lock file was last refreshed (zero when its time is in the future or unreadable).
fn heartbeat_age(path: &Path) -> Duration {
    std::fs::metadata(path)
        .and_then(|m| m.modified())
        .ok()
        .and_then(|t| SystemTime::now().duration_since(t).ok())
        .unwrap_or(Duration::ZERO)
}

/// Why a lock is stale, or `None` when its owner may be alive.
fn stale_reason(path: &Path, owner: Option<&LockOwner>, me: &LockOwner) -> Option<String> {
    if let Some(o) = owner
        && o.pid_is_ours_to_check(me)
    {
        // Our own PID in a lock is a lock this process left (or a reused PID's): never live.
        return (o.pid == me.pid || !process_running(o.pid))
            .then(|| format!("{}, no longer running", o.describe(me)));
    }
    let age = heartbeat_age(path);
    let who = owner.map_or_else(|| "an unreadable owner".to_string(), |o| o.describe(me));
    (age >= STALE_AFTER).then(|| {
        format!(
            "{who}, no heartbeat for {} s (a live run refreshes it every {} s)",
            age.as_secs(),
            HEARTBEAT.as_secs()
        )
    })
}

/// An exclusive claim on a study's output folder, released (and its heartbeat stopped) when dropped.
#[derive(Debug)]
pub struct OutputLock {
    path: PathBuf,
    owner: LockOwner,
    stop: Option<mpsc::Sender<()>>,
    heartbeat: Option<JoinHandle<()>>,
}

impl OutputLock {
    /// Claims `out` (which must exist): creates the lock, or takes over a stale one with a warning; a
    /// live one is an error naming its owner.
    pub fn acquire(out: &Path) -> Result<OutputLock> {
        Self::acquire_beating(out, HEARTBEAT)
    }

    /// [`Self::acquire`] with the heartbeat every `every` (the tests' short one; runs use [`HEARTBEAT`]).
    fn acquire_beating(out: &Path, every: Duration) -> Result<OutputLock> {
        let path = out.join(LOCK_FILE);
        let me = LockOwner::current();
        let text = serde_json::to_string(&me).map_err(|e| Error::encode("the study lock", e))?;
        for _ in 0..3 {
            match create_new_with(&path, text.as_bytes()) {
                Ok(true) => return Ok(OutputLock::held(path, me, every)),
                Ok(false) => {
                    let owner = match read_owner(&path, &me) {
                        Read::Missing => continue,
                        Read::Owner(o) => Some(o),
                        Read::Unknown => None,
                    };
                    let Some(why) = stale_reason(&path, owner.as_ref(), &me) else {
                        let who = owner.map_or_else(
                            || "a run whose lock cannot be read".to_string(),
                            |o| o.describe(&me),
                        );
                        return Err(Error::Resource(format!(
                            "{}: another study ({who}) is running into {}; wait for it to finish, or \
                             use another --out (a lock of another host or PID namespace counts as stale \
                             only after {} s without its heartbeat)",
                            path.display(),
                            out.display(),
                            STALE_AFTER.as_secs()
                        )));
                    };
                    eprintln!(
                        "warning: taking over the stale lock {} ({why})",
                        path.display()
                    );
                    match std::fs::remove_file(&path) {
                        Ok(()) => {}
                        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                        Err(e) => return Err(Error::io(&path, e)),
                    }
                }
                Err(e) => return Err(Error::io(&path, e)),
            }
        }
        Err(Error::Resource(format!(
            "{}: could not claim the output folder (another run keeps taking it)",
            path.display()
        )))
    }

    /// The lock at `path`, now ours, with its heartbeat thread started (a beat every `every`).
    fn held(path: PathBuf, owner: LockOwner, every: Duration) -> OutputLock {
        let (tx, rx) = mpsc::channel::<()>();
        let (p, o) = (path.clone(), owner.clone());
        // Without a thread the lock still works; it only goes stale for other hosts after STALE_AFTER.
        let heartbeat = std::thread::Builder::new()
            .name("study-lock-heartbeat".into())
            .spawn(move || {
                while let Err(mpsc::RecvTimeoutError::Timeout) = rx.recv_timeout(every) {
                    if read_owner(&p, &o) != Read::Owner(o.clone()) {
                        break; // taken over after all: never touch another run's lock
                    }
                    if let Ok(f) = std::fs::OpenOptions::new().write(true).open(&p) {
                        let _ = f.set_modified(SystemTime::now());
                    }
                }
            })
            .ok();
        OutputLock {
            path,
            owner,
            stop: Some(tx),
            heartbeat,
        }
    }
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        drop(self.stop.take());
        if let Some(h) = self.heartbeat.take() {
            let _ = h.join();
        }
        // Only our own lock is removed (one taken over by another run after ours went stale is theirs).
        if read_owner(&self.path, &self.owner) == Read::Owner(self.owner.clone()) {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lock_file(dir: &Path, owner: &LockOwner, age: Duration) -> PathBuf {
        let p = dir.join(LOCK_FILE);
        std::fs::write(&p, serde_json::to_string(owner).unwrap()).unwrap();
        let f = std::fs::OpenOptions::new().write(true).open(&p).unwrap();
        f.set_modified(SystemTime::now() - age).unwrap();
        p
    }

    /// A PID above the kernel's pid_max (2²² at most): never running here.
    const DEAD_PID: u32 = 4_999_999;

    #[test]
    fn another_hosts_lock_is_never_stale_by_pid_only_by_its_heartbeat() {
        let dir = tempfile::tempdir().unwrap();
        let other = LockOwner {
            host: format!("{}-elsewhere", host_name()),
            pid: DEAD_PID,
            ..LockOwner::current()
        };
        lock_file(dir.path(), &other, Duration::from_secs(5));
        let e = OutputLock::acquire(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("on host") && e.contains(&other.host) && e.contains("4999999"),
            "{e}"
        );
        assert!(dir.path().join(LOCK_FILE).exists());
        lock_file(dir.path(), &other, STALE_AFTER + Duration::from_secs(5));
        let lock = OutputLock::acquire(dir.path()).unwrap();
        let now: LockOwner =
            serde_json::from_str(&std::fs::read_to_string(dir.path().join(LOCK_FILE)).unwrap())
                .unwrap();
        assert_eq!(now, lock.owner);
        drop(lock);
        assert!(!dir.path().join(LOCK_FILE).exists());
    }

    #[test]
    fn another_pid_namespace_is_judged_by_heartbeat_and_ours_by_pid() {
        let dir = tempfile::tempdir().unwrap();
        let me = LockOwner::current();
        let ns = LockOwner {
            pid: DEAD_PID,
            pid_namespace: Some("pid:[1]".into()),
            ..me.clone()
        };
        lock_file(dir.path(), &ns, Duration::ZERO);
        let e = OutputLock::acquire(dir.path()).unwrap_err().to_string();
        assert!(e.contains("another PID namespace"), "{e}");
        // The same PID in our namespace is dead: stale at once, whatever the heartbeat.
        lock_file(
            dir.path(),
            &LockOwner {
                pid: DEAD_PID,
                ..me
            },
            Duration::ZERO,
        );
        drop(OutputLock::acquire(dir.path()).unwrap());
    }

    #[test]
    fn a_bare_pid_lock_of_an_earlier_version_is_read_as_this_hosts() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(LOCK_FILE);
        std::fs::write(&p, std::process::id().to_string()).unwrap();
        // Our own PID is running, but a lock is never refused to its own process.
        drop(OutputLock::acquire(dir.path()).unwrap());
        std::fs::write(&p, "1").unwrap(); // init: running
        assert!(OutputLock::acquire(dir.path()).is_err());
        std::fs::write(&p, "garbage").unwrap();
        let e = OutputLock::acquire(dir.path()).unwrap_err().to_string();
        assert!(e.contains("cannot be read"), "{e}");
    }

    #[test]
    fn the_heartbeat_refreshes_the_lock() {
        let dir = tempfile::tempdir().unwrap();
        // A beat every 200 ms instead of every HEARTBEAT (10 s): the same thread and loop, a shorter wait.
        let every = Duration::from_millis(200);
        let lock = OutputLock::acquire_beating(dir.path(), every).unwrap();
        let p = dir.path().join(LOCK_FILE);
        let f = std::fs::OpenOptions::new().write(true).open(&p).unwrap();
        f.set_modified(SystemTime::now() - Duration::from_secs(3600))
            .unwrap();
        assert!(heartbeat_age(&p) >= Duration::from_secs(3600));
        std::thread::sleep(every * 6);
        assert!(heartbeat_age(&p) < every * 6, "{:?}", heartbeat_age(&p));
        drop(lock);
    }
}
