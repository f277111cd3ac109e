//! Landmark files in the formats users have, behind one reader and one writer.
//!
//! * **spinedrr** landmark JSON ([`crate::anatomy::landmarks`]): level sets in world RAS+ mm;
//! * **3D Slicer markups** (`.mrk.json`, [`slicer`]): LPS or RAS, one markup node per level;
//! * **VerSe centroids** (`*_ctd.json`, [`verse`], read only): voxel coordinates of an image, so they need
//!   that image's grid ([`LandmarkContext::seg`]).
//!
//! [`read_landmarks`] chooses by content, falling back on the name: a JSON object with a `markups` key
//! (or a name ending `.mrk.json`) is Slicer, a list whose first element has a `direction` key is VerSe,
//! anything else our own format. [`write_landmarks`] chooses by name (`.mrk.json` → Slicer).

pub mod slicer;
pub mod verse;

use std::path::Path;

use serde::Deserialize;

use super::ct::LabelMap;
use super::labels::LabelConvention;
use super::landmarks::{Landmarks, landmarks_from_json, landmarks_to_json, unique_keys};
use crate::{Error, Result};

pub use slicer::{parse_slicer, slicer_to_json};
pub use verse::{
    ImageGrid, VerseCentroid, VerseUnits, check_levels_in, parse_verse, read_verse_centroids,
};

/// A landmark file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LandmarkFormat {
    /// Our landmark JSON.
    Spinedrr,
    /// 3D Slicer markups JSON.
    Slicer,
    /// VerSe centroid JSON (read only).
    Verse,
}

impl std::str::FromStr for LandmarkFormat {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "spinedrr" | "json" => Ok(LandmarkFormat::Spinedrr),
            "slicer" | "mrk" | "mrk.json" => Ok(LandmarkFormat::Slicer),
            "verse" => Ok(LandmarkFormat::Verse),
            _ => Err(Error::invalid(
                "landmarks format",
                format!("{s:?}: use spinedrr, slicer or verse"),
            )),
        }
    }
}

/// True for a name ending `.mrk.json` (any case).
pub fn is_slicer_name(path: &Path) -> bool {
    path.file_name()
        .map(|n| {
            n.to_string_lossy()
                .to_ascii_lowercase()
                .ends_with(".mrk.json")
        })
        .unwrap_or(false)
}

impl LandmarkFormat {
    /// The format of a document (see the module documentation); `path` breaks no tie but names the
    /// source in the error when the text is not JSON.
    pub fn detect(text: &str, path: &Path) -> Result<LandmarkFormat> {
        let v: serde_json::Value = serde_json::from_str(text)
            .map_err(|e| Error::format(path, format!("landmarks file is not JSON: {e}")))?;
        Ok(match &v {
            serde_json::Value::Object(o) if o.contains_key("markups") => LandmarkFormat::Slicer,
            serde_json::Value::Array(a)
                if a.first()
                    .and_then(|f| f.as_object())
                    .is_some_and(|f| f.contains_key("direction")) =>
            {
                LandmarkFormat::Verse
            }
            _ if is_slicer_name(path) => LandmarkFormat::Slicer,
            _ => LandmarkFormat::Spinedrr,
        })
    }

    /// The format a file of this name is written in.
    pub fn for_output(path: &Path) -> LandmarkFormat {
        if is_slicer_name(path) {
            LandmarkFormat::Slicer
        } else {
            LandmarkFormat::Spinedrr
        }
    }
}

/// What a landmark file may need besides its bytes.
#[derive(Debug, Clone, Copy, Default)]
pub struct LandmarkContext<'a> {
    /// The label map (and its convention) the landmarks belong to. VerSe centroids are voxel
    /// coordinates of its grid, and each of their levels must be a label present in it.
    pub seg: Option<(&'a LabelMap, LabelConvention)>,
    /// How VerSe coordinates are measured.
    pub verse_units: VerseUnits,
}

/// Reads a landmark file in any supported format (no image: a VerSe file is refused with the reason).
pub fn read_landmarks(path: &Path) -> Result<Vec<Landmarks>> {
    read_landmarks_with(path, &LandmarkContext::default())
}

/// Reads a landmark file in any supported format, world RAS+ mm.
pub fn read_landmarks_with(path: &Path, ctx: &LandmarkContext) -> Result<Vec<Landmarks>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse_landmarks_with(&text, path, ctx)
}

/// [`read_landmarks_with`] on a document already read; `path` names it in errors.
pub fn parse_landmarks_with(
    text: &str,
    path: &Path,
    ctx: &LandmarkContext,
) -> Result<Vec<Landmarks>> {
    match LandmarkFormat::detect(text, path)? {
        LandmarkFormat::Spinedrr => landmarks_from_json(text, path),
        LandmarkFormat::Slicer => {
            check_unique_keys(text, path)?;
            parse_slicer(text, path)
        }
        LandmarkFormat::Verse => {
            let Some((seg, conv)) = ctx.seg else {
                return Err(Error::format(
                    path,
                    "a VerSe centroid file is in voxel coordinates of its image; it can be read only \
                     beside that image's label map (a study's [[anatomy.ct]] entry with `seg`)",
                ));
            };
            check_unique_keys(text, path)?;
            let c = parse_verse(text, path, &ImageGrid::of(seg), ctx.verse_units)?;
            check_levels_in(&c, seg, conv, path)?;
            Ok(verse::centroids_to_landmarks(&c))
        }
    }
}

