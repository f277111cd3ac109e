//! Claiming a study's output folder: the lock, and what happens to what another config left there.
//!
//! A folder whose `study.toml` is another config's is never cleared implicitly: the run is refused,
//! naming the keys that differ, and nothing in the folder changes. `--start-over` (an explicit
//! [`FolderPolicy::StartOver`]) removes that config's products — `figures/`, `tables/`, `references/`,
//! `report.*`, `timings*.csv` and every unit file that is not this config's — before the run.

use std::path::Path;

use super::experiments;
use super::identity::UnitIdentity;
use super::lock::OutputLock;
use super::units::{Unit, UnitFile};
use crate::io;
use crate::{Error, Result};

/// What to do with a folder that holds another config's results.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FolderPolicy {
    /// Refuse, naming the differing keys (the default: nothing of a finished run is deleted implicitly).
    #[default]
    Keep,
    /// Delete the other config's products, then run (`--start-over`).
    StartOver,
}

/// The product folders of a study.
pub const PRODUCT_DIRS: [&str; 4] = ["units", "tables", "figures", experiments::REFERENCES_DIR];

/// The report files a study writes at the top of its output folder (the report and its list of input
/// files).
const REPORT_FILES: [&str; 3] = ["report.md", "report.html", super::report::INPUTS_CSV];

/// Whether `name` (a file at the top of an output folder) is a study's timing table.
fn is_timings(name: &str) -> bool {
    name == "timings.csv" || (name.starts_with("timings-") && name.ends_with(".csv"))
}

/// Refuses an output folder that holds no study's record (`study.toml`) yet holds what a study writes —
/// `report.md`, `report.html`, a timing table, or files in `units/`, `tables/`, `figures/`,
/// `references/` — naming them: such files are someone's own, not a run this tool may resume or
/// replace. A missing or empty folder, one with only other files (written beside, never over), or one
/// whose product folders are empty (a run stopped before it recorded its config) passes. Called before
/// anything is written into `out`.
pub fn refuse_unowned_products(out: &Path) -> Result<()> {
    if !out.is_dir() || out.join("study.toml").exists() {
        return Ok(());
    }
    let mut found: Vec<String> = std::fs::read_dir(out)
        .map(|es| {
            es.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| REPORT_FILES.contains(&n.as_str()) || is_timings(n))
                .collect()
        })
        .unwrap_or_default();
    for d in PRODUCT_DIRS {
        let files = std::fs::read_dir(out.join(d))
            .map(|es| es.flatten().filter(|e| !is_hidden(&e.path())).count())
            .unwrap_or(0);
        if files > 0 {
            found.push(format!("{d}/ ({files} entries)"));
        }
    }
    if found.is_empty() {
        return Ok(());
    }
    found.sort();
    Err(Error::invalid(
        "--out",
        format!(
            "{} holds no study (no study.toml) but does hold what a study would write over: {}. Nothing \
             was changed. Use a new or empty folder for --out",
            out.display(),
            found.join(", ")
        ),
    ))
}

/// Claims the output folder `out` (which must exist) for this process: takes its lock, checks (or, under
/// [`FolderPolicy::StartOver`], clears) what another config left, creates the product folders and removes
/// stale temporaries.
pub fn claim_folder(
    out: &Path,
    toml: &str,
    units: &[Unit],
    ident: &UnitIdentity,
    policy: FolderPolicy,
) -> Result<OutputLock> {
    let lock = OutputLock::acquire(out)?;
    if let Some(previous) = foreign_config(out, toml) {
        // A study creates units/ before it records its config: a study.toml without it is not a
        // study's record (the user's own config, say), and --start-over deletes only a study's products.
        if !out.join("units").is_dir() {
            return Err(Error::invalid(
                "--out",
                format!(
                    "{}/study.toml is not a study's record (no units/ folder beside it; your own config?): \
                     a study writes its own study.toml there. Nothing was changed. Use another --out",
                    out.display()
                ),
            ));
        }
        match policy {
            FolderPolicy::Keep => return Err(another_config_error(out, &previous, toml)),
            FolderPolicy::StartOver => clear_foreign_products(out, units, ident)?,
        }
    }
    for d in PRODUCT_DIRS {
        let p = out.join(d);
        std::fs::create_dir_all(&p).map_err(|e| Error::io(&p, e))?;
        io::remove_stale_temporaries(&p);
    }
    io::remove_stale_temporaries(out);
    Ok(lock)
}

/// The `study.toml` in `out` when it is another config's.
pub fn foreign_config(out: &Path, toml: &str) -> Option<String> {
    let previous = std::fs::read_to_string(out.join("study.toml")).ok()?;
    (previous != toml).then_some(previous)
}

