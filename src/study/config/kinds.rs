//! The enumerated values of a study config, parsed once from their TOML spelling: which experiments run,
//! which registration methods (solver + observed views) and the CT label convention. An unknown value
//! is an error naming the key and listing the accepted values.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::anatomy::ct::Alignment;
use crate::anatomy::labels::LabelConvention;
use crate::registration::{Method, PnpSolver};
use crate::render::volume::VolumeMethod;
use crate::{Error, Result};

/// An experiment a study can run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Experiment {
    /// Silhouette, contour and image metrics, per-structure Dice, heatmaps.
    Projection,
    /// Landmark shifts measured from marker images beside the homography prediction.
    Landmarks,
    /// Monte-Carlo 2D–3D registration under perturbed intrinsics.
    Registration,
    /// Simulated C-arm calibrations whose errors feed the projection-domain analysis.
    Calibration,
    /// Intensity-based 2D–3D registration (DRR against fixed image) under perturbed intrinsics.
    IntensityRegistration,
    /// Relative (tracking) error: one target registered at two poses with the same wrong geometry.
    Tracking,
    /// Planned pedicle screws drawn and navigated with the wrong geometry: on-screen and 3-D errors.
    Screws,
}

impl Experiment {
    /// Every experiment.
    pub const ALL: [Experiment; 7] = [
        Experiment::Projection,
        Experiment::Landmarks,
        Experiment::Registration,
        Experiment::Calibration,
        Experiment::IntensityRegistration,
        Experiment::Tracking,
        Experiment::Screws,
    ];

    /// The experiments of the default config: all seven (calibration on a small grid).
    pub const DEFAULT: [Experiment; 7] = [
        Experiment::Projection,
        Experiment::Landmarks,
        Experiment::Registration,
        Experiment::IntensityRegistration,
        Experiment::Calibration,
        Experiment::Tracking,
        Experiment::Screws,
    ];

    /// The config spelling.
    pub fn name(self) -> &'static str {
        match self {
            Experiment::Projection => "projection",
            Experiment::Landmarks => "landmarks",
            Experiment::Registration => "registration",
            Experiment::Calibration => "calibration",
            Experiment::IntensityRegistration => "intensity-registration",
            Experiment::Tracking => "tracking",
            Experiment::Screws => "screws",
        }
    }
}

/// A registration method of the study: a solver and the views it observes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RegistrationMethod {
    DirectAp,
    DirectLat,
    DirectApLat,
    Kabsch,
    OpencvAp,
    OpencvLat,
}

impl RegistrationMethod {
    /// Every method, in the order of the default config.
    pub const ALL: [RegistrationMethod; 6] = [
        RegistrationMethod::DirectAp,
        RegistrationMethod::DirectLat,
        RegistrationMethod::DirectApLat,
        RegistrationMethod::Kabsch,
        RegistrationMethod::OpencvAp,
        RegistrationMethod::OpencvLat,
    ];

    /// The config (and table) spelling.
    pub fn name(self) -> &'static str {
        match self {
            RegistrationMethod::DirectAp => "direct-ap",
            RegistrationMethod::DirectLat => "direct-lat",
            RegistrationMethod::DirectApLat => "direct-ap+lat",
            RegistrationMethod::Kabsch => "kabsch",
            RegistrationMethod::OpencvAp => "opencv-ap",
            RegistrationMethod::OpencvLat => "opencv-lat",
        }
    }

    /// The solver.
    pub fn solver(self) -> Method {
        match self {
            RegistrationMethod::DirectAp
            | RegistrationMethod::DirectLat
            | RegistrationMethod::DirectApLat => Method::Direct,
            RegistrationMethod::Kabsch => Method::Kabsch,
            RegistrationMethod::OpencvAp | RegistrationMethod::OpencvLat => {
                Method::OpenCv(PnpSolver::Iterative)
            }
        }
    }

    /// The geometry views it observes.
    pub fn views(self) -> &'static [&'static str] {
        match self {
            RegistrationMethod::DirectAp | RegistrationMethod::OpencvAp => &["ap"],
            RegistrationMethod::DirectLat | RegistrationMethod::OpencvLat => &["lat"],
            RegistrationMethod::DirectApLat | RegistrationMethod::Kabsch => &["ap", "lat"],
        }
    }

    /// Whether it observes a single view (and so cannot separate a focal error from depth).
    pub fn single_view(self) -> bool {
        self.views().len() == 1
    }
}

/// A value with a fixed set of spellings, parsed with an error that names its config key.
trait Spelled: Sized + Copy + 'static {
    const KEY: &'static str;
    const WHAT: &'static str;
    fn all() -> &'static [Self];
    fn spelling(self) -> &'static str;

    fn parse_spelling(s: &str) -> Result<Self> {
        Self::all()
            .iter()
            .copied()
            .find(|v| v.spelling() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::all().iter().map(|v| v.spelling()).collect();
                Error::invalid(
                    Self::KEY,
                    format!("unknown {} '{s}' (use {})", Self::WHAT, names.join(", ")),
                )
            })
    }
}

