//! The JSON sidecar written beside every image (`name.json` for `name.tiff` / `name.png`): the one
//! builder of every sidecar the tool writes ([`Sidecar::new`] for a rendered image, [`Sidecar::derived`]
//! for an image computed from another, [`Sidecar::with_details`] for the producer's record), and the one
//! spelling of each image kind ([`kind`]) and unit ([`units`]).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::geometry::{Perturbation, View};
use crate::{Error, Result};

/// What an image's pixels are (the sidecar's `kind`).
pub mod kind {
    /// A DRR: line integral or intensity.
    pub const DRR: &str = "drr";
    /// A silhouette mask.
    pub const MASK: &str = "mask";
    /// A first-hit depth map.
    pub const DEPTH: &str = "depth";
    /// `|A − B|` of two DRRs, as a float image.
    pub const ABS_DIFFERENCE: &str = "abs_difference";
    /// A colour map of values (a difference) with a colour bar.
    pub const HEATMAP: &str = "heatmap";
    /// `compare`'s record, `metrics.json`.
    pub const METRICS: &str = "metrics";
    /// `register`'s result, `R.json`.
    pub const REGISTRATION: &str = "registration";
    /// `calibrate`'s record, `phantom.json`.
    pub const CALIBRATION: &str = "calibration";
}

/// Units of pixel values (the sidecar's `units`), one spelling each.
pub mod units {
    /// The line integral of linear attenuation, unitless (μ in mm⁻¹ times mm).
    pub const LINE_INTEGRAL: &str = "line integral ∫μ dl (μ in 1/mm)";
    /// Transmitted intensity by the Beer–Lambert law.
    pub const INTENSITY: &str = "intensity I0·exp(−∫μ dl)";
    /// Detected photons of the X-ray image model (`crate::io::XrayModel`).
    pub const XRAY_COUNTS: &str = "detected photons per pixel (I0·exp(−∫μ dl), Poisson, blurred)";
    /// The log-converted X-ray image model.
    pub const XRAY_LOG: &str = "−ln(N/I0) of detected photons N (an estimate of ∫μ dl)";
    /// Camera depth of the first surface a ray enters.
    pub const DEPTH_MM: &str = "camera z of the first surface, mm (0 = no surface)";
    /// Silhouette pixels of a mask PNG.
    pub const SILHOUETTE: &str = "silhouette: 255 inside, 0 outside";
    /// Absolute difference of two line-integral DRRs.
    pub const LINE_INTEGRAL_DIFFERENCE: &str = "|Δ line integral ∫μ dl| (μ in 1/mm)";
}

/// Everything needed to interpret an image geometrically.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sidecar {
    pub tool: String,
    pub version: String,
    /// What the pixels are: `drr`, `mask`, `depth`, `heatmap`, …
    pub kind: String,
    pub width: u32,
    pub height: u32,
    /// The intrinsics the image was rendered with (perturbed, if a perturbation was applied).
    #[serde(rename = "K")]
    pub k: [[f64; 3]; 3],
    /// The unperturbed intrinsics of the view.
    #[serde(rename = "K_reference")]
    pub k_reference: [[f64; 3]; 3],
    /// The extrinsics the image was rendered with (moved, if a physical perturbation was applied).
    pub world_to_camera: [[f64; 4]; 4],
    /// The unperturbed extrinsics of the view (absent in sidecars older than the physical
    /// perturbations, whose `world_to_camera` is always the reference's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub world_to_camera_reference: Option<[[f64; 4]; 4]>,
    /// The projection matrix the image was rendered with, `P = K [R | t]` (3 × 4, row-major, pixels
    /// from homogeneous world mm).
    #[serde(default, rename = "P", skip_serializing_if = "Option::is_none")]
    pub p: Option<[[f64; 4]; 3]>,
    /// The view's true source-to-detector distance (mm), when its geometry gives one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sdd_mm: Option<f64>,
    /// Units of the pixel values.
    pub units: String,
    pub view: String,
    /// Canonical perturbation spec (`none`, `df=300,dcx=20`, …) and its fields.
    pub perturbation_spec: String,
    pub perturbation: Perturbation,
    /// Producer-specific details (renderer, backend, anatomy, μ table, statistics).
    #[serde(default)]
    pub details: serde_json::Map<String, serde_json::Value>,
    /// The files of this image's output set (names in the sidecar's folder), written before this sidecar,
    /// which is written last: a set whose main sidecar is missing is incomplete, and a file of the set's
    /// naming pattern that is not listed here is not part of it (see [`super::write_drr_set`]). Empty
    /// (and not written) for an image without companions.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub companions: Vec<String>,
}

impl Sidecar {
    /// A sidecar for an image of `view` (reference geometry) rendered under `perturbation`.
    pub fn new(
        kind: &str,
        units: &str,
        reference: &View,
        perturbation: &Perturbation,
    ) -> Result<Self> {
        let rendered = reference.perturbed(perturbation)?;
        let k = rendered.intrinsics;
        Ok(Sidecar {
            tool: super::TOOL.into(),
            version: crate::VERSION.into(),
            kind: kind.into(),
            width: k.width,
            height: k.height,
            k: k.matrix_rows(),
            k_reference: reference.intrinsics.matrix_rows(),
            world_to_camera: rendered.world_to_camera.to_rows(),
            world_to_camera_reference: Some(reference.world_to_camera.to_rows()),
            p: Some(crate::geometry::physical::projection_matrix(&rendered)),
            sdd_mm: reference.sdd_mm,
            units: units.into(),
            view: reference.name.clone(),
            perturbation_spec: perturbation.to_string(),
            perturbation: *perturbation,
            details: serde_json::Map::new(),
            companions: Vec::new(),
        })
    }

