//! VerSe centroid files (`*_seg-subreg_ctd.json` of the VerSe 2019/2020 data sets).
//!
//! **Layout.** A JSON list whose first element states the axis codes, then one object per vertebra:
//! `[{"direction": ["P", "I", "R"]}, {"label": 20, "X": 63.2, "Y": 141.9, "Z": 31.8}, …]`. Labels are the
//! VerSe numbering ([`LabelConvention::Verse`]): 1–7 C1–C7, 8–19 T1–T12, 20–25 L1–L6, 26 sacrum,
//! 27 coccyx, 28 T13. The header may carry more keys (the TPTBox tools add `zoom`, `shape`, `origin`,
//! `format`); `zoom` and `shape` are checked against the image when present.
//!
//! **Coordinates.** `X, Y, Z` are *continuous voxel indices* of the image the centroids belong to, along
//! the three axes the codes name, each code being the direction in which that index grows (nibabel's
//! convention: `P` = the index grows toward posterior). This is what the data set's README says ("given
//! in voxels in the image space") and what its `utils/data_utilities.py` does: `calc_centroids` takes
//! `scipy.ndimage.center_of_mass` of the mask array, and `rescale_centroids` multiplies by the image's
//! zooms to reach millimetres. The published files are written for the image as distributed (their codes
//! are that image's own codes); when the codes differ from the image's, the centroids are of the image
//! *reoriented* to the codes, whose flipped axes run `n − 1 − i` (a voxel-centre flip, as nibabel's
//! `apply_orientation` and `inv_ornt_aff` define it; the data set's own `reorient_centroids_to` uses
//! `n − i`, half a voxel different on average — we follow nibabel, whose affine is the one that holds).
//! Files rescaled to millimetres (coordinates = index × spacing from the volume's first voxel, e.g. after
//! `rescale_centroids` to 1 mm) are read with [`VerseUnits::Millimetres`].
//!
//! The centroid is the centre of mass of the vertebral body (the `subreg` segmentation's body region,
//! hence the file name); it becomes the `center` landmark of its level.

use std::path::Path;

use glam::{DMat4, DVec3};
use serde::Deserialize;

use super::super::ct::{LabelMap, Volume};
use super::super::labels::{LabelConvention, Level};
use super::super::landmarks::Landmarks;
use crate::{Error, Result};

/// What the numbers of a VerSe file measure along each stated axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum VerseUnits {
    /// Continuous voxel indices (the VerSe data sets as published).
    #[default]
    Voxels,
    /// Millimetres from the first voxel's centre along each axis (index × spacing).
    Millimetres,
}

impl std::str::FromStr for VerseUnits {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "voxel" | "voxels" => Ok(VerseUnits::Voxels),
            "mm" | "millimetres" | "millimeters" => Ok(VerseUnits::Millimetres),
            _ => Err(Error::invalid(
                "verse units",
                format!("{s:?}: use voxels or mm"),
            )),
        }
    }
}

/// The grid of the image a VerSe file's coordinates refer to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageGrid {
    pub dims: [usize; 3],
    /// Voxel index → world mm (RAS+), as [`Volume::index_to_world`].
    pub index_to_world: DMat4,
}

impl ImageGrid {
    /// The grid of a CT or label map.
    pub fn of<T>(v: &Volume<T>) -> ImageGrid {
        ImageGrid {
            dims: v.dims,
            index_to_world: v.index_to_world,
        }
    }
}

/// One vertebra's centroid read from a VerSe file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VerseCentroid {
    /// The VerSe label as written (1–28).
    pub label: u16,
    /// The level it denotes.
    pub level: Level,
    /// World position (mm, RAS+): the file's coordinates mapped through the image's axes and affine.
    pub world_mm: DVec3,
    /// `X, Y, Z` as written.
    pub file_xyz: DVec3,
}

#[derive(Deserialize)]
struct Header {
    direction: Vec<String>,
    #[serde(default)]
    zoom: Option<Vec<f64>>,
    #[serde(default)]
    shape: Option<Vec<f64>>,
    #[serde(default)]
    format: Option<String>,
}

#[derive(Deserialize)]
struct Entry {
    label: serde_json::Value,
    #[serde(rename = "X")]
    x: f64,
    #[serde(rename = "Y")]
    y: f64,
    #[serde(rename = "Z")]
    z: f64,
}

/// Reads a VerSe centroid file for the image on `grid` (see the module documentation), in file order.
/// Errors name the file and the entry: a missing or malformed `direction`, axis codes that do not name
/// three distinct axes, a label outside 1–28 or given twice, a centroid outside the image.
pub fn read_verse_centroids(
    path: &Path,
    grid: &ImageGrid,
    units: VerseUnits,
) -> Result<Vec<VerseCentroid>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse_verse(&text, path, grid, units)
}

