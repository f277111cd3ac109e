//! Named 3D landmarks per vertebral level and their JSON file.
//!
//! File format (one file holds any number of levels; a single level object is accepted on reading):
//!
//! ```json
//! [
//!   {"level": "L3", "units": "mm", "frame": "world RAS+",
//!    "landmarks": {"center": [0.0, 0.0, 0.0], "spinous_tip": [0.0, -64.0, -6.0]}},
//!   {"level": "L4", "units": "mm", "frame": "world RAS+", "landmarks": {...}}
//! ]
//! ```
//!
//! `units` is `"mm"` (the default), `"cm"`, `"m"` or `"um"`; `frame` is `"world RAS+"` (the default; also
//! written `"RAS"`, `"RAS+"`, `"world RAS"`) or `"world LPS+"` (`"LPS"`, …, DICOM's and ITK's patient
//! frame: x and y negated). Both are converted to world mm RAS+ on reading ([`to_world_mm`]); anything
//! else (a voxel or camera frame, an unknown unit) is refused, naming the value.
//!
//! Files are read and written through [`crate::anatomy::markups`], which also speaks 3D Slicer markups
//! and VerSe centroids; this module is our own format.

use std::collections::BTreeMap;
use std::path::Path;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// The landmarks of one level, world millimetres.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Landmarks {
    pub level: String,
    pub points: BTreeMap<String, DVec3>,
}

impl Landmarks {
    /// The points of several sets as one named list, each name prefixed with its level (`L2/center`)
    /// when `prefix_level` (sets of several levels share names).
    pub fn named_points(sets: Vec<Landmarks>, prefix_level: bool) -> Vec<(String, DVec3)> {
        let mut out = Vec::new();
        for set in sets {
            for (n, &p) in &set.points {
                let full = if prefix_level {
                    format!("{}/{n}", set.level)
                } else {
                    n.clone()
                };
                out.push((full, p));
            }
        }
        out
    }
}

#[derive(Serialize, Deserialize)]
struct LevelJson {
    /// `spinedrr` in a file spinedrr wrote ([`crate::io::TOOL`]): what lets a later run replace it and
    /// never a hand-placed file ([`crate::io::check_ours`]); absent in the user's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    tool: Option<String>,
    level: String,
    #[serde(default = "default_units")]
    units: String,
    #[serde(default = "default_frame")]
    frame: String,
    #[serde(deserialize_with = "unique_keys")]
    landmarks: BTreeMap<String, [f64; 3]>,
}

/// Deserialises a JSON object into a map, refusing a key that appears twice (serde's maps keep the last
/// value silently). Use with `#[serde(deserialize_with = "unique_keys")]`.
pub fn unique_keys<'de, D, V>(d: D) -> std::result::Result<BTreeMap<String, V>, D::Error>
where
    D: serde::Deserializer<'de>,
    V: Deserialize<'de>,
{
    struct Unique<V>(std::marker::PhantomData<V>);
    impl<'de, V: Deserialize<'de>> serde::de::Visitor<'de> for Unique<V> {
        type Value = BTreeMap<String, V>;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("an object with distinct keys")
        }
        fn visit_map<A: serde::de::MapAccess<'de>>(
            self,
            mut access: A,
        ) -> std::result::Result<Self::Value, A::Error> {
            let mut map = BTreeMap::new();
            while let Some((k, v)) = access.next_entry::<String, V>()? {
                if map.contains_key(&k) {
                    return Err(serde::de::Error::custom(format!(
                        "key \"{k}\" appears twice in one object"
                    )));
                }
                map.insert(k, v);
            }
            Ok(map)
        }
    }
    d.deserialize_map(Unique(std::marker::PhantomData))
}

fn default_units() -> String {
    "mm".to_string()
}

fn default_frame() -> String {
    "world RAS+".to_string()
}

/// How a landmark file's `units` and `frame` map its coordinates to world mm RAS+: the scale (mm per
/// unit) and the axis signs (LPS+ → RAS+ negates x and y). `None` means the default (mm, RAS+). An
/// error names the value and what is accepted.
pub fn to_world_mm(units: Option<&str>, frame: Option<&str>) -> std::result::Result<DVec3, String> {
    let scale = match units.map(str::trim) {
        None | Some("mm") => 1.0,
        Some("cm") => 10.0,
        Some("m") => 1000.0,
        Some("um" | "µm" | "μm") => 1e-3,
        Some(u) => {
            return Err(format!(
                "units {u:?}: give \"mm\", \"cm\", \"m\" or \"um\" (lengths in the world frame)"
            ));
        }
    };
    let frame_key = frame.map(|f| {
        f.trim()
            .trim_start_matches("world")
            .trim()
            .trim_end_matches('+')
            .to_ascii_uppercase()
    });
    let signs = match frame_key.as_deref() {
        None | Some("RAS") => DVec3::ONE,
        Some("LPS") => DVec3::new(-1.0, -1.0, 1.0),
        Some(_) => {
            return Err(format!(
                "frame {:?}: landmarks are world coordinates, \"world RAS+\" or \"world LPS+\" (not voxel \
                 indices or a camera frame)",
                frame.unwrap_or_default()
            ));
        }
    };
    Ok(signs * scale)
}

impl Landmarks {
    /// A landmark by name.
    pub fn get(&self, name: &str) -> Option<DVec3> {
        self.points.get(name).copied()
    }
}

