//! Cohorts: `[[anatomy.dataset]]` folders of CT cases, each case becoming CT targets exactly as an
//! `[[anatomy.ct]]` entry does (the same reading, checking, meshing and rendering code).
//!
//! [`prepare`] finds the cases ([`dataset`]), reads and checks each one with the study's own input
//! loader (the CT and label map read whole, labels present, same grid: a truncated file, a bad affine
//! or a missing level is found here), and writes the outcome to `OUT/cohort/manifest.json`: the cases
//! studied and the cases left out with the file and the reason. The manifest is keyed by the dataset
//! configs and the size and modification time of every file found, so every shard of a cluster run
//! uses the same case list without reading every CT again (the one written by `--slurm` on the
//! submitting host, or by whichever shard came first: atomic writes of identical bytes). With
//! `strict = true` a case left out is an error before any work, naming the file. [`expand`] turns the
//! manifest's cases into `[[anatomy.ct]]` entries.

pub mod dataset;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::config::{AnatomyConfig, CtTarget, StudyConfig};
use super::experiments;
use super::schema::StudyTables;
use super::schema::cohort::{CaseOf, CohortRow, LeftOutRow, cohort_rows};
use super::schema::write_rows;
use super::units::derive_seed;
use crate::anatomy::ct::{LabelMap, read_labels, write_labels};
use crate::io::write_json;
use crate::{Error, Result};
use dataset::{DatasetConfig, FoundCase, SegSource, target_part};

/// The folder of `OUT` that holds the manifest and merged label maps.
pub const COHORT_DIR: &str = "cohort";

/// The cases of a study's datasets, as checked.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Hash of the dataset configs and of the files found (paths, sizes, modification times).
    pub key: String,
    pub cases: Vec<Case>,
    pub left_out: Vec<LeftOut>,
}

/// A case studied.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Case {
    pub dataset: String,
    /// The case id in the dataset (`sub-verse004`, `s0001`).
    pub case: String,
    /// The `[[anatomy.ct]]` name of the case: its targets are `<target>-<level>`.
    pub target: String,
    pub ct: PathBuf,
    /// The label map (for per-structure masks: the merged map under `OUT/cohort/labels/`).
    pub seg: PathBuf,
}

/// A case that could not be read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LeftOut {
    pub dataset: String,
    pub case: String,
    /// The file at fault (or the case's CT when the error names none).
    pub file: PathBuf,
    pub reason: String,
}

fn manifest_path(out: &Path) -> PathBuf {
    out.join(COHORT_DIR).join("manifest.json")
}

/// The manifest a run wrote into `out`, if any.
pub fn read_manifest(out: &Path) -> Option<Manifest> {
    let text = std::fs::read_to_string(manifest_path(out)).ok()?;
    serde_json::from_str(&text).ok()
}

/// Size and modification time of a file (or `-` when absent), for the manifest key.
fn stamp(p: &Path) -> String {
    match std::fs::metadata(p) {
        Ok(m) => {
            let t = m
                .modified()
                .ok()
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                .map_or(0, |d| d.as_nanos());
            format!("{}:{t}", m.len())
        }
        Err(_) => "-".into(),
    }
}

/// The files of a case's labels that are read (for per-structure masks, one per level).
fn seg_files(d: &DatasetConfig, c: &FoundCase) -> Vec<PathBuf> {
    match &c.seg {
        SegSource::LabelMap(p) => vec![p.clone()],
        SegSource::Structures(dir) => d
            .levels
            .iter()
            .map(|l| dir.join(format!("vertebrae_{}.nii.gz", level_name(l))))
            .collect(),
    }
}

/// `L1` from `L1` or `vertebrae_L1`.
fn level_name(l: &str) -> &str {
    l.trim().strip_prefix("vertebrae_").unwrap_or(l.trim())
}

