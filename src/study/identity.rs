//! A unit's identity: the config it belongs to and the content of every input file it reads.
//!
//! A unit file (`units/<id>.json`) is reused only when its `fingerprint` equals [`UnitIdentity::of`] the
//! unit: BLAKE3 over the build's code digest ([`BUILD_DIGEST`]: a unit of another build is run again),
//! the config's fingerprint and the BLAKE3 digests of the unit's inputs — the geometry
//! file (every unit), its target's files (a mesh target's surfaces and landmarks; a CT target's CT, label
//! map and landmarks, for each level and the segment), a calibration cell's phantom file. Replacing one
//! input file therefore reruns exactly the units that read it, and a resumed study's tables equal a fresh
//! run's. Built-in anatomy (phantom levels, `plate`, `helix`) reads no file.
//!
//! Digests are cached in `OUT/.input-digests.json` under the file's canonical path, size and modification
//! time (nanoseconds): an unchanged file is not read again; a file whose size or time changed is.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use serde::{Deserialize, Serialize};

use super::config::StudyConfig;
use super::units::Unit;
use crate::{Error, Result};

/// The digest of the code this binary was built from, with its compiler and profile (`build.rs`): a
/// unit file written by another build is computed again, never reused, so a report never states a
/// number its own build did not compute.
pub const BUILD_DIGEST: &str = env!("SPINEDRR_BUILD_DIGEST");

/// The digest cache's file name in the output folder.
pub const DIGEST_CACHE: &str = ".input-digests.json";

/// The identities of a config's units.
#[derive(Debug, Clone)]
pub struct UnitIdentity {
    config_fp: String,
    /// Digests of the files every unit reads (the geometry file).
    common: Vec<String>,
    /// Digests of the files each target's units read.
    targets: HashMap<String, Vec<String>>,
    /// Digests of calibration phantom files, by their `phantoms` entry.
    calibration: HashMap<String, Vec<String>>,
    /// The digest cache, when this computation added to it ([`UnitIdentity::save_cache`]).
    cache: Option<BTreeMap<String, CachedDigest>>,
    /// Every input file of the config, once each.
    inputs: Vec<InputFile>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct CachedDigest {
    size: u64,
    modified_ns: u128,
    blake3: String,
}

/// Content digests by canonical path, cached across runs.
struct Digests {
    cache: BTreeMap<String, CachedDigest>,
    changed: bool,
    /// Every file digested, as the config names it: (path, bytes, BLAKE3), in first-read order.
    read: Vec<InputFile>,
}

/// One input file of a study: its path as the config names it, its size and its BLAKE3 digest.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InputFile {
    pub path: PathBuf,
    pub bytes: u64,
    pub blake3: String,
}

impl Digests {
    fn load(out: &Path) -> Digests {
        let cache = std::fs::read_to_string(out.join(DIGEST_CACHE))
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
            .unwrap_or_default();
        Digests {
            cache,
            changed: false,
            read: Vec::new(),
        }
    }

    /// `path: digest` of the file at `path` (named as the config names it: the identity must not
    /// depend on where the output folder is).
    fn of(&mut self, path: &Path) -> Result<String> {
        let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
        let modified_ns = meta
            .modified()
            .ok()
            .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
            .map_or(0, |d| d.as_nanos());
        let key = std::fs::canonicalize(path)
            .unwrap_or_else(|_| path.to_path_buf())
            .display()
            .to_string();
        let digest = match self.cache.get(&key) {
            Some(c) if c.size == meta.len() && c.modified_ns == modified_ns && modified_ns != 0 => {
                c.blake3.clone()
            }
            _ => {
                let d = hash_file(path)?;
                self.cache.insert(
                    key,
                    CachedDigest {
                        size: meta.len(),
                        modified_ns,
                        blake3: d.clone(),
                    },
                );
                self.changed = true;
                d
            }
        };
        if !self.read.iter().any(|f| f.path == path) {
            self.read.push(InputFile {
                path: path.to_path_buf(),
                bytes: meta.len(),
                blake3: digest.clone(),
            });
        }
        Ok(format!("{}:{digest}", path.display()))
    }