/// Serialises landmark sets in the file format above.
pub fn landmarks_to_json(sets: &[Landmarks]) -> Result<String> {
    let list: Vec<LevelJson> = sets
        .iter()
        .map(|l| LevelJson {
            tool: Some(crate::io::TOOL.into()),
            level: l.level.clone(),
            units: "mm".into(),
            frame: default_frame(),
            landmarks: l
                .points
                .iter()
                .map(|(k, v)| (k.clone(), v.to_array()))
                .collect(),
        })
        .collect();
    serde_json::to_string_pretty(&list).map_err(|e| Error::invalid("landmarks", e.to_string()))
}

/// Parses the file format above; `path` names the source in errors.
pub fn landmarks_from_json(text: &str, path: &Path) -> Result<Vec<Landmarks>> {
    let bad = |e: serde_json::Error| Error::format(path, format!("landmarks JSON: {e}"));
    // An array of levels or one level, told apart by the first character so the inner error (and the
    // duplicate-key check, which a `serde_json::Value` would lose) reaches the user.
    let list: Vec<LevelJson> = if text.trim_start().starts_with('[') {
        serde_json::from_str(text).map_err(bad)?
    } else {
        vec![serde_json::from_str(text).map_err(bad)?]
    };
    if list.is_empty() {
        return Err(Error::format(path, "the landmarks file holds no level"));
    }
    for (i, l) in list.iter().enumerate() {
        if list[..i].iter().any(|m| m.level == l.level) {
            return Err(Error::format(
                path,
                format!("level {:?} appears twice: give each level once", l.level),
            ));
        }
    }
    list.into_iter()
        .map(|l| {
            let to_world = to_world_mm(Some(&l.units), Some(&l.frame))
                .map_err(|e| Error::format(path, format!("level {}: {e}", l.level)))?;
            if let Some((k, _)) = l
                .landmarks
                .iter()
                .find(|(_, v)| v.iter().any(|c| !c.is_finite()))
            {
                return Err(Error::format(
                    path,
                    format!("level {}: landmark {k} is not finite", l.level),
                ));
            }
            Ok(Landmarks {
                level: l.level,
                points: l
                    .landmarks
                    .into_iter()
                    .map(|(k, v)| (k, DVec3::from_array(v) * to_world))
                    .collect(),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_round_trip_and_single_object() {
        let mut l = Landmarks {
            level: "L3".into(),
            ..Default::default()
        };
        l.points
            .insert("center".into(), DVec3::new(1.0, -2.5, 3.25));
        let text = landmarks_to_json(std::slice::from_ref(&l)).unwrap();
        let back = landmarks_from_json(&text, Path::new("x.json")).unwrap();
        assert_eq!(back, vec![l.clone()]);
        let one = r#"{"level":"L3","units":"mm","landmarks":{"center":[1.0,-2.5,3.25]}}"#;
        assert_eq!(
            landmarks_from_json(one, Path::new("y.json")).unwrap(),
            vec![l]
        );
    }

    #[test]
    fn repeated_names_and_empty_files_are_refused() {
        let twice = r#"{"level":"L3","units":"mm","landmarks":{"a":[0,0,0],"a":[1,1,1]}}"#;
        let e = landmarks_from_json(twice, Path::new("lm.json")).unwrap_err();
        assert!(e.to_string().contains("\"a\" appears twice"), "{e}");
        let l3 = r#"{"level":"L3","units":"mm","landmarks":{"a":[0,0,0]}}"#;
        let e = landmarks_from_json(&format!("[{l3},{l3}]"), Path::new("lm.json")).unwrap_err();
        assert!(e.to_string().contains("\"L3\" appears twice"), "{e}");
        let e = landmarks_from_json("[]", Path::new("lm.json")).unwrap_err();
        assert!(e.to_string().contains("lm.json") && e.to_string().contains("no level"));
    }

    #[test]
    fn wrong_units_or_frames_name_the_file_and_the_value() {
        for (units, frame, word) in [
            ("inch", "world RAS+", "inch"),
            ("mm", "voxel IJK", "voxel IJK"),
            ("mm", "camera", "camera"),
        ] {
            let bad =
                format!(r#"{{"level":"L3","units":"{units}","frame":"{frame}","landmarks":{{}}}}"#);
            let e = landmarks_from_json(&bad, Path::new("lm.json")).unwrap_err();
            let e = e.to_string();
            assert!(
                e.contains("lm.json") && e.contains(word) && e.contains("L3"),
                "{e}"
            );
        }
    }

    /// Other units and LPS+ coordinates come back as world mm RAS+: 1.5 cm is 15 mm; LPS+ (x, y, z) is
    /// RAS+ (−x, −y, z).
    #[test]
    fn units_and_lps_frames_are_converted_to_world_mm_ras() {
        let read = |units: &str, frame: &str| {
            let text = format!(
                r#"{{"level":"L3","units":"{units}","frame":"{frame}","landmarks":{{"a":[1.5,-2,3]}}}}"#
            );
            landmarks_from_json(&text, Path::new("lm.json")).unwrap()[0].points["a"]
        };
        assert_eq!(read("mm", "world RAS+"), DVec3::new(1.5, -2.0, 3.0));
        assert_eq!(read("cm", "RAS"), DVec3::new(15.0, -20.0, 30.0));
        assert_eq!(read("m", "world RAS"), DVec3::new(1500.0, -2000.0, 3000.0));
        assert_eq!(read("mm", "world LPS+"), DVec3::new(-1.5, 2.0, 3.0));
        assert_eq!(read("um", "LPS"), DVec3::new(-0.0015, 0.002, 0.003));
        // Without units or frame: mm, RAS+.
        let bare = r#"{"level":"L3","landmarks":{"a":[1.5,-2,3]}}"#;
        let p = landmarks_from_json(bare, Path::new("lm.json")).unwrap()[0].points["a"];
        assert_eq!(p, DVec3::new(1.5, -2.0, 3.0));
    }
}
