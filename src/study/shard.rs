//! Splitting a study's work units over N processes (`spinedrr study --shard I/N`, or a Slurm array
//! task), so that a cluster runs one study and `--assemble` builds one report from all the unit files.
//!
//! The assignment is a pure function of the config and N: every process computes the same one, so
//! shards need no coordination. It balances the expected cost ([`unit_cost`], an estimate in
//! milliseconds of one core from the measured study timings) by the longest-processing-time greedy
//! rule — units by decreasing cost, each to the shard that would finish it first — where "finish"
//! counts what the shard must prepare before it can run the unit: the anatomy of the unit's input (the
//! phantom, a mesh target, a CT entry: [`setup_cost`]) and the reference render of its target and view,
//! each once per shard. So a shard's units cluster on few inputs (a cohort's CT is read by one or two
//! shards, not by all) and the N shards finish at about the same time.
//!
//! Shards share nothing but the output folder: each builds only the anatomy its units need
//! ([`restrict_config`]), writes its unit files atomically (temporary name + rename; the names carry
//! the process id, so two writers never share a temporary) and never deletes anything, so shards
//! started together on one folder cannot corrupt each other. Inputs several shards prepare (reference
//! renders, the cohort manifest) are written the same way, byte-identical whoever writes last.

use std::collections::BTreeSet;
use std::fmt;
use std::path::Path;

use super::config::StudyConfig;
use super::units::Unit;
use crate::{Error, Result};

mod assign;

use assign::target_groups;
pub use assign::{CostModel, InputGroup, assign, assign_with, shard_loads, shards_with, units_of};

/// Shard `index` of `count` (0 ≤ index < count).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

/// At most this many shards (a Slurm array is rarely larger; the assignment is O(units × shards)).
pub const MAX_SHARDS: usize = 10_000;

impl Shard {
    /// A checked shard.
    pub fn new(index: usize, count: usize) -> Result<Shard> {
        if count == 0 || count > MAX_SHARDS {
            return Err(Error::invalid(
                "shard (--shard I/N)",
                format!("N = {count}: must be between 1 and {MAX_SHARDS}"),
            ));
        }
        if index >= count {
            return Err(Error::invalid(
                "shard (--shard I/N)",
                format!("I = {index} must be below N = {count} (shards are numbered 0 to N − 1)"),
            ));
        }
        Ok(Shard { index, count })
    }

    /// Parses `I/N` (0-based I).
    pub fn parse(s: &str) -> Result<Shard> {
        let bad = || {
            Error::invalid(
                "shard (--shard I/N)",
                format!("{s:?}: expected I/N with 0 ≤ I < N, e.g. 0/4"),
            )
        };
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let i: usize = i.trim().parse().map_err(|_| bad())?;
        let n: usize = n.trim().parse().map_err(|_| bad())?;
        Shard::new(i, n)
    }

    /// The shard of a Slurm array task: `SLURM_ARRAY_TASK_ID` of `SLURM_ARRAY_TASK_COUNT`, or `None`
    /// outside an array. (An array of a subset of the shards, such as a resubmission, has fewer tasks
    /// than shards: its script passes `--shard` explicitly.)
    pub fn from_env() -> Result<Option<Shard>> {
        let get = |k: &str| std::env::var(k).ok();
        Shard::from_vars(
            get("SLURM_ARRAY_TASK_ID").as_deref(),
            get("SLURM_ARRAY_TASK_COUNT").as_deref(),
        )
    }

    /// [`Shard::from_env`] on given values.
    pub fn from_vars(id: Option<&str>, count: Option<&str>) -> Result<Option<Shard>> {
        let (id, count) = match (id, count) {
            (None, None) => return Ok(None),
            (Some(i), Some(n)) => (i, n),
            (i, n) => {
                return Err(Error::invalid(
                    "SLURM_ARRAY_TASK_ID / SLURM_ARRAY_TASK_COUNT",
                    format!("only one is set ({i:?}, {n:?}); set both or pass --shard I/N"),
                ));
            }
        };
        let num = |k: &str, v: &str| {
            v.trim()
                .parse::<usize>()
                .map_err(|_| Error::invalid(k, format!("{v:?} is not a non-negative integer")))
        };
        let (i, n) = (
            num("SLURM_ARRAY_TASK_ID", id)?,
            num("SLURM_ARRAY_TASK_COUNT", count)?,
        );
        Shard::new(i, n).map(Some).map_err(|e| {
            Error::invalid(
                "SLURM_ARRAY_TASK_ID / SLURM_ARRAY_TASK_COUNT",
                format!(
                    "{e} (number the array from 0, e.g. --array=0-{}, or pass --shard I/N)",
                    n.max(1) - 1
                ),
            )
        })
    }