/// [`read_verse_centroids`] on a document already read; `path` names it in errors.
pub fn parse_verse(
    text: &str,
    path: &Path,
    grid: &ImageGrid,
    units: VerseUnits,
) -> Result<Vec<VerseCentroid>> {
    let bad = |msg: String| Error::format(path, msg);
    let list: Vec<serde_json::Value> =
        serde_json::from_str(text).map_err(|e| bad(format!("VerSe centroid JSON: {e}")))?;
    let Some((head, entries)) = list.split_first() else {
        return Err(bad("VerSe centroids: the list is empty".into()));
    };
    let header: Header = serde_json::from_value(head.clone()).map_err(|e| {
        bad(format!(
            "[0]: expected the header {{\"direction\": [\"P\", \"I\", \"R\"]}}: {e}"
        ))
    })?;
    if let Some(f) = header.format.as_deref()
        && f != "docker"
    {
        return Err(bad(format!(
            "[0].format: {f:?} is not the VerSe centroid list (format \"docker\")"
        )));
    }
    let axes =
        StatedAxes::new(&header.direction, grid).map_err(|m| bad(format!("[0].direction: {m}")))?;
    axes.check_header(&header).map_err(bad)?;
    let mut out: Vec<VerseCentroid> = Vec::with_capacity(entries.len());
    for (i, v) in entries.iter().enumerate() {
        let at = i + 1;
        let e: Entry = serde_json::from_value(v.clone()).map_err(|e| {
            bad(format!(
                "[{at}]: expected {{\"label\": n, \"X\": x, \"Y\": y, \"Z\": z}}: {e}"
            ))
        })?;
        let label = e
            .label
            .as_u64()
            .and_then(|l| u16::try_from(l).ok())
            .ok_or_else(|| bad(format!("[{at}].label: {} is not an integer label", e.label)))?;
        let level = LabelConvention::Verse.level(label).ok_or_else(|| {
            bad(format!(
                "[{at}].label: {label} is not a VerSe vertebra label (1–28)"
            ))
        })?;
        if out.iter().any(|c| c.label == label) {
            return Err(bad(format!(
                "[{at}].label: {label} ({level}) appears twice"
            )));
        }
        let file_xyz = DVec3::new(e.x, e.y, e.z);
        if !file_xyz.is_finite() {
            return Err(bad(format!(
                "[{at}]: label {label} ({level}) is not finite"
            )));
        }
        let index = axes.image_index(file_xyz, units);
        let n = grid.dims.map(|d| d as f64);
        if (0..3).any(|j| index[j] < -0.5 || index[j] > n[j] - 0.5) {
            return Err(bad(format!(
                "[{at}]: label {label} ({level}) at {file_xyz:?} lies outside the {:?} image (voxel \
                 index {:.1?}); the coordinates are {} of the image the centroids were made on",
                grid.dims,
                index.to_array(),
                match units {
                    VerseUnits::Voxels => "voxels (give mm if the file was rescaled)",
                    VerseUnits::Millimetres => "millimetres",
                }
            )));
        }
        out.push(VerseCentroid {
            label,
            level,
            world_mm: grid.index_to_world.transform_point3(index),
            file_xyz,
        });
    }
    if out.is_empty() {
        return Err(bad("VerSe centroids: no vertebra after the header".into()));
    }
    Ok(out)
}

/// Fails (naming the file and the entry) when a centroid's level has no label in `seg` under
/// `convention`: the centroids and the label map disagree about which vertebrae the image shows.
pub fn check_levels_in(
    centroids: &[VerseCentroid],
    seg: &LabelMap,
    convention: LabelConvention,
    path: &Path,
) -> Result<()> {
    let present = seg.labels_present();
    for c in centroids {
        let id = convention.id(c.level);
        if !id.is_some_and(|id| present.contains(&id)) {
            return Err(Error::format(
                path,
                format!(
                    "label {} names level {}, which {} the label map (labels present: {present:?})",
                    c.label,
                    c.level,
                    match id {
                        Some(id) =>
                            format!("(label {id} in the {convention} convention) is not in"),
                        None => format!("has no id in the {convention} convention of"),
                    }
                ),
            ));
        }
    }
    Ok(())
}

/// One landmark set per centroid: level name, one `center` landmark.
pub fn centroids_to_landmarks(centroids: &[VerseCentroid]) -> Vec<Landmarks> {
    centroids
        .iter()
        .map(|c| Landmarks {
            level: c.level.to_string(),
            points: [("center".to_string(), c.world_mm)].into_iter().collect(),
        })
        .collect()
}