fn key_of(datasets: &[DatasetConfig], found: &[Vec<FoundCase>]) -> Result<String> {
    let mut s = serde_json::to_string(datasets).map_err(|e| Error::encode("dataset configs", e))?;
    for (d, cases) in datasets.iter().zip(found) {
        for c in cases {
            s.push_str(&format!("\n{}|{}|{}", c.id, c.ct.display(), stamp(&c.ct)));
            for f in seg_files(d, c) {
                s.push_str(&format!("|{}|{}", f.display(), stamp(&f)));
            }
        }
    }
    Ok(format!("{:016x}", derive_seed(0, &s, 0)))
}

/// The case's label map file: the given one, or the per-structure masks merged (each level's mask
/// voxels get the level's TotalSegmentator id) into `OUT/cohort/labels/<target>.nii.gz`.
fn label_map(d: &DatasetConfig, c: &FoundCase, target: &str, out: &Path) -> Result<PathBuf> {
    let dir = match &c.seg {
        SegSource::LabelMap(p) => return Ok(p.clone()),
        SegSource::Structures(dir) => dir,
    };
    let conv = d.convention()?;
    let mut merged: Option<LabelMap> = None;
    for (l, f) in d.levels.iter().zip(seg_files(d, c)) {
        let id = conv.resolve(l)?;
        if !f.is_file() {
            return Err(Error::Format {
                path: f.clone(),
                message: format!("no mask of level {l} in {}", dir.display()),
            });
        }
        let mask = read_labels(&f)?;
        let m = merged.get_or_insert_with(|| LabelMap {
            dims: mask.dims,
            values: vec![0; mask.values.len()],
            index_to_world: mask.index_to_world,
        });
        if !m.same_grid(&mask) {
            return Err(Error::format(
                &f,
                format!(
                    "not on the grid of the case's other masks (dims {:?} vs {:?})",
                    mask.dims, m.dims
                ),
            ));
        }
        for (v, &x) in m.values.iter_mut().zip(&mask.values) {
            if x != 0 {
                *v = id;
            }
        }
    }
    let merged = merged.ok_or_else(|| Error::invalid("anatomy.dataset.levels", "no levels"))?;
    let path = out
        .join(COHORT_DIR)
        .join("labels")
        .join(format!("{target}.nii.gz"));
    std::fs::create_dir_all(path.parent().unwrap_or(out)).map_err(|e| Error::io(&path, e))?;
    write_labels(&path, &merged)?;
    Ok(path)
}

/// The `[[anatomy.ct]]` entry of a case.
fn ct_entry(d: &DatasetConfig, target: &str, ct: &Path, seg: &Path) -> Result<CtTarget> {
    Ok(CtTarget {
        name: target.to_string(),
        ct: ct.to_path_buf(),
        seg: seg.to_path_buf(),
        labels: d.convention()?,
        levels: d.levels.clone(),
        landmarks: None,
        segment: d.segment,
        align: Default::default(),
        smooth_iterations: d.smooth_iterations,
        method: Default::default(),
    })
}

/// Reads and checks one case with the study's input loader; the error names the file at fault.
fn check_case(
    cfg: &StudyConfig,
    d: &DatasetConfig,
    c: &FoundCase,
    out: &Path,
) -> std::result::Result<Case, LeftOut> {
    let target = format!("{}-{}", d.name, target_part(&c.id));
    let left_out = |e: Error| {
        let file = match &e {
            Error::Io { path, .. } | Error::Format { path, .. } => path.clone(),
            _ => c.ct.clone(),
        };
        LeftOut {
            dataset: d.name.clone(),
            case: c.id.clone(),
            file,
            reason: e.to_string(),
        }
    };
    let seg = label_map(d, c, &target, out).map_err(left_out)?;
    let entry = ct_entry(d, &target, &c.ct, &seg).map_err(left_out)?;
    let one = StudyConfig {
        anatomy: AnatomyConfig {
            levels: Vec::new(),
            meshes: Vec::new(),
            ct: vec![entry],
            dataset: Vec::new(),
            ..cfg.anatomy.clone()
        },
        ..cfg.clone()
    };
    // Missing files are named by the loader's read; the whole CT and label map are read (a truncated
    // gzip stream fails here), labels checked present and the grids compared. Then the case's targets
    // are built as a run builds them (label surfaces, automatic landmarks, renderers) and checked to
    // land on the detector, so a case that passes cannot fail later in a shard.
    let inputs = experiments::load_inputs(&one).map_err(left_out)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .map_err(|e| left_out(Error::Resource(format!("building a thread pool: {e}"))))?;
    let timings = std::sync::Arc::new(super::timings::Timings::default());
    let ctx = experiments::Context::build(&one, inputs, out, timings, &pool).map_err(left_out)?;
    ctx.check_on_detector().map_err(left_out)?;
    Ok(Case {
        dataset: d.name.clone(),
        case: c.id.clone(),
        target,
        ct: c.ct.clone(),
        seg,
    })
}

