//! A disk cache of the phantom's meshes, shared by every `spinedrr` process of one build.
//!
//! Meshing the phantom (sampling the SDFs, extracting and simplifying the isosurfaces) takes seconds;
//! everything else about it (poses, landmarks, disc and soft-tissue shapes) is cheap and always
//! recomputed. An entry holds the meshes of one phantom and is reused only when **both** of these are
//! equal to the request's:
//!
//! * the *code digest* (`SPINEDRR_CODE_DIGEST`, computed by `build.rs` from every source, asset and lock
//!   file, the compiler's version and the profile): a changed generator never serves an old mesh;
//! * the *identity*: the phantom's options written out in full (`{:?}`, whose floats round-trip), with the
//!   levels sorted and deduplicated. The entry stores its identity and the reader compares it byte for
//!   byte, so even a colliding file name cannot mix two phantoms.
//!
//! Entries are written to a temporary file and renamed into place (readers never see half an entry;
//! concurrent writers of one entry write the same bytes) and carry a BLAKE3 checksum of their contents;
//! an entry that is truncated, corrupt, or of another format is rebuilt and rewritten, with a warning.
//! The cache can only make a build faster: a directory that cannot be written costs a warning, never a
//! failure. Layout: `ROOT/phantom/DIGEST/BLAKE3(identity).bin`; when a new digest's directory is created
//! the oldest sibling digests beyond the newest [`KEEP_DIGESTS`] are removed.
//!
//! The cache is off unless a process turns it on ([`enable`]): the `spinedrr` binary does, at
//! [`MeshCache::from_env`]'s directory; the library, its tests and the Python module build afresh.

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicUsize, Ordering};

use glam::DVec3;

use super::TriMesh;
use crate::{Error, Result};

/// The build's code digest (see the module documentation). A `static`, not a `const`: a constant is
/// copied into the code of every function that reads it, and since the digest changes with every edit
/// of any source file, an incremental rebuild after a one-line edit recompiled all of them (measured:
/// 61 s against 26 s for `cargo test --no-run` after one constant changed in `error.rs`).
pub static CODE_DIGEST: &str = env!("SPINEDRR_CODE_DIGEST");

/// How many code digests' directories are kept (the newest by modification time).
pub const KEEP_DIGESTS: usize = 3;

/// The environment variable naming the cache's root directory; `off` (or empty) turns the cache off.
pub const CACHE_DIR_VAR: &str = "SPINEDRR_CACHE_DIR";

const MAGIC: &[u8] = b"spinedrr phantom meshes v1\n";

/// A mesh cache at one root directory; counts its hits, misses and rejected entries.
#[derive(Debug)]
pub struct MeshCache {
    root: PathBuf,
    hits: AtomicUsize,
    misses: AtomicUsize,
    rejected: AtomicUsize,
}

static GLOBAL: OnceLock<MeshCache> = OnceLock::new();

/// Turns the process-wide cache on (the first call wins); [`super::build_phantom`] uses it from then on.
pub fn enable(cache: MeshCache) {
    let _ = GLOBAL.set(cache);
}

/// The process-wide cache, if [`enable`] was called.
pub fn global() -> Option<&'static MeshCache> {
    GLOBAL.get()
}

impl MeshCache {
    /// A cache rooted at `root` (created when the first entry is written).
    pub fn new(root: impl Into<PathBuf>) -> Self {
        MeshCache {
            root: root.into(),
            hits: AtomicUsize::new(0),
            misses: AtomicUsize::new(0),
            rejected: AtomicUsize::new(0),
        }
    }

    /// The cache `$SPINEDRR_CACHE_DIR` names (none when it is `off` or empty), else
    /// `$XDG_CACHE_HOME/spinedrr`, else `$HOME/.cache/spinedrr`; none without any of them.
    pub fn from_env() -> Option<Self> {
        let var = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
        match std::env::var_os(CACHE_DIR_VAR) {
            Some(v) if v.is_empty() || v == "off" => None,
            Some(v) => Some(MeshCache::new(v)),
            None => var("XDG_CACHE_HOME")
                .map(|d| PathBuf::from(d).join("spinedrr"))
                .or_else(|| var("HOME").map(|h| PathBuf::from(h).join(".cache/spinedrr")))
                .map(MeshCache::new),
        }
    }

