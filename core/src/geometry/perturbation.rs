//! Geometry perturbations: the paper's `K_perr` (focal scale/offset, piercing shift, skew, pixel scale)
//! and the physical errors of a C-arm (a displaced focal spot, a displaced or rotated detector; see
//! [`super::physical`]), as one value with one spec syntax.

use std::fmt;

use serde::{Deserialize, Serialize};

use super::Intrinsics;
use crate::{Error, Result};

/// How the assumed (calibrated) geometry of a view differs from the true one.
///
/// The intrinsic part changes `K` with the extrinsics held fixed: `fx' = (α_f fx + Δf) · sx`,
/// `fy' = (α_f fy + Δf) · sy`, `cx' = cx + Δcx`, `cy' = cy + Δcy`, `s' = s + skew`. `sx`, `sy` model an
/// anisotropic pixel-spacing error (spacing scaled by `1/sx`, `1/sy`).
///
/// The physical part (fields ending in `_mm` and `_deg`) moves the assumed focal spot and detector
/// relative to the true ones, in the true view's camera axes (x along detector rows = u, y down the
/// detector = v, z along the central ray); it changes `K`, `R` and `t` together
/// ([`super::physical::assumed_view`]). When both parts are given, the physical one applies first and
/// the intrinsic one changes the `K` it produced.
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
    /// Focal-spot displacement (mm) along the camera's x, y and z axes.
    pub src_dx_mm: f64,
    pub src_dy_mm: f64,
    pub src_dz_mm: f64,
    /// Detector displacement (mm) along the camera's x, y and z axes.
    pub det_dx_mm: f64,
    pub det_dy_mm: f64,
    pub det_dz_mm: f64,
    /// Detector rotation (degrees, right-handed) about the central ray, through the piercing point.
    pub det_roll_deg: f64,
    /// Detector tilt (degrees, right-handed) about its row axis (u, camera x), through the piercing point.
    pub det_tilt_u_deg: f64,
    /// Detector tilt (degrees, right-handed) about its column axis (v, camera y), through the piercing
    /// point.
    pub det_tilt_v_deg: f64,
}

impl Default for Perturbation {
    fn default() -> Self {
        Self::NONE
    }
}

/// The keys accepted by [`Perturbation::parse`].
pub const PERTURBATION_KEYS: &str = "df, alpha, dcx, dcy, skew, sx, sy (intrinsic, px); src_dx_mm, \
     src_dy_mm, src_dz_mm, det_dx_mm, det_dy_mm, det_dz_mm, det_roll_deg, det_tilt_u_deg, det_tilt_v_deg \
     (physical)";

/// The physical keys, in spec order.
pub const PHYSICAL_KEYS: [&str; 9] = [
    "src_dx_mm",
    "src_dy_mm",
    "src_dz_mm",
    "det_dx_mm",
    "det_dy_mm",
    "det_dz_mm",
    "det_roll_deg",
    "det_tilt_u_deg",
    "det_tilt_v_deg",
];

/// Largest |displacement| (mm) and |rotation| (degrees) a physical key accepts: far beyond any C-arm
/// calibration error, short of geometry that no longer images anything.
pub const MAX_PHYSICAL_MM: f64 = 500.0;
pub const MAX_PHYSICAL_DEG: f64 = 45.0;

