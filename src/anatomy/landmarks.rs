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
//! `units` must be `"mm"`; `frame` is free text (the phantom writes `"world RAS+"`) and is kept on reading.
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

#[derive(Serialize, Deserialize)]
struct LevelJson {
    level: String,
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

fn default_frame() -> String {
    "world RAS+".to_string()
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
            if l.units != "mm" {
                return Err(Error::format(
                    path,
                    format!(
                        "level {}: units {:?} (only \"mm\" is supported)",
                        l.level, l.units
                    ),
                ));
            }
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
                    .map(|(k, v)| (k, DVec3::from_array(v)))
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
    fn wrong_units_name_the_file() {
        let bad = r#"{"level":"L3","units":"cm","landmarks":{}}"#;
        let e = landmarks_from_json(bad, Path::new("lm.json")).unwrap_err();
        assert!(e.to_string().contains("lm.json") && e.to_string().contains("cm"));
    }
}