/// World axis (0 = x R–L, 1 = y A–P, 2 = z S–I) and sign of one nibabel axis code.
fn parse_code(c: &str) -> Option<(usize, f64)> {
    match c.trim().to_ascii_uppercase().as_str() {
        "R" => Some((0, 1.0)),
        "L" => Some((0, -1.0)),
        "A" => Some((1, 1.0)),
        "P" => Some((1, -1.0)),
        "S" => Some((2, 1.0)),
        "I" => Some((2, -1.0)),
        _ => None,
    }
}

/// The image's own codes: index axis `j` runs along world axis `axis[j]` with sign `sign[j]` (the
/// assignment maximising the summed |direction cosines|, so a slightly oblique scan keeps its codes).
fn image_codes(m: &DMat4) -> ([usize; 3], [f64; 3]) {
    let cols = [m.x_axis, m.y_axis, m.z_axis].map(|c| c.truncate().normalize_or_zero());
    const PERMS: [[usize; 3]; 6] = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    let score = |p: &[usize; 3]| (0..3).map(|j| cols[j][p[j]].abs()).sum::<f64>();
    let best = PERMS
        .iter()
        .copied()
        .max_by(|a, b| score(a).total_cmp(&score(b)))
        .unwrap_or([0, 1, 2]);
    let sign = [0, 1, 2].map(|j| if cols[j][best[j]] < 0.0 { -1.0 } else { 1.0 });
    (best, sign)
}

/// How the file's three axes map onto the image's index axes.
struct StatedAxes {
    /// Stated axis `a` is image index axis `to_image[a]` …
    to_image: [usize; 3],
    /// … running the same way (`false`) or flipped (`true`).
    flipped: [bool; 3],
    spacing: [f64; 3],
    dims: [usize; 3],
}

impl StatedAxes {
    fn new(codes: &[String], grid: &ImageGrid) -> std::result::Result<StatedAxes, String> {
        if codes.len() != 3 {
            return Err(format!(
                "{} axis codes, expected 3 (e.g. P, I, R)",
                codes.len()
            ));
        }
        let parsed: Vec<(usize, f64)> = codes
            .iter()
            .map(|c| parse_code(c).ok_or_else(|| format!("{c:?} is not one of R, L, A, P, S, I")))
            .collect::<std::result::Result<_, _>>()?;
        let mut seen = [false; 3];
        for &(k, _) in &parsed {
            if std::mem::replace(&mut seen[k], true) {
                return Err(format!("{codes:?} names one body axis twice"));
            }
        }
        let (axis, sign) = image_codes(&grid.index_to_world);
        let m = grid.index_to_world;
        let len = [m.x_axis, m.y_axis, m.z_axis].map(|c| c.truncate().length());
        let mut to_image = [0; 3];
        let mut flipped = [false; 3];
        for (a, &(k, s)) in parsed.iter().enumerate() {
            let j = (0..3).find(|&j| axis[j] == k).unwrap_or(a);
            to_image[a] = j;
            flipped[a] = sign[j] != s;
        }
        Ok(StatedAxes {
            to_image,
            flipped,
            spacing: to_image.map(|j| len[j]),
            dims: to_image.map(|j| grid.dims[j]),
        })
    }

    /// `zoom` and `shape` of the header, when present, must be the reoriented image's.
    fn check_header(&self, h: &Header) -> std::result::Result<(), String> {
        if let Some(z) = &h.zoom {
            let ok = z.len() == 3
                && (0..3).all(|a| (z[a] - self.spacing[a]).abs() <= 0.01 * self.spacing[a]);
            if !ok {
                return Err(format!(
                    "[0].zoom: {z:?} is not the image's spacing along the stated axes ({:?} mm)",
                    self.spacing
                ));
            }
        }
        if let Some(s) = &h.shape {
            let ok = s.len() == 3 && (0..3).all(|a| s[a] == self.dims[a] as f64);
            if !ok {
                return Err(format!(
                    "[0].shape: {s:?} is not the image's size along the stated axes ({:?})",
                    self.dims
                ));
            }
        }
        Ok(())
    }

    /// The continuous index in the image of file coordinates `c`.
    fn image_index(&self, c: DVec3, units: VerseUnits) -> DVec3 {
        let mut index = DVec3::ZERO;
        for a in 0..3 {
            let u = match units {
                VerseUnits::Voxels => c[a],
                VerseUnits::Millimetres => c[a] / self.spacing[a],
            };
            let n = self.dims[a] as f64;
            index[self.to_image[a]] = if self.flipped[a] { n - 1.0 - u } else { u };
        }
        index
    }
}
