//! The lumbar levels L1–L5 and level lists (`L1-L5`, `L3`, `L1,L3`).

use std::fmt;

use crate::{Error, Result};

/// A lumbar level.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Level {
    L1,
    L2,
    L3,
    L4,
    L5,
}

impl Level {
    pub const ALL: [Level; 5] = [Level::L1, Level::L2, Level::L3, Level::L4, Level::L5];

    /// 0 for L1 … 4 for L5 (cranial to caudal).
    pub fn index(self) -> usize {
        self as usize
    }

    pub fn name(self) -> &'static str {
        ["L1", "L2", "L3", "L4", "L5"][self.index()]
    }

    /// Parses `L1` … `L5` (case-insensitive).
    pub fn parse(s: &str) -> Result<Level> {
        let t = s.trim();
        Level::ALL
            .into_iter()
            .find(|l| l.name().eq_ignore_ascii_case(t))
            .ok_or_else(|| {
                Error::invalid("levels", format!("{t:?} is not one of L1, L2, L3, L4, L5"))
            })
    }
}

impl fmt::Display for Level {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Parses a level list: a range `L1-L5`, a single level `L3`, or a comma list `L1,L3` (ranges allowed
/// inside the list). Returns the distinct levels, cranial to caudal.
pub fn parse_levels(spec: &str) -> Result<Vec<Level>> {
    let mut out = Vec::new();
    for part in spec.split(',') {
        let part = part.trim();
        if part.is_empty() {
            return Err(Error::invalid("levels", format!("empty item in {spec:?}")));
        }
        if let Some((a, b)) = part.split_once('-') {
            let (a, b) = (Level::parse(a)?, Level::parse(b)?);
            if a > b {
                return Err(Error::invalid(
                    "levels",
                    format!("range {part:?} runs caudal to cranial"),
                ));
            }
            out.extend(Level::ALL[a.index()..=b.index()].iter().copied());
        } else {
            out.push(Level::parse(part)?);
        }
    }
    out.sort();
    out.dedup();
    Ok(out)
}