    /// The cache to save, when this run added to it, and the files read.
    fn finish(self) -> (Option<BTreeMap<String, CachedDigest>>, Vec<InputFile>) {
        (self.changed.then_some(self.cache), self.read)
    }
}

/// BLAKE3 of a file's bytes, read in 1 MiB pieces.
fn hash_file(path: &Path) -> Result<String> {
    let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut h = blake3::Hasher::new();
    h.update_reader(&mut f).map_err(|e| Error::io(path, e))?;
    Ok(h.finalize().to_hex().to_string())
}

impl UnitIdentity {
    /// The identities of `cfg`'s units (a config with cohorts already resolved), reading each input once
    /// (or its cached digest from `out`). A missing input is an error naming it.
    pub fn new(cfg: &StudyConfig, config_fp: &str, out: &Path) -> Result<UnitIdentity> {
        let mut digests = Digests::load(out);
        let mut files = |paths: &[&PathBuf]| -> Result<Vec<String>> {
            paths.iter().map(|p| digests.of(p)).collect()
        };
        let common = match &cfg.geometry.file {
            Some(f) => files(&[f])?,
            None => Vec::new(),
        };
        let mut targets = HashMap::new();
        for m in &cfg.anatomy.meshes {
            let mut paths: Vec<&PathBuf> = m.files.iter().collect();
            paths.push(&m.landmarks);
            targets.insert(m.name.clone(), files(&paths)?);
        }
        for c in &cfg.anatomy.ct {
            let mut paths = vec![&c.ct, &c.seg];
            paths.extend(c.landmarks.as_ref());
            let d = files(&paths)?;
            for (name, _) in c.level_targets()? {
                targets.insert(name, d.clone());
            }
            targets.insert(c.segment_target(), d);
        }
        let mut calibration = HashMap::new();
        for p in &cfg.calibration.phantoms {
            if !matches!(p.as_str(), "plate" | "helix") {
                calibration.insert(p.clone(), files(&[&PathBuf::from(p)])?);
            }
        }
        let (cache, inputs) = digests.finish();
        Ok(UnitIdentity {
            config_fp: config_fp.to_string(),
            common,
            targets,
            calibration,
            cache,
            inputs,
        })
    }

    /// Every input file the config reads (geometry, meshes, landmarks, CTs, label maps, phantom files),
    /// once each, with its size and BLAKE3 digest: what the report's provenance names.
    pub fn inputs(&self) -> &[InputFile] {
        &self.inputs
    }

    /// Writes the digest cache into `out` when this computation added to it. Called once the run owns
    /// the folder (a refused run changes nothing in it); a cache only saves reading, so failing to write
    /// it is not an error of the study.
    pub fn save_cache(&self, out: &Path) {
        let Some(cache) = &self.cache else {
            return;
        };
        if let Ok(text) = serde_json::to_string(cache) {
            let _ = crate::io::write_atomic_bytes(&out.join(DIGEST_CACHE), text.as_bytes());
        }
    }

    /// The fingerprint a unit file of `u` must carry: BLAKE3 over the build's code digest, the config's
    /// fingerprint and the unit's input digests (16 hex digits, as the config's).
    pub fn of(&self, u: &Unit) -> String {
        let mut inputs: Vec<&str> = self.common.iter().map(String::as_str).collect();
        let own = match u {
            Unit::Calibration(c) => self.calibration.get(&c.phantom),
            other => other.target().and_then(|t| self.targets.get(t)),
        };
        inputs.extend(own.into_iter().flatten().map(String::as_str));
        let key = format!("{BUILD_DIGEST}\n{}\n{}", self.config_fp, inputs.join("\n"));
        blake3::hash(key.as_bytes()).to_hex()[..16].to_string()
    }
}