    /// The root directory.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// (hits, misses, rejected entries) so far.
    pub fn stats(&self) -> (usize, usize, usize) {
        (
            self.hits.load(Ordering::Relaxed),
            self.misses.load(Ordering::Relaxed),
            self.rejected.load(Ordering::Relaxed),
        )
    }

    /// The directory of this build's entries.
    pub fn digest_dir(&self) -> PathBuf {
        self.root.join("phantom").join(CODE_DIGEST)
    }

    /// The file of the entry for `identity`.
    pub fn entry_path(&self, identity: &str) -> PathBuf {
        let name = blake3::hash(identity.as_bytes()).to_hex();
        self.digest_dir().join(format!("{name}.bin"))
    }

    /// The `count` meshes stored for `identity`, or those `build` makes (then stored). A miss takes an
    /// exclusive lock on the entry (`NAME.lock`, released when the process ends however it ends) and looks
    /// again before building, so processes that miss the same entry together build it once.
    pub fn meshes(
        &self,
        identity: &str,
        count: usize,
        build: impl FnOnce() -> Result<Vec<TriMesh>>,
    ) -> Result<Vec<TriMesh>> {
        let path = self.entry_path(identity);
        if let Some(m) = self.lookup(&path, identity, count, false) {
            return Ok(m);
        }
        let lock = self.lock(&path);
        if lock.is_some()
            && let Some(m) = self.lookup(&path, identity, count, true)
        {
            return Ok(m);
        }
        self.misses.fetch_add(1, Ordering::Relaxed);
        let meshes = build()?;
        if meshes.len() != count {
            return Err(Error::invalid(
                "phantom meshes",
                format!("built {} meshes where {count} were expected", meshes.len()),
            ));
        }
        if let Err(e) = self.store(&path, &encode(identity, &meshes)) {
            eprintln!(
                "warning: phantom mesh cache: could not write {} ({e}); the phantom was built and is used, not cached",
                path.display()
            );
        }
        drop(lock);
        Ok(meshes)
    }

    /// The entry at `path`, if it is there and valid; an invalid one is counted and warned about (on the
    /// second look only when it was not already, `again`).
    fn lookup(
        &self,
        path: &Path,
        identity: &str,
        count: usize,
        again: bool,
    ) -> Option<Vec<TriMesh>> {
        match fs::read(path) {
            Ok(bytes) => match decode(&bytes, identity, count) {
                Ok(m) => {
                    self.hits.fetch_add(1, Ordering::Relaxed);
                    Some(m)
                }
                Err(why) => {
                    if !again {
                        self.rejected.fetch_add(1, Ordering::Relaxed);
                        eprintln!(
                            "warning: phantom mesh cache entry {} is unusable ({why}); rebuilding it",
                            path.display()
                        );
                    }
                    None
                }
            },
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
            Err(e) => {
                if !again {
                    eprintln!(
                        "warning: phantom mesh cache entry {} cannot be read ({e}); rebuilding it",
                        path.display()
                    );
                }
                None
            }
        }
    }

    /// An exclusive lock on the entry at `path`, held until the file is dropped; none where the
    /// directory cannot be made or the file system does not lock (the build then goes ahead unlocked).
    fn lock(&self, path: &Path) -> Option<fs::File> {
        fs::create_dir_all(self.digest_dir()).ok()?;
        let f = fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(path.with_extension("lock"))
            .ok()?;
        f.lock().ok()?;
        Some(f)
    }

    /// Writes the entry atomically ([`crate::io::write_atomic_bytes`]; temporaries of writers that died
    /// are removed first), pruning older digests when this is the digest's first entry.
    fn store(&self, path: &Path, bytes: &[u8]) -> Result<()> {
        let dir = self.digest_dir();
        let first = !fs::read_dir(&dir).is_ok_and(|mut d| {
            d.any(|e| e.is_ok_and(|e| e.file_name().to_string_lossy().ends_with(".bin")))
        });
        fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        crate::io::remove_stale_temporaries(&dir);
        let written = crate::io::write_atomic_bytes(path, bytes);
        if first {
            self.prune();
        }
        written
    }

