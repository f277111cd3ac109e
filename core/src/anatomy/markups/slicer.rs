//! 3D Slicer markups files (`.mrk.json`, schema `markups-schema-v1.0.3.json` of
//! `Modules/Loadable/Markups/Resources/Schema/` in the Slicer repository).
//!
//! The parts we read: `{"@schema": …, "markups": [{"type": "Fiducial", "name": "L3", "coordinateSystem":
//! "LPS" | "RAS", "coordinateUnits": "mm" | "um" | ["mm", "UCUM", "millimeter"], "controlPoints": [{"label":
//! "center", "position": [x, y, z], "positionStatus": "defined" | "preview" | "undefined"}, …]}, …]}`.
//! Everything else (display, orientation, measurements) is ignored.
//!
//! * **Coordinates.** Slicer's own world is RAS, but its files default to LPS (the schema's default, and what
//!   Slicer ≥ 5 writes): an LPS position `(x, y, z)` is the RAS point `(−x, −y, z)`. A missing
//!   `coordinateSystem` therefore means LPS; any value other than `LPS`/`RAS` is an error naming the markup.
//!   `um` positions are divided by 1000.
//! * **Levels.** Each markup node is one landmark set whose level is the node's `name`; a control point
//!   label `LEVEL/name` (as `spinedrr compare` names landmarks of several levels) puts that point in level
//!   `LEVEL` instead. Points whose `positionStatus` is `undefined` carry no position and are skipped.
//! * **Writing** puts each level in its own `Fiducial` node named after the level, one control point per
//!   landmark labelled with its name, in LPS millimetres (Slicer's default, so the file opens unchanged).

use std::collections::BTreeMap;
use std::path::Path;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::super::landmarks::Landmarks;
use crate::{Error, Result};

/// The schema URL written into `@schema`.
pub const SCHEMA_URL: &str = "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/Resources/Schema/markups-schema-v1.0.3.json#";

