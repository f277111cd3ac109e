//! `[[anatomy.dataset]]`: a folder of CT cases in a known layout, and how its cases are found.
//!
//! Layouts:
//! * `verse` — the VerSe 2019/2020 release (BIDS naming): `rawdata/sub-X/sub-X[_entities]_ct.nii.gz`
//!   with its mask `derivatives/sub-X/sub-X[_entities]_seg-vert_msk.nii.gz` (or both in one
//!   `sub-X/` folder); labels 20–24 = L1–L5. The case is the file stem (`sub-verse004`,
//!   `sub-gl003_dir-ax`).
//! * `totalseg` — one folder per case holding `ct.nii.gz` and the TotalSegmentator label map: the
//!   multilabel `segmentations.nii.gz` (`TotalSegmentator --ml`), or the per-structure files of the
//!   TotalSegmentator dataset, `segmentations/vertebrae_L1.nii.gz` …, merged into one label map
//!   (TotalSegmentator v2 ids) by [`super::prepare`]. The case is the folder name.
//! * `glob` — two patterns relative to the folder with one `{case}` each, e.g. `ct = "{case}/image.nii.gz"`,
//!   `seg = "{case}/labels.nii.gz"`; `labels` names the convention (default `totalseg`).
//!
//! Cases are sorted by id; `include` keeps only the listed ids, `exclude` drops ids.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::anatomy::labels::LabelConvention;
use crate::{Error, Result};

/// A dataset's file layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    Verse,
    Totalseg,
    Glob,
}

/// `[[anatomy.dataset]]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetConfig {
    /// Prefix of its targets: case `C` level `L1` is target `<name>-<C>-L1`.
    pub name: String,
    /// The dataset's root folder (relative paths: relative to the config file).
    pub folder: PathBuf,
    pub layout: Layout,
    /// `glob` layout: the CT pattern, with one `{case}`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ct: Option<String>,
    /// `glob` layout: the label-map pattern, with one `{case}`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seg: Option<String>,
    /// `glob` layout: the label convention (`totalseg` or `verse`; default `totalseg`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub labels: Option<String>,
    /// Levels studied in every case (`L1`, …).
    pub levels: Vec<String>,
    /// Only these case ids (default: every case found).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub include: Vec<String>,
    /// Case ids left out.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub exclude: Vec<String>,
    /// A case that cannot be read stops the study before any work (default: it is reported, skipped
    /// and listed in the report's *cases left out* table).
    #[serde(default)]
    pub strict: bool,
    /// Also study each case's levels together (`<name>-<C>-segment`).
    #[serde(default)]
    pub segment: bool,
    /// Taubin smoothing of every case's label surfaces, as `[[anatomy.ct]]`'s `smooth_iterations`
    /// (about 10 for thick slices, whose stair steps automatic landmarks cannot read).
    #[serde(default)]
    pub smooth_iterations: usize,
}

/// One case found on disk (files not yet read).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FoundCase {
    pub id: String,
    pub ct: PathBuf,
    /// The label map, or for per-structure TotalSegmentator files their folder.
    pub seg: SegSource,
}

/// Where a case's labels come from.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SegSource {
    /// One label map on the CT's grid.
    LabelMap(PathBuf),
    /// A folder of binary masks `vertebrae_<level>.nii.gz` (TotalSegmentator's per-structure output).
    Structures(PathBuf),
}

impl SegSource {
    /// The file (or folder) to name in messages.
    pub fn path(&self) -> &Path {
        match self {
            SegSource::LabelMap(p) | SegSource::Structures(p) => p,
        }
    }
}

impl DatasetConfig {
    /// The label convention of the dataset's label maps.
    pub fn convention(&self) -> Result<LabelConvention> {
        match self.layout {
            Layout::Verse => Ok(LabelConvention::Verse),
            Layout::Totalseg => Ok(LabelConvention::TotalSegmentator),
            Layout::Glob => match &self.labels {
                None => Ok(LabelConvention::TotalSegmentator),
                Some(s) => s.parse().map_err(|e: Error| {
                    Error::invalid("anatomy.dataset.labels", format!("'{}': {e}", self.name))
                }),
            },
        }
    }