    /// The file name tag of this shard, `shard-I-of-N`.
    pub fn tag(&self) -> String {
        format!("shard-{}-of-{}", self.index, self.count)
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// `cfg` with only the anatomy the `units` need: the phantom when one of its targets is studied
/// (its levels and segment are built together, so the segment stays the same), and the mesh and CT
/// entries of the units' targets. The experiments, grid and seed are unchanged, so a unit computes
/// the same rows in the restricted context as in the full one.
pub fn restrict_config(cfg: &StudyConfig, units: &[&Unit]) -> StudyConfig {
    let groups = target_groups(cfg);
    let calibration = assign::calibration_target(cfg);
    let needed: BTreeSet<InputGroup> = units
        .iter()
        .map(|u| {
            let t = match u {
                Unit::Projection { target, .. }
                | Unit::Registration { target, .. }
                | Unit::Screws { target } => target,
                Unit::Calibration(_) => &calibration,
                // Built from the phantom by the experiment itself.
                Unit::Intensity(c) => &c.target,
                Unit::Tracking(c) => &c.target,
                Unit::RegistrationPhysical(c) => &c.target,
            };
            groups
                .get(t)
                .map_or(InputGroup::Phantom, |(g, _)| g.clone())
        })
        .collect();
    let mut c = cfg.clone();
    // The restricted study's first target may differ: name the calibration's target explicitly.
    if units.iter().any(|u| matches!(u, Unit::Calibration(_))) {
        c.calibration.target = Some(calibration.clone());
    }
    if !needed.contains(&InputGroup::Phantom) {
        c.anatomy.levels.clear();
    }
    c.anatomy
        .meshes
        .retain(|m| needed.contains(&InputGroup::Mesh(m.name.clone())));
    c.anatomy
        .ct
        .retain(|e| needed.contains(&InputGroup::Ct(e.name.clone())));
    c
}

/// The error of `--assemble` when units are missing: how many, the first ids, and (when the shard
/// count is known) the shards to run again.
pub fn missing_units_error(
    out: &Path,
    units: &[Unit],
    missing: &[usize],
    shards: Option<(usize, Vec<usize>)>,
) -> Error {
    let first: Vec<String> = missing.iter().take(10).map(|&i| units[i].id()).collect();
    let more = missing.len().saturating_sub(first.len());
    let shards = match shards {
        Some((n, s)) => format!(
            "; they belong to shard{} {} of {n} (run `spinedrr study --shard I/{n}` for each, or \
             `spinedrr study --slurm --submit` again)",
            if s.len() == 1 { "" } else { "s" },
            s.iter()
                .map(|i| i.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
        None => String::new(),
    };
    Error::format(
        out.join("units"),
        format!(
            "{} of {} work units are missing or from another config, so the tables cannot be \
             assembled: {}{}{shards}",
            missing.len(),
            units.len(),
            first.join(", "),
            if more > 0 {
                format!(" and {more} more")
            } else {
                String::new()
            }
        ),
    )
}

/// The folder of `OUT` where `--slurm` writes its plan (`plan.json`, see `study::slurm`).
pub const PLAN_DIR: &str = "slurm";

/// The shard count of the plan `--slurm` wrote into `out`, if any.
pub fn planned_shards(out: &Path) -> Option<usize> {
    let text = std::fs::read_to_string(out.join(PLAN_DIR).join("plan.json")).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    v.get("shards")?.as_u64().map(|n| n as usize)
}

/// Gets the output folder ready for a shard without taking it over: creates the folders, writes
/// `study.toml` when absent, and refuses a folder whose `study.toml` is another config's (a shard never
/// deletes: clearing a folder is the job of `--slurm` or of an unsharded run, which own it whole).
pub fn prepare_folder(out: &Path, toml: &str, dirs: &[&str]) -> Result<()> {
    for d in std::iter::once(".").chain(dirs.iter().copied()) {
        let p = out.join(d);
        std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
    }
    let path = out.join("study.toml");
    match std::fs::read_to_string(&path) {
        Ok(t) if t == toml => Ok(()),
        Ok(_) => Err(Error::invalid(
            "--shard",
            format!(
                "{} is another study's config: a shard does not clear a folder; run `spinedrr \
                 study --slurm` (which prepares it) or use another --out",
                path.display()
            ),
        )),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            crate::io::write_atomic_bytes(&path, toml.as_bytes())
        }
        Err(e) => Err(Error::io(&path, e)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shard_spellings() {
        assert_eq!(Shard::parse("0/4").unwrap(), Shard { index: 0, count: 4 });
        assert_eq!(Shard::parse(" 3 / 4 ").unwrap().to_string(), "3/4");
        for bad in ["4/4", "1/0", "x/2", "1", "-1/3", "1/2/3"] {
            let e = Shard::parse(bad).unwrap_err().to_string();
            assert!(e.contains("--shard"), "{bad}: {e}");
        }
        assert_eq!(Shard::from_vars(None, None).unwrap(), None);
        assert_eq!(
            Shard::from_vars(Some("2"), Some("5")).unwrap(),
            Some(Shard { index: 2, count: 5 })
        );
        let e = Shard::from_vars(Some("4"), Some("4"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("--array=0-3"), "{e}");
        assert!(Shard::from_vars(Some("1"), None).is_err());
        assert!(Shard::from_vars(Some("a"), Some("2")).is_err());
    }
}
