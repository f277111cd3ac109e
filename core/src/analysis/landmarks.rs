//! Landmark displacement between a reference and a perturbed projection, with the analytic
//! prediction of the homography law `x' = H x`, `H = K' K⁻¹`, beside it; and blob centroids for
//! measuring landmark positions in rendered images.

use std::collections::BTreeMap;
use std::path::Path;

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

use crate::geometry::{View, apply_homography};
use crate::io::ImageF32;
use crate::{Error, Result};

/// A named 3D landmark (world mm).
#[derive(Debug, Clone, PartialEq)]
pub struct Landmark {
    pub name: String,
    pub position: DVec3,
}

/// One landmark's projection under both calibrations.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LandmarkShift {
    pub name: String,
    pub reference_px: [f64; 2],
    pub perturbed_px: [f64; 2],
    /// `e_2D = ‖x_gt − x_err‖` (the paper's landmark projection error).
    pub shift_px: f64,
    /// `H x_gt` with `H = K' K⁻¹`; NaN (JSON `null`) when the two views differ in pose (a physical
    /// perturbation moved the source or the detector), where no homography maps one image to the other.
    pub predicted_px: [f64; 2],
    /// `‖H x_gt − x_gt‖`; NaN when the views differ in pose.
    pub predicted_shift_px: f64,
}

/// Projects every landmark through both views and sets the homography prediction beside the
/// measurement (they agree when the two views share the source and orientation; when they do not, the
/// prediction is NaN: parallax makes the shift depend on each landmark's depth).
pub fn landmark_shifts(
    reference: &View,
    perturbed: &View,
    landmarks: &[Landmark],
) -> Vec<LandmarkShift> {
    let h = if reference.same_pose(perturbed) {
        reference.homography_to(perturbed)
    } else {
        glam::DMat3::from_cols_array(&[f64::NAN; 9])
    };
    landmarks
        .iter()
        .map(|l| {
            let x = reference.project(l.position);
            let y = perturbed.project(l.position);
            let p = apply_homography(&h, x);
            LandmarkShift {
                name: l.name.clone(),
                reference_px: x.to_array(),
                perturbed_px: y.to_array(),
                shift_px: (y - x).length(),
                predicted_px: p.to_array(),
                predicted_shift_px: (p - x).length(),
            }
        })
        .collect()
}

/// Intensity-weighted centroid `Σ I(u,v) (u,v) / Σ I(u,v)` of the pixels within `radius_px` of
/// `centre_guess` (pixel centres at integers; negative and non-finite values count as 0). `None` when
/// the disc holds no positive intensity.
pub fn blob_centroid(img: &ImageF32, centre_guess: DVec2, radius_px: f64) -> Option<DVec2> {
    if !(centre_guess.is_finite() && radius_px.is_finite() && radius_px > 0.0) {
        return None;
    }
    let (w, h) = (f64::from(img.width), f64::from(img.height));
    let u0 = (centre_guess.x - radius_px).floor().max(0.0);
    let u1 = (centre_guess.x + radius_px).ceil().min(w - 1.0);
    let v0 = (centre_guess.y - radius_px).floor().max(0.0);
    let v1 = (centre_guess.y + radius_px).ceil().min(h - 1.0);
    if u0 > u1 || v0 > v1 {
        return None;
    }
    let (mut sum, mut acc) = (0.0, DVec2::ZERO);
    for v in v0 as u32..=v1 as u32 {
        for u in u0 as u32..=u1 as u32 {
            let p = DVec2::new(f64::from(u), f64::from(v));
            let i = f64::from(img.get(u, v));
            if (p - centre_guess).length() <= radius_px && i.is_finite() && i > 0.0 {
                sum += i;
                acc += i * p;
            }
        }
    }
    (sum > 0.0).then(|| acc / sum)
}

#[derive(Deserialize)]
struct LandmarkSet {
    #[serde(default)]
    level: Option<String>,
    /// Length unit of the coordinates (default mm), see [`crate::anatomy::landmarks::to_world_mm`].
    #[serde(default)]
    units: Option<String>,
    /// World frame of the coordinates (default RAS+).
    #[serde(default)]
    frame: Option<String>,
    landmarks: BTreeMap<String, [f64; 3]>,
}