    /// Static checks (names, patterns, levels, lists); the folder is read by [`Self::discover`].
    pub fn check(&self) -> Result<()> {
        let key = |k: &str| format!("anatomy.dataset.{k}");
        let ok_name = !self.name.is_empty()
            && self
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-');
        if !ok_name {
            return Err(Error::invalid(
                key("name"),
                format!("'{}' must be non-empty, letters/digits/'-' only", self.name),
            ));
        }
        if self.levels.is_empty() {
            return Err(Error::invalid(
                key("levels"),
                format!("dataset '{}' lists no levels", self.name),
            ));
        }
        let conv = self.convention()?;
        for l in &self.levels {
            conv.resolve(l).map_err(|e| {
                Error::invalid(
                    key("levels"),
                    format!("dataset '{}': {l:?}: {e}", self.name),
                )
            })?;
        }
        let glob = self.layout == Layout::Glob;
        for (k, v) in [("ct", &self.ct), ("seg", &self.seg)] {
            match (glob, v) {
                (true, None) => {
                    return Err(Error::invalid(
                        key(k),
                        format!(
                            "dataset '{}' (layout glob) needs `{k}`, a pattern with one {{case}}",
                            self.name
                        ),
                    ));
                }
                (true, Some(p)) if p.matches("{case}").count() != 1 => {
                    return Err(Error::invalid(
                        key(k),
                        format!("{p:?} must hold {{case}} exactly once"),
                    ));
                }
                (false, Some(_)) => {
                    return Err(Error::invalid(
                        key(k),
                        format!(
                            "dataset '{}': `{k}` is for layout = \"glob\" only",
                            self.name
                        ),
                    ));
                }
                _ => {}
            }
        }
        if let (Some(ct), Some(seg)) = (&self.ct, &self.seg)
            && ct == seg
        {
            return Err(Error::invalid(
                key("seg"),
                format!(
                    "dataset '{}': {seg:?} is the CT pattern too; the label map must be another file",
                    self.name
                ),
            ));
        }
        if !glob && self.labels.is_some() {
            return Err(Error::invalid(
                key("labels"),
                format!(
                    "dataset '{}': the {:?} layout fixes its labels; `labels` is for layout = \"glob\"",
                    self.name, self.layout
                ),
            ));
        }
        Ok(())
    }

    /// The cases in the folder, sorted by id, after `include` / `exclude`. An `include` id that is not
    /// found is an error naming it; so is a folder that cannot be listed.
    pub fn discover(&self) -> Result<Vec<FoundCase>> {
        if !self.folder.is_dir() {
            return Err(Error::invalid(
                "anatomy.dataset.folder",
                format!(
                    "dataset '{}': no such folder {}",
                    self.name,
                    self.folder.display()
                ),
            ));
        }
        let mut cases = match self.layout {
            Layout::Verse => verse_cases(&self.folder)?,
            Layout::Totalseg => totalseg_cases(&self.folder)?,
            Layout::Glob => glob_cases(
                &self.folder,
                self.ct.as_deref().unwrap_or_default(),
                self.seg.as_deref().unwrap_or_default(),
            )?,
        };
        cases.sort_by(|a, b| a.id.cmp(&b.id));
        cases.dedup_by(|a, b| a.id == b.id);
        for id in &self.include {
            if !cases.iter().any(|c| &c.id == id) {
                return Err(Error::invalid(
                    "anatomy.dataset.include",
                    format!(
                        "dataset '{}': no case {id:?} in {} ({} cases found)",
                        self.name,
                        self.folder.display(),
                        cases.len()
                    ),
                ));
            }
        }
        if !self.include.is_empty() {
            cases.retain(|c| self.include.contains(&c.id));
        }
        cases.retain(|c| !self.exclude.contains(&c.id));
        Ok(cases)
    }
}

