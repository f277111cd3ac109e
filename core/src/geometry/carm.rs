//! The C-arm: one detector and a set of named views, loaded from a geometry TOML file or the defaults.

use std::path::Path;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::{Intrinsics, RigidTransform, View};
use crate::{Error, Result};

/// The default geometry as an annotated TOML document: `spinedrr geometry` prints it, and
/// [`CArm::default_paper`] parses it, so the printed file and the defaults cannot drift apart.
pub const DEFAULT_GEOMETRY_TOML: &str = r#"# spinedrr C-arm geometry. World frame: millimetres, RAS+ (x = patient right, y = anterior,
# z = superior). Camera frame: OpenCV's (origin at the X-ray source, +z along the central ray toward
# the detector, +x along detector rows = u, +y down the detector = v). Pixel centres at integers.

[detector]
width = 1024                      # pixels (u)
height = 1024                     # pixels (v)
pixel_spacing_mm = [0.30, 0.30]   # [u, v]
sdd_mm = 1350.0                   # source-to-detector distance: fx = sdd / spacing_u = 4500 px
# principal_point_px = [511.5, 511.5]   # piercing point; default is the detector centre
# skew_px = 0.0
# K = [[4500.0, 0.0, 511.5], [0.0, 4500.0, 511.5], [0.0, 0.0, 1.0]]   # overrides all of the above but width/height
#                                  (with K, pixel_spacing_mm and sdd_mm may be left out)

# A view is either source_mm + target_mm (+ up) or an explicit 4x4 world_to_camera matrix.
[[view]]
name = "ap"
# Source posterior of the patient, central ray through the vertebra: source-to-object 1000 mm,
# magnification 1.35.
source_mm = [0.0, -1000.0, 0.0]
target_mm = [0.0, 0.0, 0.0]
up = [0.0, 0.0, 1.0]              # world direction shown at the top of the image

[[view]]
name = "lat"
# Non-isocentric lateral view: the source is 900 mm from the vertebra (magnification 1.5, nearer the
# source than in AP, so the vertebra appears larger, and the L1-L5 segment still fits the detector),
# and the central ray passes 25 mm posterior and 20 mm superior of the vertebra centre, which lands
# about 160 px from the piercing point.
source_mm = [-900.0, -25.0, 20.0]
target_mm = [0.0, -25.0, 20.0]
up = [0.0, 0.0, 1.0]
"#;

/// `[detector]` of the geometry file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorConfig {
    pub width: u32,
    pub height: u32,
    /// Required unless `K` is given (which fixes the intrinsics without a size in mm).
    #[serde(default)]
    pub pixel_spacing_mm: Option<[f64; 2]>,
    /// Required unless `K` is given.
    #[serde(default)]
    pub sdd_mm: Option<f64>,
    #[serde(default)]
    pub principal_point_px: Option<[f64; 2]>,
    #[serde(default)]
    pub skew_px: Option<f64>,
    #[serde(default, rename = "K")]
    pub k: Option<[[f64; 3]; 3]>,
}

/// One `[[view]]` of the geometry file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewConfig {
    pub name: String,
    #[serde(default)]
    pub source_mm: Option<[f64; 3]>,
    #[serde(default)]
    pub target_mm: Option<[f64; 3]>,
    #[serde(default)]
    pub up: Option<[f64; 3]>,
    #[serde(default)]
    pub world_to_camera: Option<[[f64; 4]; 4]>,
}

/// The whole geometry file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GeometryConfig {
    pub detector: DetectorConfig,
    #[serde(rename = "view")]
    pub views: Vec<ViewConfig>,
}

/// A C-arm with one detector and named views.
#[derive(Debug, Clone, PartialEq)]
pub struct CArm {
    pub views: Vec<View>,
}

impl DetectorConfig {
    /// The pixel spacing (mm, u and v) where this section states the detector physically (`None` for an
    /// explicit `K`, whose pixels have no stated size in mm).
    pub fn stated_pixel_spacing_mm(&self) -> Option<[f64; 2]> {
        self.physical().ok().map(|(spacing, _)| spacing)
    }