    /// Removes the directories of older code digests beyond the newest [`KEEP_DIGESTS`] (only names that
    /// are digests: 32 hex digits).
    fn prune(&self) {
        let Ok(entries) = fs::read_dir(self.root.join("phantom")) else {
            return;
        };
        let mut dirs: Vec<(std::time::SystemTime, PathBuf)> = entries
            .filter_map(|e| e.ok())
            .filter(|e| {
                let n = e.file_name();
                let n = n.to_string_lossy();
                n.len() == 32 && n.bytes().all(|b| b.is_ascii_hexdigit()) && n != CODE_DIGEST
            })
            .filter_map(|e| Some((e.metadata().ok()?.modified().ok()?, e.path())))
            .collect();
        dirs.sort_by_key(|d| std::cmp::Reverse(d.0));
        for (_, d) in dirs.into_iter().skip(KEEP_DIGESTS.saturating_sub(1)) {
            let _ = fs::remove_dir_all(d);
        }
    }
}

fn put(out: &mut Vec<u8>, bytes: &[u8]) {
    out.extend_from_slice(&(bytes.len() as u64).to_le_bytes());
    out.extend_from_slice(bytes);
}

/// An entry's bytes: magic, digest, identity, the meshes, then the BLAKE3 hash of all that.
fn encode(identity: &str, meshes: &[TriMesh]) -> Vec<u8> {
    let mut out = MAGIC.to_vec();
    put(&mut out, CODE_DIGEST.as_bytes());
    put(&mut out, identity.as_bytes());
    out.extend_from_slice(&(meshes.len() as u64).to_le_bytes());
    for m in meshes {
        put(&mut out, m.name.as_bytes());
        out.extend_from_slice(&(m.vertices.len() as u64).to_le_bytes());
        for v in &m.vertices {
            for c in v.to_array() {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        out.extend_from_slice(&(m.triangles.len() as u64).to_le_bytes());
        for t in &m.triangles {
            for i in t {
                out.extend_from_slice(&i.to_le_bytes());
            }
        }
        put(&mut out, &m.labels);
    }
    let sum = blake3::hash(&out);
    out.extend_from_slice(sum.as_bytes());
    out
}

/// Reads an entry, checking the checksum, the format, the digest, the identity, the mesh count and that
/// every triangle indexes a vertex of its mesh; the error says what did not match.
fn decode(bytes: &[u8], identity: &str, count: usize) -> std::result::Result<Vec<TriMesh>, String> {
    if bytes.len() < MAGIC.len() + 32 || &bytes[..MAGIC.len()] != MAGIC {
        return Err("not a phantom mesh entry of this format".into());
    }
    let (body, sum) = bytes.split_at(bytes.len() - 32);
    if blake3::hash(body).as_bytes() != sum {
        return Err("checksum mismatch (truncated or corrupt)".into());
    }
    let mut r = Reader(&body[MAGIC.len()..]);
    if r.bytes()? != CODE_DIGEST.as_bytes() {
        return Err("written by another build".into());
    }
    if r.bytes()? != identity.as_bytes() {
        return Err("holds another phantom".into());
    }
    let n = r.len(1)?;
    if n != count {
        return Err(format!("holds {n} meshes, {count} expected"));
    }
    let mut meshes = Vec::with_capacity(n);
    for _ in 0..n {
        let name =
            String::from_utf8(r.bytes()?.to_vec()).map_err(|_| "a mesh name is not UTF-8")?;
        let nv = r.len(24)?;
        let vertices = (0..nv)
            .map(|_| Ok(DVec3::new(r.f64()?, r.f64()?, r.f64()?)))
            .collect::<std::result::Result<Vec<_>, String>>()?;
        let nt = r.len(12)?;
        let triangles = (0..nt)
            .map(|_| Ok([r.u32()?, r.u32()?, r.u32()?]))
            .collect::<std::result::Result<Vec<_>, String>>()?;
        if triangles.iter().flatten().any(|&i| i as usize >= nv) {
            return Err(format!("mesh {name} indexes a vertex it lacks"));
        }
        let labels = r.bytes()?.to_vec();
        if !labels.is_empty() && labels.len() != nt {
            return Err(format!(
                "mesh {name} has {} labels for {nt} triangles",
                labels.len()
            ));
        }
        meshes.push(TriMesh {
            name,
            vertices,
            triangles,
            labels,
        });
    }
    if !r.0.is_empty() {
        return Err("trailing bytes".into());
    }
    Ok(meshes)
}

/// A bounds-checked little-endian reader.
struct Reader<'a>(&'a [u8]);

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> std::result::Result<&'a [u8], String> {
        if n > self.0.len() {
            return Err("ends early".into());
        }
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        Ok(a)
    }
    fn u64(&mut self) -> std::result::Result<u64, String> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }
    /// A count of items of `size` bytes each, no more than the bytes left could hold.
    fn len(&mut self, size: usize) -> std::result::Result<usize, String> {
        let n = self.u64()?;
        usize::try_from(n)
            .ok()
            .filter(|&n| n.checked_mul(size).is_some_and(|b| b <= self.0.len()))
            .ok_or_else(|| format!("a count of {n} exceeds the entry"))
    }
    fn bytes(&mut self) -> std::result::Result<&'a [u8], String> {
        let n = self.len(1)?;
        self.take(n)
    }
    fn f64(&mut self) -> std::result::Result<f64, String> {
        Ok(f64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }
    fn u32(&mut self) -> std::result::Result<u32, String> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().expect("4 bytes"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra(name: &str) -> TriMesh {
        TriMesh {
            name: name.into(),
            vertices: vec![
                DVec3::ZERO,
                DVec3::X,
                DVec3::Y,
                DVec3::new(0.1, -0.0, 1.0 / 3.0),
            ],
            triangles: vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]],
            labels: vec![1, 2, 3, 4],
        }
    }

    #[test]
    fn entries_round_trip_bit_for_bit_and_reject_every_single_byte_change() {
        let meshes = vec![
            tetra("a"),
            TriMesh {
                labels: vec![],
                ..tetra("b")
            },
        ];
        let bytes = encode("id", &meshes);
        let back = decode(&bytes, "id", 2).unwrap();
        for (x, y) in meshes.iter().zip(&back) {
            assert_eq!(x.name, y.name);
            assert_eq!(x.triangles, y.triangles);
            assert_eq!(x.labels, y.labels);
            let bits = |m: &TriMesh| -> Vec<u64> {
                m.vertices
                    .iter()
                    .flat_map(|v| v.to_array().map(f64::to_bits))
                    .collect()
            };
            assert_eq!(bits(x), bits(y));
        }
        assert!(
            decode(&bytes, "other", 2)
                .unwrap_err()
                .contains("another phantom")
        );
        assert!(decode(&bytes, "id", 3).unwrap_err().contains("3 expected"));
        for i in 0..bytes.len() {
            let mut b = bytes.clone();
            b[i] ^= 0x10;
            assert!(
                decode(&b, "id", 2).is_err(),
                "byte {i} flipped was accepted"
            );
        }
        for n in 0..bytes.len() {
            assert!(decode(&bytes[..n], "id", 2).is_err(), "{n} bytes accepted");
        }
    }

    #[test]
    fn a_well_formed_entry_with_a_bad_index_is_refused_not_used() {
        let mut m = tetra("a");
        m.triangles[0][1] = 9;
        let bytes = encode("id", &[m]);
        assert!(
            decode(&bytes, "id", 1)
                .unwrap_err()
                .contains("indexes a vertex")
        );
    }

    #[test]
    fn processes_and_threads_that_miss_together_build_once() {
        let dir = tempfile::tempdir().unwrap();
        let builds = AtomicUsize::new(0);
        let build = || {
            builds.fetch_add(1, Ordering::SeqCst);
            std::thread::sleep(std::time::Duration::from_millis(200));
            Ok(vec![tetra("a")])
        };
        // Separate caches at one root stand for separate processes (each opens its own lock file).
        let caches: Vec<MeshCache> = (0..4).map(|_| MeshCache::new(dir.path())).collect();
        std::thread::scope(|s| {
            for c in &caches {
                s.spawn(|| {
                    let m = c.meshes("id", 1, build).unwrap();
                    assert_eq!(m[0].triangles, tetra("a").triangles);
                });
            }
        });
        assert_eq!(builds.load(Ordering::SeqCst), 1);
        let (hits, misses) = caches
            .iter()
            .fold((0, 0), |(h, m), c| (h + c.stats().0, m + c.stats().1));
        assert_eq!((hits, misses), (3, 1));
    }
}