/// Finds and checks the cases of `cfg`'s datasets, reusing `OUT/cohort/manifest.json` when its key
/// matches; `None` without datasets. With `strict = true` on a dataset, a case of it left out is an
/// error naming the file. Cases are checked in parallel on at most 4 threads (each holds a CT).
pub fn prepare(cfg: &StudyConfig, out: &Path) -> Result<Option<Manifest>> {
    let datasets = &cfg.anatomy.dataset;
    if datasets.is_empty() {
        return Ok(None);
    }
    let found = datasets
        .iter()
        .map(|d| d.discover())
        .collect::<Result<Vec<_>>>()?;
    let key = key_of(datasets, &found)?;
    let manifest = match read_manifest(out).filter(|m| m.key == key) {
        Some(m) => m,
        None => {
            let threads = std::thread::available_parallelism()
                .map_or(1, |n| n.get())
                .min(4);
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .map_err(|e| Error::Resource(format!("building the case-checking pool: {e}")))?;
            let jobs: Vec<(&DatasetConfig, &FoundCase)> = datasets
                .iter()
                .zip(&found)
                .flat_map(|(d, cases)| cases.iter().map(move |c| (d, c)))
                .collect();
            let checked: Vec<std::result::Result<Case, LeftOut>> = pool.install(|| {
                jobs.par_iter()
                    .map(|(d, c)| check_case(cfg, d, c, out))
                    .collect()
            });
            let mut m = Manifest {
                key,
                cases: Vec::new(),
                left_out: Vec::new(),
            };
            for r in checked {
                match r {
                    Ok(c) => m.cases.push(c),
                    Err(l) => m.left_out.push(l),
                }
            }
            // A strict dataset's bad case stops the run before anything is written.
            strict_check(datasets, &m)?;
            let dir = out.join(COHORT_DIR);
            std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
            write_json(&manifest_path(out), &m)?;
            m
        }
    };
    strict_check(datasets, &manifest)?;
    if manifest.cases.is_empty() {
        return Err(Error::invalid(
            "anatomy.dataset",
            format!(
                "no usable case in {} ({} left out)",
                datasets
                    .iter()
                    .map(|d| d.folder.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", "),
                manifest.left_out.len()
            ),
        ));
    }
    for l in &manifest.left_out {
        eprintln!(
            "warning: dataset '{}': case '{}' left out ({}): {}",
            l.dataset,
            l.case,
            l.file.display(),
            l.reason
        );
    }
    Ok(Some(manifest))
}

/// The error for the first case left out of a dataset with `strict = true`, naming the file.
fn strict_check(datasets: &[DatasetConfig], m: &Manifest) -> Result<()> {
    match m
        .left_out
        .iter()
        .find(|l| datasets.iter().any(|d| d.name == l.dataset && d.strict))
    {
        Some(l) => Err(Error::invalid(
            "anatomy.dataset (strict = true)",
            format!(
                "dataset '{}', case '{}': {} cannot be used: {}",
                l.dataset,
                l.case,
                l.file.display(),
                l.reason
            ),
        )),
        None => Ok(()),
    }
}