impl Perturbation {
    pub const NONE: Perturbation = Perturbation {
        df_px: 0.0,
        alpha_f: 1.0,
        dcx_px: 0.0,
        dcy_px: 0.0,
        skew_px: 0.0,
        sx: 1.0,
        sy: 1.0,
        src_dx_mm: 0.0,
        src_dy_mm: 0.0,
        src_dz_mm: 0.0,
        det_dx_mm: 0.0,
        det_dy_mm: 0.0,
        det_dz_mm: 0.0,
        det_roll_deg: 0.0,
        det_tilt_u_deg: 0.0,
        det_tilt_v_deg: 0.0,
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

    /// Every key with its value and its no-change value, in spec order.
    fn entries(&self) -> [(&'static str, f64, f64); 16] {
        [
            ("df", self.df_px, 0.0),
            ("alpha", self.alpha_f, 1.0),
            ("dcx", self.dcx_px, 0.0),
            ("dcy", self.dcy_px, 0.0),
            ("skew", self.skew_px, 0.0),
            ("sx", self.sx, 1.0),
            ("sy", self.sy, 1.0),
            ("src_dx_mm", self.src_dx_mm, 0.0),
            ("src_dy_mm", self.src_dy_mm, 0.0),
            ("src_dz_mm", self.src_dz_mm, 0.0),
            ("det_dx_mm", self.det_dx_mm, 0.0),
            ("det_dy_mm", self.det_dy_mm, 0.0),
            ("det_dz_mm", self.det_dz_mm, 0.0),
            ("det_roll_deg", self.det_roll_deg, 0.0),
            ("det_tilt_u_deg", self.det_tilt_u_deg, 0.0),
            ("det_tilt_v_deg", self.det_tilt_v_deg, 0.0),
        ]
    }

    /// The field a key names, or `None` for an unknown key.
    fn slot(&mut self, key: &str) -> Option<&mut f64> {
        Some(match key {
            "df" => &mut self.df_px,
            "alpha" => &mut self.alpha_f,
            "dcx" => &mut self.dcx_px,
            "dcy" => &mut self.dcy_px,
            "skew" => &mut self.skew_px,
            "sx" => &mut self.sx,
            "sy" => &mut self.sy,
            "src_dx_mm" => &mut self.src_dx_mm,
            "src_dy_mm" => &mut self.src_dy_mm,
            "src_dz_mm" => &mut self.src_dz_mm,
            "det_dx_mm" => &mut self.det_dx_mm,
            "det_dy_mm" => &mut self.det_dy_mm,
            "det_dz_mm" => &mut self.det_dz_mm,
            "det_roll_deg" => &mut self.det_roll_deg,
            "det_tilt_u_deg" => &mut self.det_tilt_u_deg,
            "det_tilt_v_deg" => &mut self.det_tilt_v_deg,
            _ => return None,
        })
    }

    /// Parses a comma-separated spec such as `df=300,dcx=20,dcy=-10` or `det_dz_mm=5,det_roll_deg=0.5`.
    /// An empty string or `none` is no change.
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
            let slot = p.slot(key).ok_or_else(|| {
                Error::invalid(
                    "perturbation",
                    format!("unknown key '{key}' (keys: {PERTURBATION_KEYS})"),
                )
            })?;
            *slot = value;
        }
        p.check()?;
        Ok(p)
    }

    /// Checks the domain of every key: positive scales, finite values, physical keys within
    /// ±[`MAX_PHYSICAL_MM`] mm and ±[`MAX_PHYSICAL_DEG`]°.
    pub fn check(&self) -> Result<()> {
        for (name, v, _) in self.entries() {
            if !v.is_finite() {
                return Err(Error::invalid(
                    format!("perturbation {name}"),
                    format!("must be finite, got {v}"),
                ));
            }
        }
        for (name, v) in [("alpha", self.alpha_f), ("sx", self.sx), ("sy", self.sy)] {
            if v <= 0.0 {
                return Err(Error::invalid(
                    format!("perturbation {name}"),
                    format!("must be positive, got {v}"),
                ));
            }
        }
        for (name, v, _) in self.entries().into_iter().skip(7) {
            let (limit, unit) = if name.ends_with("_deg") {
                (MAX_PHYSICAL_DEG, "°")
            } else {
                (MAX_PHYSICAL_MM, " mm")
            };
            if v.abs() > limit {
                return Err(Error::invalid(
                    format!("perturbation {name}"),
                    format!(
                        "{v}{unit} is beyond ±{limit}{unit}, far past any C-arm calibration error"
                    ),
                ));
            }
        }
        Ok(())
    }

    /// True when the perturbation changes nothing.
    pub fn is_none(&self) -> bool {
        *self == Self::NONE
    }

    /// True when a physical key (focal spot or detector displacement, detector rotation) is set: the
    /// perturbation then moves the camera, not only `K`.
    pub fn is_physical(&self) -> bool {
        self.entries()
            .into_iter()
            .skip(7)
            .any(|(_, v, default)| v != default)
    }

    /// The intrinsic part alone (physical keys cleared).
    pub fn intrinsic_part(&self) -> Perturbation {
        Perturbation {
            df_px: self.df_px,
            alpha_f: self.alpha_f,
            dcx_px: self.dcx_px,
            dcy_px: self.dcy_px,
            skew_px: self.skew_px,
            sx: self.sx,
            sy: self.sy,
            ..Self::NONE
        }
    }

    /// The intrinsics under the intrinsic part alone; fails if the result is not a valid camera (e.g.
    /// a focal length ≤ 0), or if a physical key is set (that changes the camera, not only `K`: use
    /// [`crate::geometry::View::perturbed`]).
    pub fn apply(&self, k: &Intrinsics) -> Result<Intrinsics> {
        if self.is_physical() {
            return Err(Error::invalid(
                "perturbation",
                format!(
                    "'{self}' moves the focal spot or the detector, which changes the camera's pose \
                     as well as K; this analysis takes intrinsic perturbations only"
                ),
            ));
        }
        self.apply_intrinsic(k)
    }

    /// `K` changed by the intrinsic part (physical keys ignored).
    pub(crate) fn apply_intrinsic(&self, k: &Intrinsics) -> Result<Intrinsics> {
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
        let items: Vec<String> = self
            .entries()
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
            "src_dx_mm=2,det_dz_mm=-5,det_roll_deg=0.5",
            "df=100,det_tilt_u_deg=1,det_tilt_v_deg=-2",
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
            "det_dz=5",
            "det_dz_mm=600",
            "det_roll_deg=90",
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
