//! Serde of f64 table cells as text: Rust's `{}` Display (shortest round-trip: `100`, `0.3`, `NaN`,
//! `inf`, `-inf`), parsed back with `str::parse`, so a value read back is the exact f64 written.
//!
//! Used for every f64 field of a row, in the CSV tables (where Display keeps today's bytes; the csv
//! crate would write `100.0`) and in the JSON unit files (where serde_json would turn NaN and ±inf into
//! `null`): there each number is a JSON string such as `"0.30000000000000004"` or `"NaN"`.

use std::fmt;

use serde::de::{self, Visitor};
use serde::{Deserializer, Serializer};

/// Writes `x` with `{}`.
pub fn serialize<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
    s.collect_str(x)
}

/// Reads a cell written by [`serialize`]. Asked for as text, not inferred: the csv crate would read
/// `-0` as the integer 0 and lose the sign.
pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    d.deserialize_str(Cell)
}

struct Cell;

impl Visitor<'_> for Cell {
    type Value = f64;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a number (e.g. 0.25, NaN, inf)")
    }

    fn visit_str<E: de::Error>(self, v: &str) -> Result<f64, E> {
        v.trim()
            .parse()
            .map_err(|_| E::custom(format!("'{v}' is not a number")))
    }

    fn visit_f64<E: de::Error>(self, v: f64) -> Result<f64, E> {
        Ok(v)
    }

    fn visit_i64<E: de::Error>(self, v: i64) -> Result<f64, E> {
        Ok(v as f64)
    }

    fn visit_u64<E: de::Error>(self, v: u64) -> Result<f64, E> {
        Ok(v as f64)
    }
}