fn list(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    v.sort();
    Ok(v)
}

fn file_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

const VERSE_CT: &str = "_ct.nii.gz";
const VERSE_MASK: &str = "_seg-vert_msk.nii.gz";

/// VerSe: every `sub-*/…_ct.nii.gz` under `rawdata/` (or directly under the folder), with the mask of
/// the same stem in `derivatives/sub-*/` or beside the CT. A CT without its mask is still a case (its
/// mask is named missing when it is read).
fn verse_cases(root: &Path) -> Result<Vec<FoundCase>> {
    let raw = root.join("rawdata");
    let image_root = if raw.is_dir() {
        raw
    } else {
        root.to_path_buf()
    };
    let mut out = Vec::new();
    for sub in list(&image_root)? {
        let subject = file_name(&sub);
        if !(subject.starts_with("sub-") && sub.is_dir()) {
            continue;
        }
        for f in list(&sub)? {
            let name = file_name(&f);
            let Some(stem) = name.strip_suffix(VERSE_CT) else {
                continue;
            };
            let mask_name = format!("{stem}{VERSE_MASK}");
            let derived = root.join("derivatives").join(&subject).join(&mask_name);
            let beside = sub.join(&mask_name);
            let mask = if beside.is_file() { beside } else { derived };
            out.push(FoundCase {
                id: stem.to_string(),
                ct: f.clone(),
                seg: SegSource::LabelMap(mask),
            });
        }
    }
    Ok(out)
}

/// TotalSegmentator: each sub-folder with a `ct.nii.gz`; labels from `segmentations.nii.gz`, else the
/// `segmentations/` folder of per-structure masks.
fn totalseg_cases(root: &Path) -> Result<Vec<FoundCase>> {
    let mut out = Vec::new();
    for dir in list(root)? {
        let ct = dir.join("ct.nii.gz");
        if !(dir.is_dir() && ct.is_file()) {
            continue;
        }
        let multi = dir.join("segmentations.nii.gz");
        let seg = if multi.is_file() || !dir.join("segmentations").is_dir() {
            SegSource::LabelMap(multi)
        } else {
            SegSource::Structures(dir.join("segmentations"))
        };
        out.push(FoundCase {
            id: file_name(&dir),
            ct,
            seg,
        });
    }
    Ok(out)
}

/// `glob`: the CT pattern's matches, the case being what `{case}` matched; the label map is the seg
/// pattern with that case.
fn glob_cases(root: &Path, ct: &str, seg: &str) -> Result<Vec<FoundCase>> {
    let (pre, post) = ct.split_once("{case}").unwrap_or((ct, ""));
    let pattern = root.join(format!(
        "{}*{}",
        glob::Pattern::escape(pre),
        glob::Pattern::escape(post)
    ));
    let pattern_s = pattern.to_string_lossy().into_owned();
    let paths = glob::glob(&pattern_s)
        .map_err(|e| Error::invalid("anatomy.dataset.ct", format!("pattern {ct:?}: {e}")))?;
    let root_s = root.to_string_lossy().into_owned();
    let mut out = Vec::new();
    for p in paths.flatten() {
        let s = p.to_string_lossy().into_owned();
        let Some(rel) = s.strip_prefix(&root_s) else {
            continue;
        };
        let rel = rel.trim_start_matches('/');
        let Some(id) = rel.strip_prefix(pre).and_then(|r| r.strip_suffix(post)) else {
            continue;
        };
        // `{case}` stands for one path component's part, never a path.
        if id.is_empty() || id.contains('/') {
            continue;
        }
        out.push(FoundCase {
            id: id.to_string(),
            ct: p.clone(),
            seg: SegSource::LabelMap(root.join(seg.replace("{case}", id))),
        });
    }
    Ok(out)
}