    /// A sidecar for an image computed from the image this sidecar describes (same geometry, units and
    /// details), of another kind.
    pub fn derived(&self, kind: &str) -> Self {
        Sidecar {
            kind: kind.into(),
            ..self.clone()
        }
    }

    /// Adds the fields of `details` (a struct or map serialising to a JSON object) to the sidecar's
    /// `details`, replacing fields of the same name.
    pub fn with_details(mut self, details: &impl Serialize) -> Result<Self> {
        match serde_json::to_value(details) {
            Ok(serde_json::Value::Object(map)) => {
                self.details.extend(map);
                Ok(self)
            }
            Ok(other) => Err(Error::Internal(format!(
                "sidecar details must be a JSON object, not {other}"
            ))),
            Err(e) => Err(Error::encode("sidecar details", e.to_string())),
        }
    }

    /// Whether the image this sidecar describes was rendered with the same camera as `other`'s: size,
    /// `K` and `world_to_camera` (a mask belongs to a DRR only when they agree).
    pub fn same_camera(&self, other: &Sidecar) -> bool {
        (self.width, self.height, self.k, self.world_to_camera)
            == (other.width, other.height, other.k, other.world_to_camera)
    }

    /// The view the image was rendered with (perturbed intrinsics), checked for validity.
    pub fn rendered_view(&self, path: &Path) -> Result<View> {
        let k = crate::geometry::Intrinsics::from_matrix(self.k, self.width, self.height)
            .map_err(|e| Error::format(path, e.to_string()))?;
        let t = crate::geometry::RigidTransform::from_rows(self.world_to_camera, "world_to_camera")
            .map_err(|e| Error::format(path, e.to_string()))?;
        Ok(View::new(self.view.clone(), k, t))
    }

    /// The unperturbed view the image's perturbation was applied to.
    pub fn reference_view(&self, path: &Path) -> Result<View> {
        let k = crate::geometry::Intrinsics::from_matrix(self.k_reference, self.width, self.height)
            .map_err(|e| Error::format(path, format!("K_reference: {e}")))?;
        let rows = self
            .world_to_camera_reference
            .unwrap_or(self.world_to_camera);
        let t = crate::geometry::RigidTransform::from_rows(rows, "world_to_camera_reference")
            .map_err(|e| Error::format(path, e.to_string()))?;
        let v = View::new(self.view.clone(), k, t);
        Ok(match self.sdd_mm {
            Some(s) => v.with_sdd(s),
            None => v,
        })
    }

    /// Writes the sidecar atomically as pretty JSON.
    pub fn write(&self, path: &Path) -> Result<()> {
        super::write_json(path, self)
    }

    /// Reads a sidecar.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::from_json_str(&text, path)
    }

    /// Parses a sidecar's JSON; `origin` names it in errors.
    pub fn from_json_str(text: &str, origin: &Path) -> Result<Self> {
        serde_json::from_str(text)
            .map_err(|e| Error::format(origin, format!("not a spinedrr sidecar: {e}")))
    }
}

/// `name.json` beside `name.tiff`.
pub fn sidecar_path(image: &Path) -> PathBuf {
    image.with_extension("json")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::CArm;

    #[test]
    fn sidecar_round_trip() {
        let c = CArm::default_paper();
        let ap = c.view("ap").unwrap();
        for spec in [
            "df=300,dcx=20",
            "df=50,det_dz_mm=8,src_dx_mm=-3,det_roll_deg=1",
        ] {
            let p = Perturbation::parse(spec).unwrap();
            let s = Sidecar::new("drr", "mm", ap, &p).unwrap();
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("x.json");
            s.write(&path).unwrap();
            let back = Sidecar::read(&path).unwrap();
            assert_eq!(back, s);
            let v = back.rendered_view(&path).unwrap();
            let pv = ap.perturbed(&p).unwrap();
            assert_eq!(
                (v.intrinsics, v.world_to_camera),
                (pv.intrinsics, pv.world_to_camera)
            );
            assert_eq!(back.reference_view(&path).unwrap(), *ap);
            // P projects like the rendered view.
            let x = glam::DVec3::new(20.0, -10.0, 30.0);
            let m = back.p.unwrap();
            let h: [f64; 3] =
                std::array::from_fn(|i| m[i][0] * x.x + m[i][1] * x.y + m[i][2] * x.z + m[i][3]);
            let px = glam::DVec2::new(h[0] / h[2], h[1] / h[2]);
            assert!((px - pv.project(x)).length() < 1e-9);
        }
    }

    #[test]
    fn details_merge_and_derived_keeps_geometry() {
        let c = CArm::default_paper();
        let lat = c.view("lat").unwrap();
        let p = Perturbation::parse("df=100").unwrap();
        let s = Sidecar::new(kind::DRR, units::LINE_INTEGRAL, lat, &p)
            .unwrap()
            .with_details(&serde_json::json!({ "a": 1, "b": "x" }))
            .unwrap()
            .with_details(&serde_json::json!({ "b": "y" }))
            .unwrap();
        assert_eq!(
            (s.details["a"].as_i64(), s.details["b"].as_str()),
            (Some(1), Some("y"))
        );
        let h = s.derived(kind::HEATMAP);
        assert_eq!(h.kind, "heatmap");
        assert_eq!(
            (h.k, h.k_reference, h.units.as_str()),
            (s.k, s.k_reference, units::LINE_INTEGRAL)
        );
        assert_eq!(h.k[0][0], lat.intrinsics.fx + 100.0);
        assert!(s.with_details(&3).is_err());
    }
}