/// The refusal to run into a folder of another config, with the keys that differ.
pub fn another_config_error(out: &Path, previous: &str, toml: &str) -> Error {
    let diffs = config_differences(previous, toml);
    let shown: Vec<&str> = diffs.iter().take(12).map(String::as_str).collect();
    let more = diffs.len().saturating_sub(shown.len());
    Error::invalid(
        "--out",
        format!(
            "{} holds the results of another study config ({}/study.toml); the keys that differ: {}{}. \
             Nothing was changed. Use another --out, restore that config, or pass --start-over to delete \
             that run's units, tables, figures and report and run this config",
            out.display(),
            out.display(),
            if shown.is_empty() {
                "none (the files differ only in form)".to_string()
            } else {
                shown.join("; ")
            },
            if more > 0 {
                format!("; and {more} more")
            } else {
                String::new()
            }
        ),
    )
}

/// The dotted keys whose values differ between two TOML texts, as `key: old → new` (`(absent)` where a
/// side lacks it), in key order.
pub fn config_differences(previous: &str, current: &str) -> Vec<String> {
    let parse = |t: &str| t.parse::<toml::Table>().map(toml::Value::Table);
    match (parse(previous), parse(current)) {
        (Ok(a), Ok(b)) => {
            let mut out = Vec::new();
            diff_values("", Some(&a), Some(&b), &mut out);
            out
        }
        _ => vec!["(the recorded study.toml does not parse)".to_string()],
    }
}

fn diff_values(key: &str, a: Option<&toml::Value>, b: Option<&toml::Value>, out: &mut Vec<String>) {
    match (a, b) {
        (Some(toml::Value::Table(x)), Some(toml::Value::Table(y))) => {
            let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
            keys.sort();
            keys.dedup();
            for k in keys {
                let child = if key.is_empty() {
                    k.clone()
                } else {
                    format!("{key}.{k}")
                };
                diff_values(&child, x.get(k), y.get(k), out);
            }
        }
        (x, y) if x != y => {
            let show = |v: Option<&toml::Value>| {
                v.map_or_else(|| "(absent)".to_string(), |v| short(&v.to_string()))
            };
            out.push(format!("{key}: {} → {}", show(x), show(y)));
        }
        _ => {}
    }
}

fn short(s: &str) -> String {
    const MAX: usize = 60;
    if s.chars().count() <= MAX {
        s.to_string()
    } else {
        format!("{}…", s.chars().take(MAX).collect::<String>())
    }
}

/// Removes what another config's run left in `out` (see the module doc); says so on stderr.
fn clear_foreign_products(out: &Path, units: &[Unit], ident: &UnitIdentity) -> Result<()> {
    let mut removed = Vec::new();
    for d in ["figures", "tables", experiments::REFERENCES_DIR] {
        let p = out.join(d);
        if p.is_dir() {
            std::fs::remove_dir_all(&p).map_err(|e| Error::io(&p, e))?;
            removed.push(format!("{d}/"));
        }
    }
    let entries = std::fs::read_dir(out).map_err(|e| Error::io(out, e))?;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if (REPORT_FILES.contains(&name.as_str()) || is_timings(&name)) && e.path().is_file() {
            std::fs::remove_file(e.path()).map_err(|err| Error::io(e.path(), err))?;
            removed.push(name);
        }
    }
    let ours: std::collections::HashMap<String, String> =
        units.iter().map(|u| (u.id(), ident.of(u))).collect();
    let mut stale_units = 0;
    if let Ok(entries) = std::fs::read_dir(out.join("units")) {
        for e in entries.flatten() {
            let p = e.path();
            if p.extension().is_none_or(|x| x != "json") || is_hidden(&p) {
                continue;
            }
            let keep = std::fs::read_to_string(&p)
                .ok()
                .and_then(|t| serde_json::from_str::<UnitFile>(&t).ok())
                .is_some_and(|f| ours.get(&f.id) == Some(&f.fingerprint));
            if !keep {
                std::fs::remove_file(&p).map_err(|err| Error::io(&p, err))?;
                stale_units += 1;
            }
        }
    }
    if stale_units > 0 {
        removed.push(format!("{stale_units} unit files"));
    }
    removed.sort();
    eprintln!(
        "note: --start-over: {} held the products of another study config; removed {}",
        out.display(),
        if removed.is_empty() {
            "nothing else".to_string()
        } else {
            removed.join(", ")
        }
    );
    Ok(())
}

fn is_hidden(p: &Path) -> bool {
    p.file_name()
        .is_some_and(|n| n.to_string_lossy().starts_with('.'))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn differences_name_each_changed_key() {
        let a = "seed = 1\n[perturbations]\ndf_px = [100.0]\n[geometry]\nviews = [\"ap\"]\n";
        let b = "seed = 2\n[perturbations]\ndf_px = [100.0]\n[geometry]\nviews = [\"ap\", \"lat\"]\nbinning = 2\n";
        assert_eq!(
            config_differences(a, b),
            vec![
                "geometry.binning: (absent) → 2".to_string(),
                "geometry.views: [\"ap\"] → [\"ap\", \"lat\"]".to_string(),
                "seed: 1 → 2".to_string(),
            ]
        );
        assert!(config_differences(a, a).is_empty());
        assert_eq!(config_differences("= x", a).len(), 1);
    }
}