/// A case id as a target-name part: letters, digits and '-' (others become '-').
pub fn target_part(id: &str) -> String {
    id.chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn touch(p: &Path) {
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, b"x").unwrap();
    }

    fn dataset(layout: Layout, folder: &Path) -> DatasetConfig {
        DatasetConfig {
            name: "d".into(),
            folder: folder.to_path_buf(),
            layout,
            ct: None,
            seg: None,
            labels: None,
            levels: vec!["L1".into()],
            include: vec![],
            exclude: vec![],
            strict: false,
            segment: false,
            smooth_iterations: 0,
        }
    }

    #[test]
    fn verse_layout_finds_bids_names_in_rawdata_and_derivatives() {
        let d = tempfile::tempdir().unwrap();
        let r = d.path();
        touch(&r.join("rawdata/sub-verse004/sub-verse004_ct.nii.gz"));
        touch(&r.join("derivatives/sub-verse004/sub-verse004_seg-vert_msk.nii.gz"));
        touch(&r.join("rawdata/sub-gl003/sub-gl003_dir-ax_ct.nii.gz"));
        touch(&r.join("derivatives/sub-gl003/sub-gl003_dir-ax_seg-vert_msk.nii.gz"));
        touch(&r.join("derivatives/sub-gl003/sub-gl003_dir-ax_seg-subreg_ctd.json"));
        touch(&r.join("rawdata/notasubject/x_ct.nii.gz"));
        let cases = dataset(Layout::Verse, r).discover().unwrap();
        let ids: Vec<&str> = cases.iter().map(|c| c.id.as_str()).collect();
        assert_eq!(ids, ["sub-gl003_dir-ax", "sub-verse004"]);
        assert_eq!(
            cases[1].seg,
            SegSource::LabelMap(
                r.join("derivatives/sub-verse004/sub-verse004_seg-vert_msk.nii.gz")
            )
        );
        assert_eq!(target_part(&cases[0].id), "sub-gl003-dir-ax");
    }

    #[test]
    fn totalseg_layout_takes_multilabel_or_structure_folders() {
        let d = tempfile::tempdir().unwrap();
        let r = d.path();
        touch(&r.join("s0001/ct.nii.gz"));
        touch(&r.join("s0001/segmentations.nii.gz"));
        touch(&r.join("s0002/ct.nii.gz"));
        touch(&r.join("s0002/segmentations/vertebrae_L1.nii.gz"));
        touch(&r.join("notes/readme.txt"));
        let mut ds = dataset(Layout::Totalseg, r);
        let cases = ds.discover().unwrap();
        assert_eq!(cases.len(), 2);
        assert_eq!(
            cases[0].seg,
            SegSource::LabelMap(r.join("s0001/segmentations.nii.gz"))
        );
        assert_eq!(
            cases[1].seg,
            SegSource::Structures(r.join("s0002/segmentations"))
        );
        ds.exclude = vec!["s0001".into()];
        assert_eq!(ds.discover().unwrap().len(), 1);
        ds.include = vec!["s0009".into()];
        let e = ds.discover().unwrap_err().to_string();
        assert!(
            e.contains("anatomy.dataset.include") && e.contains("s0009"),
            "{e}"
        );
    }

    #[test]
    fn glob_layout_captures_the_case() {
        let d = tempfile::tempdir().unwrap();
        let r = d.path();
        touch(&r.join("img/a1_ct.nii.gz"));
        touch(&r.join("img/b2_ct.nii.gz"));
        touch(&r.join("img/deep/c3_ct.nii.gz"));
        let mut ds = dataset(Layout::Glob, r);
        ds.ct = Some("img/{case}_ct.nii.gz".into());
        ds.seg = Some("lab/{case}.nii.gz".into());
        ds.check().unwrap();
        let cases = ds.discover().unwrap();
        let ids: Vec<&str> = cases.iter().map(|c| c.id.as_str()).collect();
        assert_eq!(ids, ["a1", "b2"]);
        assert_eq!(cases[0].seg, SegSource::LabelMap(r.join("lab/a1.nii.gz")));
        ds.seg = Some("lab/x.nii.gz".into());
        assert!(ds.check().unwrap_err().to_string().contains("{case}"));
    }
}