/// What kind of JSON value `v` is, in words.
fn json_kind(v: &serde_json::Value) -> &'static str {
    match v {
        serde_json::Value::Null => "null",
        serde_json::Value::Bool(_) => "a boolean",
        serde_json::Value::Number(_) => "a number",
        serde_json::Value::String(_) => "a string",
        serde_json::Value::Array(_) => "an array",
        serde_json::Value::Object(_) => "an object",
    }
}

/// Parses landmark JSON: `{"landmarks": {"name": [x, y, z], …}}` with optional `level`, `units` and
/// `frame` (converted to world mm RAS+; an unknown unit or a non-world frame is refused), or an array
/// of such objects, whose names are then prefixed `LEVEL/` when a level is given.
pub fn parse_landmarks(text: &str, origin: &str) -> Result<Vec<Landmark>> {
    const EXPECTED: &str =
        "expected {\"landmarks\": {\"name\": [x, y, z]}} or an array of such objects";
    let value: serde_json::Value = serde_json::from_str(text)
        .map_err(|e| Error::format(origin, format!("not JSON ({e}); {EXPECTED}")))?;
    // One object, or an array of them: each parsed on its own, so an error says which and why.
    let set = |v: &serde_json::Value, which: &str| -> Result<LandmarkSet> {
        if !v.is_object() {
            return Err(Error::format(
                origin,
                format!("{which} is {}, not an object; {EXPECTED}", json_kind(v)),
            ));
        }
        LandmarkSet::deserialize(v)
            .map_err(|e| Error::format(origin, format!("{which}: {e}; {EXPECTED}")))
    };
    let (sets, prefix) = match &value {
        serde_json::Value::Array(items) => (
            items
                .iter()
                .enumerate()
                .map(|(i, v)| set(v, &format!("entry {i} of the array")))
                .collect::<Result<Vec<_>>>()?,
            true,
        ),
        v => (vec![set(v, "the file")?], false),
    };
    let mut out = Vec::new();
    for set in sets {
        let to_world =
            crate::anatomy::landmarks::to_world_mm(set.units.as_deref(), set.frame.as_deref())
                .map_err(|e| {
                    let which = set
                        .level
                        .as_ref()
                        .map_or(String::new(), |l| format!("level {l}: "));
                    Error::format(origin, format!("{which}{e}"))
                })?;
        for (name, p) in set.landmarks {
            let name = match (&set.level, prefix) {
                (Some(level), true) => format!("{level}/{name}"),
                _ => name,
            };
            let position = DVec3::from(p) * to_world;
            if !position.is_finite() {
                return Err(Error::format(
                    origin,
                    format!("landmark '{name}' is not finite"),
                ));
            }
            out.push(Landmark { name, position });
        }
    }
    if out.is_empty() {
        return Err(Error::format(origin, "no landmarks"));
    }
    Ok(out)
}

/// Reads a landmark file: our JSON (see [`parse_landmarks`]) or 3D Slicer markups, whose sets are named
/// as [`parse_landmarks`] names them (`LEVEL/name` when the file holds several levels). A VerSe centroid
/// file is refused: its voxel coordinates need the image it was made on.
pub fn read_landmarks(path: &Path) -> Result<Vec<Landmark>> {
    use crate::anatomy::markups::{LandmarkContext, LandmarkFormat, parse_landmarks_with};
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    if LandmarkFormat::detect(&text, path)? == LandmarkFormat::Spinedrr {
        return parse_landmarks(&text, &path.display().to_string());
    }
    let sets = parse_landmarks_with(&text, path, &LandmarkContext::default())?;
    let prefix = sets.len() > 1;
    Ok(sets
        .into_iter()
        .flat_map(|s| {
            s.points.into_iter().map(move |(name, position)| Landmark {
                name: if prefix {
                    format!("{}/{name}", s.level)
                } else {
                    name
                },
                position,
            })
        })
        .collect())
}
