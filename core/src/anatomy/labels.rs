//! Segmentation label conventions: which integer a vertebra carries in a label map.
//!
//! * **TotalSegmentator v2** (`total` task): `vertebrae_S1` = 26, `vertebrae_L5` = 27 … `vertebrae_L1` = 31,
//!   `vertebrae_T12` = 32 … `vertebrae_T1` = 43, `vertebrae_C7` = 44 … `vertebrae_C1` = 50, `sacrum` = 25.
//! * **VerSe** (2019/2020): C1–C7 = 1–7, T1–T12 = 8–19, L1–L5 = 20–24, L6 = 25, sacrum = 26,
//!   coccyx = 27, T13 = 28.

use std::fmt;
use std::str::FromStr;

use crate::{Error, Result};

/// A label numbering scheme for vertebrae.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LabelConvention {
    /// TotalSegmentator v2, `total` task.
    #[default]
    TotalSegmentator,
    /// The VerSe challenge.
    Verse,
}

impl FromStr for LabelConvention {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "totalseg" | "totalsegmentator" | "total" => Ok(LabelConvention::TotalSegmentator),
            "verse" => Ok(LabelConvention::Verse),
            _ => Err(Error::invalid(
                "labels",
                format!("unknown label convention {s:?}: use totalseg or verse"),
            )),
        }
    }
}

impl fmt::Display for LabelConvention {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            LabelConvention::TotalSegmentator => "totalseg",
            LabelConvention::Verse => "verse",
        })
    }
}

/// A spinal level: cervical 1–7, thoracic 1–13 (T13 only in VerSe), lumbar 1–6, sacrum, coccyx.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    C(u8),
    T(u8),
    L(u8),
    /// TotalSegmentator's `vertebrae_S1`.
    S1,
    Sacrum,
    Coccyx,
}

impl fmt::Display for Level {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Level::C(n) => write!(f, "C{n}"),
            Level::T(n) => write!(f, "T{n}"),
            Level::L(n) => write!(f, "L{n}"),
            Level::S1 => f.write_str("S1"),
            Level::Sacrum => f.write_str("sacrum"),
            Level::Coccyx => f.write_str("coccyx"),
        }
    }
}

impl Level {
    /// Parses `L1`, `t12`, `vertebrae_L1`, `S1`, `sacrum`, `coccyx`.
    pub fn parse(s: &str) -> Option<Level> {
        let t = s.trim().to_ascii_lowercase();
        let t = t.strip_prefix("vertebrae_").unwrap_or(&t);
        match t {
            "s1" => return Some(Level::S1),
            "sacrum" => return Some(Level::Sacrum),
            "coccyx" | "cocygis" => return Some(Level::Coccyx),
            _ => {}
        }
        // The first character, not byte: a name may start with any letter (`ê1` is no level, no panic).
        let kind = t.chars().next()?;
        let n: u8 = t[kind.len_utf8()..].parse().ok()?;
        match kind {
            'c' if (1..=7).contains(&n) => Some(Level::C(n)),
            't' if (1..=13).contains(&n) => Some(Level::T(n)),
            'l' if (1..=6).contains(&n) => Some(Level::L(n)),
            _ => None,
        }
    }
}

impl LabelConvention {
    /// The label id of `level` in this convention, if it has one.
    pub fn id(self, level: Level) -> Option<u16> {
        match (self, level) {
            (LabelConvention::TotalSegmentator, Level::C(n)) => Some(51 - n as u16),
            (LabelConvention::TotalSegmentator, Level::T(n)) if n <= 12 => Some(44 - n as u16),
            (LabelConvention::TotalSegmentator, Level::L(n)) if n <= 5 => Some(32 - n as u16),
            (LabelConvention::TotalSegmentator, Level::S1) => Some(26),
            (LabelConvention::TotalSegmentator, Level::Sacrum) => Some(25),
            (LabelConvention::Verse, Level::C(n)) => Some(n as u16),
            (LabelConvention::Verse, Level::T(13)) => Some(28),
            (LabelConvention::Verse, Level::T(n)) => Some(7 + n as u16),
            (LabelConvention::Verse, Level::L(n)) => Some(19 + n as u16),
            (LabelConvention::Verse, Level::Sacrum) => Some(26),
            (LabelConvention::Verse, Level::Coccyx) => Some(27),
            _ => None,
        }
    }

    /// The level that label `id` denotes in this convention, if any (inverse of [`Self::id`]).
    pub fn level(self, id: u16) -> Option<Level> {
        let candidates = (1..=7)
            .map(Level::C)
            .chain((1..=13).map(Level::T))
            .chain((1..=6).map(Level::L))
            .chain([Level::S1, Level::Sacrum, Level::Coccyx]);
        candidates.into_iter().find(|&l| self.id(l) == Some(id))
    }

    /// Resolves a command-line label: a level name (`L1`, `vertebrae_T12`) or a raw integer id.
    pub fn resolve(self, spec: &str) -> Result<u16> {
        if let Ok(id) = spec.trim().parse::<u16>() {
            if id == 0 {
                return Err(Error::invalid(
                    "label",
                    format!(
                        "{spec:?}: label 0 is the background of every label map, not a structure (give \
                         the label of a vertebra, e.g. L3 or its id)"
                    ),
                ));
            }
            return Ok(id);
        }
        let level = Level::parse(spec).ok_or_else(|| {
            Error::invalid(
                "label",
                format!(
                    "{spec:?} is neither a level name (L1, T12, C7, S1, sacrum) nor an integer id"
                ),
            )
        })?;
        self.id(level).ok_or_else(|| {
            Error::invalid(
                "label",
                format!("level {level} has no id in the {self} convention"),
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn published_ids() {
        let ts = LabelConvention::TotalSegmentator;
        let vs = LabelConvention::Verse;
        // TotalSegmentator v2 class map (`total`): L5 = 27 … L1 = 31, T12 = 32, T1 = 43, C7 = 44, C1 = 50.
        for (name, id) in [
            ("L5", 27),
            ("L1", 31),
            ("T12", 32),
            ("T1", 43),
            ("C7", 44),
            ("C1", 50),
            ("S1", 26),
        ] {
            assert_eq!(ts.resolve(name).unwrap(), id, "{name}");
        }
        // VerSe: C1 = 1, T1 = 8, T12 = 19, L1 = 20, L5 = 24, L6 = 25, T13 = 28.
        for (name, id) in [
            ("C1", 1),
            ("T1", 8),
            ("T12", 19),
            ("L1", 20),
            ("L5", 24),
            ("L6", 25),
            ("T13", 28),
        ] {
            assert_eq!(vs.resolve(name).unwrap(), id, "{name}");
        }
        assert_eq!(ts.resolve("vertebrae_l3").unwrap(), 29);
        assert_eq!(vs.resolve("117").unwrap(), 117);
    }

    #[test]
    fn level_is_inverse_of_id() {
        for conv in [LabelConvention::TotalSegmentator, LabelConvention::Verse] {
            for id in 0..=60 {
                if let Some(l) = conv.level(id) {
                    assert_eq!(conv.id(l), Some(id));
                }
            }
        }
    }

    #[test]
    fn bad_specs_are_errors() {
        let ts = LabelConvention::TotalSegmentator;
        assert!(ts.resolve("L6").is_err());
        assert!(ts.resolve("T13").is_err());
        assert!(ts.resolve("X1").is_err());
        assert!(ts.resolve("").is_err());
        let background = ts.resolve("0").unwrap_err().to_string();
        assert!(background.contains("background"), "{background}");
        assert!("mni".parse::<LabelConvention>().is_err());
    }
}