#[derive(Deserialize)]
struct FileIn {
    markups: Vec<MarkupIn>,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct MarkupIn {
    #[serde(default)]
    name: Option<String>,
    #[serde(default)]
    coordinate_system: Option<String>,
    #[serde(default)]
    coordinate_units: Option<serde_json::Value>,
    #[serde(default)]
    control_points: Vec<PointIn>,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct PointIn {
    #[serde(default)]
    label: Option<String>,
    #[serde(default)]
    position: Option<Vec<f64>>,
    #[serde(default)]
    position_status: Option<String>,
}

#[derive(Serialize)]
struct FileOut {
    #[serde(rename = "@schema")]
    schema: &'static str,
    markups: Vec<MarkupOut>,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct MarkupOut {
    #[serde(rename = "type")]
    kind: &'static str,
    name: String,
    coordinate_system: &'static str,
    coordinate_units: &'static str,
    control_points: Vec<PointOut>,
    display: DisplayOut,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct PointOut {
    id: String,
    label: String,
    /// [`crate::io::SLICER_DESCRIPTION`]: how a later run tells the file for spinedrr's own.
    description: &'static str,
    position: [f64; 3],
    position_status: &'static str,
}

#[derive(Serialize)]
#[serde(rename_all = "camelCase")]
struct DisplayOut {
    point_labels_visibility: bool,
}

/// The coordinate system a markup's positions are written in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum System {
    Lps,
    Ras,
}

impl System {
    /// The RAS point of a position written in this system (the map is its own inverse).
    fn to_ras(self, p: DVec3) -> DVec3 {
        match self {
            System::Ras => p,
            System::Lps => DVec3::new(-p.x, -p.y, p.z),
        }
    }
}

/// Parses a Slicer markups document; `path` names the source in errors.
pub fn parse_slicer(text: &str, path: &Path) -> Result<Vec<Landmarks>> {
    let file: FileIn = serde_json::from_str(text)
        .map_err(|e| Error::format(path, format!("Slicer markups JSON: {e}")))?;
    if file.markups.is_empty() {
        return Err(Error::format(path, "field \"markups\" holds no markup"));
    }
    let mut sets: Vec<Landmarks> = Vec::new();
    for (i, m) in file.markups.iter().enumerate() {
        let field = |f: &str| format!("markups[{i}].{f}");
        let system = match m.coordinate_system.as_deref() {
            None | Some("LPS") => System::Lps,
            Some("RAS") => System::Ras,
            Some(other) => {
                return Err(Error::format(
                    path,
                    format!(
                        "{}: {other:?} is not a coordinate system Slicer writes (LPS or RAS)",
                        field("coordinateSystem")
                    ),
                ));
            }
        };
        let scale = units_scale(m.coordinate_units.as_ref())
            .map_err(|msg| Error::format(path, format!("{}: {msg}", field("coordinateUnits"))))?;
        let node_level = m.name.clone().unwrap_or_default();
        for (j, p) in m.control_points.iter().enumerate() {
            let pfield = |f: &str| field(&format!("controlPoints[{j}].{f}"));
            match p.position_status.as_deref() {
                None | Some("defined") | Some("preview") => {}
                Some("undefined") => continue,
                Some(other) => {
                    return Err(Error::format(
                        path,
                        format!(
                            "{}: {other:?} is not defined, preview or undefined",
                            pfield("positionStatus")
                        ),
                    ));
                }
            }
            let label = p.label.as_deref().unwrap_or("").trim();
            if label.is_empty() {
                return Err(Error::format(
                    path,
                    format!("{}: a landmark needs a name", pfield("label")),
                ));
            }
            let xyz = match p.position.as_deref() {
                Some(&[x, y, z]) => DVec3::new(x, y, z),
                Some(v) => {
                    return Err(Error::format(
                        path,
                        format!("{}: {} numbers, expected 3", pfield("position"), v.len()),
                    ));
                }
                None => {
                    return Err(Error::format(
                        path,
                        format!("{}: missing for a defined point", pfield("position")),
                    ));
                }
            };
            if !xyz.is_finite() {
                return Err(Error::format(
                    path,
                    format!("{}: not finite", pfield("position")),
                ));
            }
            let (level, name) = match label.split_once('/') {
                Some((l, n)) if !l.is_empty() && !n.is_empty() => (l.to_string(), n.to_string()),
                _ => (node_level.clone(), label.to_string()),
            };
            let k = match sets.iter().position(|s| s.level == level) {
                Some(k) => k,
                None => {
                    sets.push(Landmarks {
                        level: level.clone(),
                        points: BTreeMap::new(),
                    });
                    sets.len() - 1
                }
            };
            if sets[k].points.contains_key(&name) {
                return Err(Error::format(
                    path,
                    format!(
                        "{}: landmark {name:?} of level {level:?} appears twice",
                        pfield("label")
                    ),
                ));
            }
            sets[k].points.insert(name, system.to_ras(xyz * scale));
        }
    }
    if sets.iter().all(|s| s.points.is_empty()) {
        return Err(Error::format(
            path,
            "the markups hold no defined control point",
        ));
    }
    Ok(sets)
}

/// Millimetres per file unit from `coordinateUnits` (absent = mm).
fn units_scale(v: Option<&serde_json::Value>) -> std::result::Result<f64, String> {
    let code = match v {
        None => return Ok(1.0),
        Some(serde_json::Value::String(s)) => s.as_str(),
        Some(serde_json::Value::Array(a)) => a.first().and_then(|c| c.as_str()).unwrap_or(""),
        Some(other) => return Err(format!("{other} is neither a unit code nor a code triple")),
    };
    match code {
        "mm" => Ok(1.0),
        "um" => Ok(1e-3),
        other => Err(format!(
            "unit {other:?} (only \"mm\" and \"um\" are defined)"
        )),
    }
}

/// Serialises landmark sets as a Slicer markups document (one `Fiducial` node per level, LPS mm).
pub fn slicer_to_json(sets: &[Landmarks]) -> Result<String> {
    let markups = sets
        .iter()
        .map(|s| MarkupOut {
            kind: "Fiducial",
            name: s.level.clone(),
            coordinate_system: "LPS",
            coordinate_units: "mm",
            control_points: s
                .points
                .iter()
                .enumerate()
                .map(|(i, (name, p))| PointOut {
                    id: (i + 1).to_string(),
                    label: name.clone(),
                    description: crate::io::SLICER_DESCRIPTION,
                    position: System::Lps.to_ras(*p).to_array(),
                    position_status: "defined",
                })
                .collect(),
            display: DisplayOut {
                point_labels_visibility: true,
            },
        })
        .collect();
    let file = FileOut {
        schema: SCHEMA_URL,
        markups,
    };
    serde_json::to_string_pretty(&file).map_err(|e| Error::invalid("landmarks", e.to_string()))
}
