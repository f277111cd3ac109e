//! How the cases of an `[[anatomy.dataset]]` ([`DatasetConfig`]) are found on disk, layout by layout.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub use crate::study::config::dataset::{DatasetConfig, Layout};
use crate::{Error, Result};

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