    /// The physical detector, `(pixel_spacing_mm, sdd_mm)`: an error naming the missing key when the
    /// section gives neither it nor an explicit `K`, and when `K` is given (it overrides them).
    pub fn physical(&self) -> Result<([f64; 2], f64)> {
        if self.k.is_some() {
            return Err(Error::invalid(
                "detector.K",
                "an explicit K has no pixel size or SDD in mm",
            ));
        }
        let missing = |key: &str| {
            Error::invalid(
                format!("detector.{key}"),
                "missing: give pixel_spacing_mm and sdd_mm, or an explicit K",
            )
        };
        Ok((
            self.pixel_spacing_mm
                .ok_or_else(|| missing("pixel_spacing_mm"))?,
            self.sdd_mm.ok_or_else(|| missing("sdd_mm"))?,
        ))
    }

    /// The intrinsics this detector section describes.
    pub fn intrinsics(&self) -> Result<Intrinsics> {
        if let Some(k) = self.k {
            return Intrinsics::from_matrix(k, self.width, self.height);
        }
        let (spacing, sdd) = self.physical()?;
        let mut k = Intrinsics::from_detector(sdd, spacing, self.width, self.height)?;
        if let Some([cx, cy]) = self.principal_point_px {
            k.cx = cx;
            k.cy = cy;
        }
        if let Some(s) = self.skew_px {
            k.skew = s;
        }
        k.validate()?;
        Ok(k)
    }
}

impl ViewConfig {
    fn world_to_camera(&self) -> Result<RigidTransform> {
        let field = format!("view '{}'", self.name);
        match (self.world_to_camera, self.source_mm, self.target_mm) {
            (Some(m), None, None) => {
                if self.up.is_some() {
                    return Err(Error::invalid(
                        field,
                        "'up' goes with source_mm/target_mm, not world_to_camera",
                    ));
                }
                RigidTransform::from_rows(m, &format!("{field} world_to_camera"))
            }
            (None, Some(s), Some(t)) => {
                let up = self.up.unwrap_or([0.0, 0.0, 1.0]);
                RigidTransform::look_at(DVec3::from(s), DVec3::from(t), DVec3::from(up))
                    .map_err(|e| Error::invalid(field, e.to_string()))
            }
            _ => Err(Error::invalid(
                field,
                "give either world_to_camera (4x4) or both source_mm and target_mm",
            )),
        }
    }
}

impl GeometryConfig {
    /// Builds the C-arm, validating every view.
    pub fn build(&self) -> Result<CArm> {
        let k = self.detector.intrinsics()?;
        if self.views.is_empty() {
            return Err(Error::invalid("view", "the geometry has no [[view]]"));
        }
        let mut views: Vec<View> = Vec::with_capacity(self.views.len());
        let mut names = std::collections::BTreeSet::new();
        for vc in &self.views {
            if vc.name.trim().is_empty() {
                return Err(Error::invalid("view.name", "must not be empty"));
            }
            if !names.insert(vc.name.as_str()) {
                return Err(Error::invalid(
                    "view.name",
                    format!("'{}' appears twice", vc.name),
                ));
            }
            let view = View::new(vc.name.clone(), k, vc.world_to_camera()?);
            // With an explicit K the detector's distance in mm is not known (K fixes only ratios).
            views.push(match self.detector.physical() {
                Ok((_, sdd)) => view.with_sdd(sdd),
                Err(_) => view,
            });
        }
        Ok(CArm { views })
    }
}

impl CArm {
    /// The default non-isocentric C-arm of `DESIGN.md` (AP and LAT).
    pub fn default_paper() -> CArm {
        Self::from_toml_str(DEFAULT_GEOMETRY_TOML, "built-in geometry")
            .unwrap_or_else(|e| panic!("the built-in geometry must parse: {e}"))
    }