impl Spelled for Experiment {
    const KEY: &'static str = "experiments";
    const WHAT: &'static str = "experiment";
    fn all() -> &'static [Self] {
        &Experiment::ALL
    }
    fn spelling(self) -> &'static str {
        self.name()
    }
}

impl Spelled for RegistrationMethod {
    const KEY: &'static str = "registration.methods";
    const WHAT: &'static str = "method";
    fn all() -> &'static [Self] {
        &RegistrationMethod::ALL
    }
    fn spelling(self) -> &'static str {
        self.name()
    }
}

macro_rules! spelled_impls {
    ($t:ty) => {
        impl FromStr for $t {
            type Err = Error;
            fn from_str(s: &str) -> Result<Self> {
                <$t as Spelled>::parse_spelling(s)
            }
        }
        impl fmt::Display for $t {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(self.name())
            }
        }
        impl Serialize for $t {
            fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
                s.serialize_str(self.name())
            }
        }
        impl<'de> Deserialize<'de> for $t {
            fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
                let s = String::deserialize(d)?;
                s.parse().map_err(serde::de::Error::custom)
            }
        }
    };
}

spelled_impls!(Experiment);
spelled_impls!(RegistrationMethod);

/// A serde `with` module that reads and writes a `[[anatomy.ct]]` field by its spelling (`FromStr` /
/// `Display`), its errors naming the config key.
macro_rules! spelled_field {
    ($(#[$doc:meta])* $module:ident, $t:ty, $key:literal) => {
        $(#[$doc])*
        pub mod $module {
            use super::*;

            pub fn serialize<S: Serializer>(v: &$t, s: S) -> std::result::Result<S::Ok, S::Error> {
                s.serialize_str(&v.to_string())
            }

            pub fn deserialize<'de, D: Deserializer<'de>>(
                d: D,
            ) -> std::result::Result<$t, D::Error> {
                let s = String::deserialize(d)?;
                s.parse::<$t>()
                    .map_err(|e| {
                        let message = match e {
                            Error::Invalid { message, .. } => message,
                            other => other.to_string(),
                        };
                        Error::invalid($key, message)
                    })
                    .map_err(serde::de::Error::custom)
            }
        }
    };
}

spelled_field!(
    /// Serde of an [`Alignment`] by its spelling (`none`, `anatomical`).
    alignment,
    Alignment,
    "anatomy.ct.align"
);
spelled_field!(
    /// Serde of a [`VolumeMethod`] by its spelling (`siddon`, `trilinear`).
    volume_method,
    VolumeMethod,
    "anatomy.ct.method"
);
spelled_field!(
    /// Serde of a [`LabelConvention`] by its spelling (`totalseg`, `verse`).
    label_convention,
    LabelConvention,
    "anatomy.ct.labels"
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spellings_round_trip_and_unknown_values_list_the_accepted_ones() {
        for m in RegistrationMethod::ALL {
            assert_eq!(m.name().parse::<RegistrationMethod>().unwrap(), m);
        }
        for e in Experiment::ALL {
            assert_eq!(e.name().parse::<Experiment>().unwrap(), e);
        }
        let e = "kabsh"
            .parse::<RegistrationMethod>()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("registration.methods") && e.contains("direct-ap+lat"),
            "{e}"
        );
        let e = "proj".parse::<Experiment>().unwrap_err().to_string();
        assert!(e.contains("experiments") && e.contains("landmarks"), "{e}");
        assert_eq!(RegistrationMethod::Kabsch.views(), ["ap", "lat"]);
        #[derive(Debug, Deserialize)]
        struct Ct {
            #[serde(with = "label_convention")]
            #[allow(dead_code)]
            labels: LabelConvention,
        }
        let e = toml::from_str::<Ct>("labels = \"foo\"")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("invalid anatomy.ct.labels: unknown label convention"),
            "{e}"
        );
        assert_eq!(
            RegistrationMethod::OpencvLat.solver(),
            Method::parse("opencv").unwrap()
        );
    }
}

/// The family of a projection perturbation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Family {
    /// Δf alone.
    Focal,
    /// Piercing point shifted by (p, p).
    Piercing,
    /// Δf paired with a non-zero piercing shift.
    Joint,
    /// Skew alone.
    Skew,
    /// Anisotropic pixel scale alone.
    Scale,
    /// A physical geometry error alone (focal spot or detector moved, detector rotated).
    Physical,
}

impl Family {
    /// The table spelling.
    pub fn name(self) -> &'static str {
        match self {
            Family::Focal => "focal",
            Family::Piercing => "piercing",
            Family::Joint => "joint",
            Family::Skew => "skew",
            Family::Scale => "scale",
            Family::Physical => "physical",
        }
    }

    /// The config keys whose values a perturbation of this family comes from.
    pub fn config_keys(self) -> &'static str {
        match self {
            Family::Focal => "perturbations.df_px",
            Family::Piercing => "perturbations.piercing_px",
            Family::Joint => "perturbations.df_px / perturbations.piercing_px",
            Family::Skew => "perturbations.skew_px",
            Family::Scale => "perturbations.pixel_scale",
            Family::Physical => "perturbations.physical",
        }
    }
}

impl std::fmt::Display for Family {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}