/// `cfg` with every case of `manifest` appended as an `[[anatomy.ct]]` entry.
pub fn expand(cfg: &StudyConfig, manifest: &Manifest) -> Result<StudyConfig> {
    let mut c = cfg.clone();
    for case in &manifest.cases {
        let d = cfg
            .anatomy
            .dataset
            .iter()
            .find(|d| d.name == case.dataset)
            .ok_or_else(|| {
                Error::Internal(format!(
                    "manifest case of unknown dataset '{}'",
                    case.dataset
                ))
            })?;
        c.anatomy
            .ct
            .push(ct_entry(d, &case.target, &case.ct, &case.seg)?);
    }
    Ok(c)
}

/// The config a run works on: `cfg` itself without datasets, else with its cases expanded
/// ([`prepare`], [`expand`]).
pub fn resolve(cfg: &StudyConfig, out: &Path) -> Result<StudyConfig> {
    match prepare(cfg, out)? {
        None => Ok(cfg.clone()),
        Some(m) => expand(cfg, &m),
    }
}

/// A dataset target: its case and its level (`L1`) or `segment`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CaseTarget {
    pub dataset: String,
    pub case: String,
    pub level: String,
}

/// Every dataset target of an expanded config, by target name.
pub fn case_targets(cfg: &StudyConfig, manifest: &Manifest) -> BTreeMap<String, CaseTarget> {
    let mut m = BTreeMap::new();
    for case in &manifest.cases {
        let Some(entry) = cfg.anatomy.ct.iter().find(|e| e.name == case.target) else {
            continue;
        };
        for (t, _) in entry.level_targets().unwrap_or_default() {
            let level = t[entry.name.len() + 1..].to_string();
            m.insert(
                t,
                CaseTarget {
                    dataset: case.dataset.clone(),
                    case: case.case.clone(),
                    level,
                },
            );
        }
        if entry.segment {
            m.insert(
                entry.segment_target(),
                CaseTarget {
                    dataset: case.dataset.clone(),
                    case: case.case.clone(),
                    level: super::config::SEGMENT_TARGET.into(),
                },
            );
        }
    }
    m
}

/// Which case (`<dataset>/<case>`) each level target of the cases is (segment targets left out).
pub fn case_of(cfg: &StudyConfig, manifest: &Manifest) -> CaseOf {
    case_targets(cfg, manifest)
        .into_iter()
        .filter(|(_, c)| c.level != super::config::SEGMENT_TARGET)
        .map(|(t, c)| (t, format!("{}/{}", c.dataset, c.case)))
        .collect()
}

/// The cohort of a finished study in `out`: its manifest and the cohort rows of `tables` (`None`
/// without datasets).
pub fn cohort_of(
    out: &Path,
    cfg: &StudyConfig,
    tables: &StudyTables,
) -> Option<(Manifest, Vec<CohortRow>)> {
    if cfg.anatomy.dataset.is_empty() {
        return None;
    }
    let m = read_manifest(out)?;
    let rows = cohort_rows(tables, &case_of(cfg, &m));
    Some((m, rows))
}

/// Writes `tables/cohort.csv` and `tables/cohort_left_out.csv` when the study has datasets; returns
/// how many tables.
pub fn write_tables(out: &Path, cfg: &StudyConfig, tables: &StudyTables) -> Result<usize> {
    let Some((m, rows)) = cohort_of(out, cfg, tables) else {
        return Ok(0);
    };
    let dir = out.join("tables");
    write_rows(&dir, &rows)?;
    let left: Vec<LeftOutRow> = m
        .left_out
        .iter()
        .map(|l| LeftOutRow {
            dataset: l.dataset.clone(),
            case: l.case.clone(),
            file: l.file.display().to_string(),
            reason: l.reason.clone(),
        })
        .collect();
    write_rows(&dir, &left)?;
    Ok(2)
}