/// Writes `sets` to `path` (atomically) in the format its name asks for (see
/// [`LandmarkFormat::for_output`]).
pub fn write_landmarks(path: &Path, sets: &[Landmarks]) -> Result<()> {
    write_landmarks_as(path, sets, LandmarkFormat::for_output(path))
}

/// Writes `sets` to `path` (atomically) in `format`.
pub fn write_landmarks_as(path: &Path, sets: &[Landmarks], format: LandmarkFormat) -> Result<()> {
    let text = match format {
        LandmarkFormat::Spinedrr => landmarks_to_json(sets)?,
        LandmarkFormat::Slicer => slicer_to_json(sets)?,
        LandmarkFormat::Verse => {
            return Err(Error::invalid(
                "landmarks format",
                "VerSe centroid files are read, not written (write slicer or spinedrr)",
            ));
        }
    };
    crate::io::write_atomic_bytes(path, text.as_bytes())?;
    Ok(())
}

/// Refuses a key repeated inside any JSON object of the document (serde keeps the last silently), so a
/// hand-edited file with two `position` keys is not read as the second one.
fn check_unique_keys(text: &str, path: &Path) -> Result<()> {
    struct Any;
    impl<'de> Deserialize<'de> for Any {
        fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
            d.deserialize_any(AnyVisitor)
        }
    }
    struct AnyVisitor;
    impl<'de> serde::de::Visitor<'de> for AnyVisitor {
        type Value = Any;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("JSON")
        }
        fn visit_bool<E>(self, _: bool) -> std::result::Result<Any, E> {
            Ok(Any)
        }
        fn visit_i64<E>(self, _: i64) -> std::result::Result<Any, E> {
            Ok(Any)
        }
        fn visit_u64<E>(self, _: u64) -> std::result::Result<Any, E> {
            Ok(Any)
        }
        fn visit_f64<E>(self, _: f64) -> std::result::Result<Any, E> {
            Ok(Any)
        }
        fn visit_str<E>(self, _: &str) -> std::result::Result<Any, E> {
            Ok(Any)
        }
        fn visit_unit<E>(self) -> std::result::Result<Any, E> {
            Ok(Any)
        }
        fn visit_seq<A: serde::de::SeqAccess<'de>>(
            self,
            mut a: A,
        ) -> std::result::Result<Any, A::Error> {
            while a.next_element::<Any>()?.is_some() {}
            Ok(Any)
        }
        fn visit_map<A: serde::de::MapAccess<'de>>(
            self,
            a: A,
        ) -> std::result::Result<Any, A::Error> {
            unique_keys::<_, Any>(serde::de::value::MapAccessDeserializer::new(a))?;
            Ok(Any)
        }
    }
    serde_json::from_str::<Any>(text)
        .map(|_| ())
        .map_err(|e| Error::format(path, format!("JSON: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_are_told_apart_by_content_then_name() {
        let p = Path::new("x.json");
        let slicer = r#"{"markups": []}"#;
        let verse = r#"[{"direction": ["P", "I", "R"]}]"#;
        let ours = r#"[{"level": "L3", "units": "mm", "landmarks": {}}]"#;
        assert_eq!(
            LandmarkFormat::detect(slicer, p).unwrap(),
            LandmarkFormat::Slicer
        );
        assert_eq!(
            LandmarkFormat::detect(verse, p).unwrap(),
            LandmarkFormat::Verse
        );
        assert_eq!(
            LandmarkFormat::detect(ours, p).unwrap(),
            LandmarkFormat::Spinedrr
        );
        let named = Path::new("a/F.MRK.json");
        assert_eq!(
            LandmarkFormat::detect(ours, named).unwrap(),
            LandmarkFormat::Slicer
        );
        assert_eq!(LandmarkFormat::for_output(named), LandmarkFormat::Slicer);
        assert_eq!(LandmarkFormat::for_output(p), LandmarkFormat::Spinedrr);
        let e = LandmarkFormat::detect("{oops", Path::new("bad.json")).unwrap_err();
        assert!(
            e.to_string().contains("bad.json") && e.to_string().contains("not JSON"),
            "{e}"
        );
    }

    #[test]
    fn repeated_keys_anywhere_are_refused() {
        let twice = r#"{"markups": [{"controlPoints": [{"label": "a", "position": [1, 2, 3],
            "position": [4, 5, 6]}]}]}"#;
        let e = check_unique_keys(twice, Path::new("t.mrk.json")).unwrap_err();
        assert!(e.to_string().contains("\"position\" appears twice"), "{e}");
        assert!(check_unique_keys(r#"[1, {"a": [true, null, "s"]}]"#, Path::new("t")).is_ok());
    }
}