    /// Parses a geometry TOML document; `origin` names it in errors.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<CArm> {
        let cfg: GeometryConfig =
            toml::from_str(text).map_err(|e| Error::format(origin, e.to_string()))?;
        cfg.build()
            .map_err(|e| Error::format(origin, e.to_string()))
    }

    /// Reads a geometry TOML file.
    pub fn from_file(path: &Path) -> Result<CArm> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::from_toml_str(&text, &path.display().to_string())
    }

    /// The view called `name`.
    pub fn view(&self, name: &str) -> Result<&View> {
        self.views.iter().find(|v| v.name == name).ok_or_else(|| {
            let names: Vec<&str> = self.views.iter().map(|v| v.name.as_str()).collect();
            Error::invalid(
                "view",
                format!(
                    "unknown view '{name}' (this geometry has: {})",
                    names.join(", ")
                ),
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_geometry_matches_design() {
        let c = CArm::default_paper();
        let ap = c.view("ap").unwrap();
        let lat = c.view("lat").unwrap();
        assert_eq!(ap.intrinsics.fx, 4500.0);
        assert_eq!((ap.intrinsics.cx, ap.intrinsics.cy), (511.5, 511.5));
        // AP: the vertebra centre (world origin) projects to the piercing point at depth 1000 mm.
        assert!((ap.project(DVec3::ZERO) - glam::DVec2::new(511.5, 511.5)).length() < 1e-9);
        assert!((ap.depth(DVec3::ZERO) - 1000.0).abs() < 1e-9);
        // LAT: nearer the source (larger image) and 150-250 px off the piercing point.
        assert!(lat.depth(DVec3::ZERO) < ap.depth(DVec3::ZERO));
        let off = (lat.project(DVec3::ZERO) - glam::DVec2::new(511.5, 511.5)).length();
        assert!((150.0..=250.0).contains(&off), "{off}");
        assert!(
            c.view("oblique")
                .unwrap_err()
                .to_string()
                .contains("ap, lat")
        );
    }

    #[test]
    fn explicit_matrix_views_and_errors() {
        let m = RigidTransform::look_at(DVec3::new(0.0, -900.0, 0.0), DVec3::ZERO, DVec3::Z)
            .unwrap()
            .to_rows();
        let text = format!(
            "[detector]\nwidth = 64\nheight = 32\npixel_spacing_mm = [0.5, 0.5]\nsdd_mm = 1000.0\n\
             [[view]]\nname = \"m\"\nworld_to_camera = {m:?}\n"
        );
        let c = CArm::from_toml_str(&text, "t.toml").unwrap();
        assert_eq!(c.views[0].intrinsics.fx, 2000.0);
        assert_eq!(c.views[0].intrinsics.cx, 31.5);
        let bad = text.replace("sdd_mm = 1000.0", "sdd_mm = 0.0");
        assert!(
            CArm::from_toml_str(&bad, "t.toml")
                .unwrap_err()
                .to_string()
                .contains("sdd_mm")
        );
        let bad = text.replace("width = 64", "width = 0");
        assert!(
            CArm::from_toml_str(&bad, "t.toml")
                .unwrap_err()
                .to_string()
                .contains("width")
        );
        let bad = text.replace("name = \"m\"", "name = \"m\"\nzoom = 2");
        assert!(
            CArm::from_toml_str(&bad, "t.toml")
                .unwrap_err()
                .to_string()
                .contains("zoom")
        );
    }

    /// An explicit K needs no pixel size or SDD (the template says so); without K, each of them is
    /// required and its absence is an error naming it. With K the views carry no SDD.
    #[test]
    fn explicit_k_needs_no_physical_detector_and_without_it_both_keys_are_named() {
        let views = "[[view]]\nname = \"ap\"\nsource_mm = [0.0, -1000.0, 0.0]\ntarget_mm = [0.0, 0.0, 0.0]\n";
        let k = format!(
            "[detector]\nwidth = 64\nheight = 32\nK = [[900.0, 0.0, 31.5], [0.0, 900.0, 15.5], [0.0, 0.0, 1.0]]\n{views}"
        );
        let c = CArm::from_toml_str(&k, "k.toml").unwrap();
        assert_eq!(c.views[0].intrinsics.fx, 900.0);
        assert_eq!(c.views[0].sdd_mm, None);
        let g: GeometryConfig = toml::from_str(&k).unwrap();
        assert_eq!(g.detector.stated_pixel_spacing_mm(), None);
        for (given, missing) in [
            ("pixel_spacing_mm = [0.5, 0.5]\n", "detector.sdd_mm"),
            ("sdd_mm = 1000.0\n", "detector.pixel_spacing_mm"),
        ] {
            let text = format!("[detector]\nwidth = 64\nheight = 32\n{given}{views}");
            let e = CArm::from_toml_str(&text, "p.toml")
                .unwrap_err()
                .to_string();
            assert!(e.contains(missing) && e.contains("p.toml"), "{e}");
        }
    }
}
