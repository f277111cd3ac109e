//! Intrinsic perturbations: the paper's `K_perr` (focal scale/offset, piercing shift, skew, pixel scale).

use std::fmt;

use serde::{Deserialize, Serialize};

use super::Intrinsics;
use crate::{Error, Result};

/// A change of the intrinsics with the extrinsics held fixed.
///
/// Applied as `fx' = (α_f fx + Δf) · sx`, `fy' = (α_f fy + Δf) · sy`, `cx' = cx + Δcx`, `cy' = cy + Δcy`,
/// `s' = s + skew`. `sx`, `sy` model an anisotropic pixel-spacing error (spacing scaled by `1/sx`, `1/sy`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Perturbation {
    /// Additive focal offset Δf (px), applied to fx and fy.
    pub df_px: f64,
    /// Multiplicative focal scale α_f.
    pub alpha_f: f64,
    /// Piercing-point shift Δcx (px).
    pub dcx_px: f64,
    /// Piercing-point shift Δcy (px).
    pub dcy_px: f64,
    /// Additive skew (px).
    pub skew_px: f64,
    /// Scale of fx alone (pixel-spacing change along u).
    pub sx: f64,
    /// Scale of fy alone (pixel-spacing change along v).
    pub sy: f64,
}

impl Default for Perturbation {
    fn default() -> Self {
        Self::NONE
    }
}

/// The keys accepted by [`Perturbation::parse`].
pub const PERTURBATION_KEYS: &str = "df, alpha, dcx, dcy, skew, sx, sy";

impl Perturbation {
    pub const NONE: Perturbation = Perturbation {
        df_px: 0.0,
        alpha_f: 1.0,
        dcx_px: 0.0,
        dcy_px: 0.0,
        skew_px: 0.0,
        sx: 1.0,
        sy: 1.0,
    };

    /// A focal offset of `df` px.
    pub fn focal(df_px: f64) -> Self {
        Perturbation {
            df_px,
            ..Self::NONE
        }
    }

    /// A piercing-point shift.
    pub fn piercing(dcx_px: f64, dcy_px: f64) -> Self {
        Perturbation {
            dcx_px,
            dcy_px,
            ..Self::NONE
        }
    }

    /// Parses a comma-separated spec such as `df=300,dcx=20,dcy=-10`. An empty string or `none` is no change.
    pub fn parse(spec: &str) -> Result<Self> {
        let mut p = Self::NONE;
        let spec = spec.trim();
        if spec.is_empty() || spec == "none" {
            return Ok(p);
        }
        let mut seen: Vec<&str> = Vec::new();
        for item in spec.split(',') {
            let item = item.trim();
            let (key, value) = item.split_once('=').ok_or_else(|| {
                Error::invalid(
                    "perturbation",
                    format!("'{item}' is not KEY=VALUE (keys: {PERTURBATION_KEYS})"),
                )
            })?;
            let key = key.trim();
            if seen.contains(&key) {
                return Err(Error::invalid(
                    format!("perturbation {key}"),
                    format!("'{key}' is given twice in '{spec}': give each key once"),
                ));
            }
            seen.push(key);
            let value: f64 = value.trim().parse().map_err(|_| {
                Error::invalid(
                    format!("perturbation {key}"),
                    format!("'{}' is not a number", value.trim()),
                )
            })?;
            if !value.is_finite() {
                return Err(Error::invalid(
                    format!("perturbation {key}"),
                    "must be finite",
                ));
            }
            let slot = match key {
                "df" => &mut p.df_px,
                "alpha" => &mut p.alpha_f,
                "dcx" => &mut p.dcx_px,
                "dcy" => &mut p.dcy_px,
                "skew" => &mut p.skew_px,
                "sx" => &mut p.sx,
                "sy" => &mut p.sy,
                other => {
                    return Err(Error::invalid(
                        "perturbation",
                        format!("unknown key '{other}' (keys: {PERTURBATION_KEYS})"),
                    ));
                }
            };
            *slot = value;
        }
        for (name, v) in [("alpha", p.alpha_f), ("sx", p.sx), ("sy", p.sy)] {
            if v <= 0.0 {
                return Err(Error::invalid(
                    format!("perturbation {name}"),
                    format!("must be positive, got {v}"),
                ));
            }
        }
        Ok(p)
    }

    /// True when the perturbation changes nothing.
    pub fn is_none(&self) -> bool {
        *self == Self::NONE
    }

    /// The perturbed intrinsics; fails if the result is not a valid camera (e.g. a focal length ≤ 0).
    pub fn apply(&self, k: &Intrinsics) -> Result<Intrinsics> {
        let out = Intrinsics {
            fx: (self.alpha_f * k.fx + self.df_px) * self.sx,
            fy: (self.alpha_f * k.fy + self.df_px) * self.sy,
            skew: k.skew + self.skew_px,
            cx: k.cx + self.dcx_px,
            cy: k.cy + self.dcy_px,
            width: k.width,
            height: k.height,
        };
        out.validate()?;
        Ok(out)
    }
}

impl fmt::Display for Perturbation {
    /// The canonical spec string (only non-default keys), parseable by [`Perturbation::parse`].
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let items: Vec<String> = [
            ("df", self.df_px, 0.0),
            ("alpha", self.alpha_f, 1.0),
            ("dcx", self.dcx_px, 0.0),
            ("dcy", self.dcy_px, 0.0),
            ("skew", self.skew_px, 0.0),
            ("sx", self.sx, 1.0),
            ("sy", self.sy, 1.0),
        ]
        .iter()
        .filter(|(_, v, default)| v != default)
        .map(|(k, v, _)| format!("{k}={v}"))
        .collect();
        if items.is_empty() {
            write!(f, "none")
        } else {
            write!(f, "{}", items.join(","))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_display_round_trip() {
        for s in [
            "none",
            "df=300",
            "alpha=1.05,dcx=20,dcy=-10",
            "skew=1.5,sx=1.01,sy=0.99",
        ] {
            let p = Perturbation::parse(s).unwrap();
            assert_eq!(p.to_string(), s);
            assert_eq!(Perturbation::parse(&p.to_string()).unwrap(), p);
        }
    }

    #[test]
    fn rejects_bad_specs() {
        for s in [
            "dz=3",
            "df",
            "df=abc",
            "alpha=0",
            "df=nan",
            "sx=-1",
            "df=1e999",
            "df=1,,dcx=2",
            "none,df=1",
            "=3",
        ] {
            let e = Perturbation::parse(s).unwrap_err().to_string();
            assert!(e.contains("perturbation"), "{s}: {e}");
        }
    }

    #[test]
    fn a_repeated_key_is_refused_naming_it() {
        for (s, key) in [("df=100,df=200", "df"), ("dcx=1, sy=1.1 ,dcx=1", "dcx")] {
            let e = Perturbation::parse(s).unwrap_err().to_string();
            assert!(e.contains(&format!("'{key}' is given twice")), "{s}: {e}");
        }
    }

    #[test]
    fn apply_matches_paper_k_perr() {
        let k = Intrinsics::from_detector(1350.0, [0.3, 0.3], 1024, 1024).unwrap();
        let p = Perturbation::parse("alpha=1.1,dcx=30,dcy=-20").unwrap();
        let q = p.apply(&k).unwrap();
        assert!((q.fx - 4950.0).abs() < 1e-9 && (q.fy - 4950.0).abs() < 1e-9);
        assert_eq!((q.cx, q.cy), (541.5, 491.5));
        assert!(Perturbation::focal(-5000.0).apply(&k).is_err());
    }
}
