//! The study configuration (TOML): anatomy, geometry, perturbation grid, registration trials, outputs.
//!
//! Every table has a default, and the defaults are the paper's experiments; `StudyConfig::quick` is a
//! tiny grid for smoke tests. [`StudyConfig::validate`] runs before any work and names the bad key.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::anatomy::{Level, parse_levels};
use crate::geometry::{CArm, DEFAULT_GEOMETRY_TOML, GeometryConfig, Perturbation, View};
use crate::render::Backend;
use crate::{Error, Result};

mod anatomy;
mod calibration;
pub mod dataset;
mod fixed_image;
mod intensity;
mod kinds;
mod limits;
mod physical;
mod tracking;
mod validate;

pub use anatomy::{AnatomyConfig, CtTarget, MeshTarget};
pub use calibration::{CalibrationCell, CalibrationSection, MAX_CALIBRATION_TRIALS, Protocol};
pub use fixed_image::{FixedImage, SpectralImageSection};
pub use intensity::{FixedScope, IntensityCell, IntensitySection, MAX_STARTS_PER_BIN};
pub use kinds::{Experiment, Family, RegistrationMethod};
pub use limits::{
    MAX_INTENSITY_STARTS, MAX_REGISTRATION_TRIALS, MAX_TRIALS_PER_UNIT, MAX_UNITS, WorkEstimate,
};
pub use physical::{PhysicalGrid, RegistrationPhysicalCell, cell_key as physical_cell_key};
pub use tracking::{TrackingCell, TrackingSection};

/// The default landmark observation noise σ (px per axis): sub-pixel localisation of a marker's centre
/// on a 0.3 mm detector (about 0.15 mm), so the registration trials of a cell differ and their mean has
/// a confidence interval.
pub const DEFAULT_NOISE_PX: f64 = 0.5;

/// The target of the phantom levels studied together (`anatomy.segment`).
pub const SEGMENT_TARGET: &str = "segment";

/// Whether `target` is a segment (several levels together): the phantom's, or `<name>-segment` of CT
/// targets and datasets. Segments are reported apart, never pooled with single levels.
pub fn is_segment(target: &str) -> bool {
    target == SEGMENT_TARGET || target.ends_with("-segment")
}

/// The whole study.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StudyConfig {
    /// Master seed; every unit derives its own from (seed, unit id).
    pub seed: u64,
    /// Which experiments run.
    pub experiments: Vec<Experiment>,
    pub anatomy: AnatomyConfig,
    pub geometry: GeometrySection,
    pub perturbations: PerturbationGrid,
    pub registration: RegistrationConfig,
    /// `[calibration]`: the calibration-in-the-loop experiment.
    pub calibration: CalibrationSection,
    /// `[intensity_registration]`: intensity-based 2D–3D registration under perturbed intrinsics.
    pub intensity_registration: IntensitySection,
    /// `[tracking]`: relative (tracking) error of a target registered at two poses.
    pub tracking: TrackingSection,
    /// Δf values (px, focal family) at which difference heatmaps are written. Each must be in
    /// `perturbations.df_px` (else the config is refused); the default, [`DEFAULT_HEATMAPS_DF_PX`], draws
    /// those of its values the focal grid renders.
    pub heatmaps_df_px: Vec<f64>,
}

/// `[geometry]`: the C-arm file (default: the built-in paper geometry), its views and detector binning.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GeometrySection {
    pub file: Option<PathBuf>,
    /// Views compared (names in the geometry).
    pub views: Vec<String>,
    /// Detector binning: `b` merges b×b pixels (width/b, spacing×b, so K scales by 1/b).
    pub binning: u32,
    /// What renders the targets' thickness DRRs and the intensity registration's moving DRRs: `raster`
    /// (the default), `embree`, `bvh` or `gpu` (see the README's *DRRs on a GPU*).
    pub backend: Backend,
}

/// `[perturbations]`: the intrinsic perturbations of the projection experiments.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PerturbationGrid {
    /// Focal offsets Δf (px), each alone (family `focal`) and paired in order with the non-zero piercing
    /// shifts (family `joint`).
    pub df_px: Vec<f64>,
    /// Piercing-point shifts (px), applied as (Δcx, Δcy) = (p, p) (family `piercing`).
    pub piercing_px: Vec<f64>,
    /// Skew values (px) (family `skew`).
    pub skew_px: Vec<f64>,
    /// Anisotropic pixel-scale factors applied to fy (family `scale`).
    pub pixel_scale: Vec<f64>,
    /// `[perturbations.physical]`: focal spot and detector displacements (mm) and detector rotations
    /// (degrees), each value alone (family `physical`). The default study has the literature's cells
    /// ([`PhysicalGrid::default`]); a `[perturbations]` table without this one has none, so a config
    /// written before the family existed runs the same units as it did.
    #[serde(default = "PhysicalGrid::none")]
    pub physical: PhysicalGrid,
}

impl PerturbationGrid {
    /// The projection perturbations of the grid with their families, in table order: each Δf alone,
    /// each non-zero piercing shift alone, Δf paired in order with the non-zero shifts, skews, scales.
    pub fn cells(&self) -> Vec<(Family, Perturbation)> {
        let nonzero: Vec<f64> = self
            .piercing_px
            .iter()
            .copied()
            .filter(|p| *p != 0.0)
            .collect();
        let mut out: Vec<(Family, Perturbation)> = Vec::new();
        out.extend(
            self.df_px
                .iter()
                .map(|&d| (Family::Focal, Perturbation::focal(d))),
        );
        out.extend(
            nonzero
                .iter()
                .map(|&p| (Family::Piercing, Perturbation::piercing(p, p))),
        );
        out.extend(self.df_px.iter().zip(&nonzero).map(|(&df_px, &p)| {
            let q = Perturbation {
                df_px,
                ..Perturbation::piercing(p, p)
            };
            (Family::Joint, q)
        }));
        out.extend(self.skew_px.iter().map(|&skew_px| {
            let q = Perturbation {
                skew_px,
                ..Perturbation::NONE
            };
            (Family::Skew, q)
        }));
        out.extend(self.pixel_scale.iter().map(|&sy| {
            let q = Perturbation {
                sy,
                ..Perturbation::NONE
            };
            (Family::Scale, q)
        }));
        // `validate` refuses a physical grid whose cells fail to parse, before any cell is used.
        out.extend(
            self.physical
                .cells()
                .unwrap_or_default()
                .into_iter()
                .map(|q| (Family::Physical, q)),
        );
        out
    }
}

/// The default `heatmaps_df_px` (px): the paper's two focal offsets.
pub const DEFAULT_HEATMAPS_DF_PX: [f64; 2] = [100.0, 500.0];

/// `[registration]`: the Monte-Carlo registration experiment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RegistrationConfig {
    /// Methods (solver and observed views).
    pub methods: Vec<RegistrationMethod>,
    pub df_px: Vec<f64>,
    /// Piercing shifts p (px), applied as (p, p).
    pub piercing_px: Vec<f64>,
    pub trials: usize,
    /// Trials per work unit (the resume granularity).
    pub trials_per_unit: usize,
    /// Initial pose: exact rotation (deg) about a random axis and translation (mm) in a random direction.
    pub init_rot_deg: f64,
    pub init_trans_mm: f64,
    /// Gaussian noise σ (px) on the observed landmarks, per axis, seeded per trial (default
    /// [`DEFAULT_NOISE_PX`]; 0 makes every trial of a cell converge to one answer).
    pub noise_px: f64,
}

impl Default for StudyConfig {
    fn default() -> Self {
        StudyConfig {
            seed: 20240601,
            experiments: Experiment::DEFAULT.to_vec(),
            anatomy: AnatomyConfig::default(),
            geometry: GeometrySection::default(),
            perturbations: PerturbationGrid::default(),
            registration: RegistrationConfig::default(),
            calibration: CalibrationSection::default(),
            intensity_registration: IntensitySection::default(),
            tracking: TrackingSection::default(),
            heatmaps_df_px: DEFAULT_HEATMAPS_DF_PX.to_vec(),
        }
    }
}

impl GeometrySection {
    /// The backend's user spelling (`raster`, `embree`, `bvh`, `gpu`), as `--backend` and the config take
    /// it.
    pub fn backend_name(&self) -> String {
        self.backend.name()
    }
}

impl Default for GeometrySection {
    fn default() -> Self {
        GeometrySection {
            file: None,
            views: vec!["ap".into(), "lat".into()],
            binning: 1,
            backend: Backend::Raster,
        }
    }
}

impl Default for PerturbationGrid {
    fn default() -> Self {
        PerturbationGrid {
            df_px: vec![100.0, 200.0, 300.0, 400.0, 500.0],
            piercing_px: vec![0.0, 10.0, 20.0, 30.0, 40.0, 50.0],
            // The paper's other two families, on scales a C-arm calibration can plausibly miss: a
            // detector shear of atan(s/fy) = 0.03–0.13° and a v pixel spacing 0.5–2 % too small (as an
            // SDD error of 7–27 mm at fy = 4500 px); the report's Setup states them so.
            skew_px: vec![2.0, 5.0, 10.0],
            pixel_scale: vec![1.005, 1.01, 1.02],
            physical: PhysicalGrid::default(),
        }
    }
}

impl Default for RegistrationConfig {
    fn default() -> Self {
        RegistrationConfig {
            methods: RegistrationMethod::ALL.to_vec(),
            df_px: vec![0.0, 100.0, 200.0, 300.0, 400.0, 500.0],
            piercing_px: vec![0.0, 10.0, 20.0, 30.0, 40.0, 50.0],
            trials: 20,
            trials_per_unit: 20,
            init_rot_deg: 2.0,
            init_trans_mm: 2.0,
            noise_px: DEFAULT_NOISE_PX,
        }
    }
}

impl StudyConfig {
    /// A tiny grid for smoke tests: L1 only, 2× binned detector, Δf {100, 500}, piercing {0, 50}, 3 trials,
    /// no calibration experiment.
    pub fn quick() -> Self {
        StudyConfig {
            anatomy: AnatomyConfig {
                levels: vec!["L1".into()],
                segment: false,
                voxel_mm: 1.0,
                marker_radius_mm: 4.0,
                meshes: Vec::new(),
                ct: Vec::new(),
                dataset: Vec::new(),
            },
            // The smoke test leaves out the calibration experiment (its own small grid is the
            // default study's).
            experiments: Experiment::DEFAULT
                .into_iter()
                .filter(|e| *e != Experiment::Calibration)
                .collect(),
            ..StudyConfig::default()
        }
        .with_quick_grid()
    }

    /// This study's targets, views and settings on the quick grid: 2× binned detector (unless already
    /// coarser), Δf {100, 500}, piercing {0, 50}, registration at Δf {0, 100, 500} × piercing {0, 50} with
    /// 3 trials, intensity registration of the last view set at Δf {0, 300}, one start in 0–5 mm, the first
    /// fixed-image model — a smoke test of a config before its full run.
    pub fn with_quick_grid(self) -> Self {
        let intensity_registration = self
            .intensity_registration
            .quick(self.geometry.binning.max(2) / self.geometry.binning.max(1));
        StudyConfig {
            intensity_registration,
            geometry: GeometrySection {
                binning: self.geometry.binning.max(2),
                ..self.geometry
            },
            perturbations: PerturbationGrid {
                df_px: vec![100.0, 500.0],
                piercing_px: vec![0.0, 50.0],
                physical: self.perturbations.physical.first_only(),
                ..self.perturbations
            },
            registration: RegistrationConfig {
                df_px: vec![0.0, 100.0, 500.0],
                piercing_px: vec![0.0, 50.0],
                trials: 3,
                trials_per_unit: 3,
                ..self.registration
            },
            ..self
        }
    }

    /// Parses a study TOML document (`origin` names it in errors) and validates it. Relative paths stay
    /// as they are (relative to the working directory); [`Self::from_file`] resolves them.
    pub fn from_toml_str(text: &str, origin: &str) -> Result<Self> {
        let cfg: StudyConfig =
            toml::from_str(text).map_err(|e| Error::format(origin, e.to_string()))?;
        cfg.validate()
            .map_err(|e| Error::format(origin, e.to_string()))?;
        Ok(cfg)
    }

    /// Reads and validates a study file. Relative paths in it (`geometry.file`, mesh files, landmarks,
    /// CT volumes) are relative to the file's folder, not to the working directory.
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let origin = path.display().to_string();
        let mut cfg: StudyConfig =
            toml::from_str(&text).map_err(|e| Error::format(&origin, e.to_string()))?;
        if let Some(dir) = path.parent() {
            cfg.resolve_paths(dir);
        }
        cfg.validate()
            .map_err(|e| Error::format(&origin, e.to_string()))?;
        Ok(cfg)
    }

    /// Makes every relative input path relative to `dir` instead (absolute paths are kept).
    pub fn resolve_paths(&mut self, dir: &Path) {
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = dir.join(&*p);
            }
        };
        if let Some(f) = &mut self.geometry.file {
            fix(f);
        }
        for m in &mut self.anatomy.meshes {
            m.files.iter_mut().for_each(fix);
            fix(&mut m.landmarks);
        }
        for d in &mut self.anatomy.dataset {
            fix(&mut d.folder);
        }
        self.intensity_registration.spectral.resolve_paths(dir);
        for c in &mut self.anatomy.ct {
            fix(&mut c.ct);
            fix(&mut c.seg);
            if let Some(l) = &mut c.landmarks {
                fix(l);
            }
        }
    }

    /// The phantom levels, parsed.
    pub fn levels(&self) -> Result<Vec<Level>> {
        if self.anatomy.levels.is_empty() {
            return Ok(Vec::new());
        }
        parse_levels(&self.anatomy.levels.join(","))
            .map_err(|e| Error::invalid("anatomy.levels", e.to_string()))
    }

    /// The C-arm: the geometry file (or the built-in one) with the detector binned.
    pub fn carm(&self) -> Result<CArm> {
        let (g, origin) = self.geometry_config()?;
        g.build().map_err(|e| Error::format(&origin, e.to_string()))
    }

    /// The views of `carm` this study uses (`geometry.views`), in the geometry's order.
    pub fn studied_views<'a>(
        &self,
        carm: &'a CArm,
    ) -> impl Iterator<Item = &'a View> + use<'a, '_> {
        carm.views
            .iter()
            .filter(|v| self.geometry.views.contains(&v.name))
    }

    /// The geometry file (or the built-in one) as written, with the detector binned, and where it came
    /// from (for messages and the report's *Setup*).
    /// The binned detector's pixel pitch along u (mm), where the geometry states it (None for an
    /// explicit K, or a geometry that cannot be read): a focal offset of Δf px is an SDD error of
    /// Δf × pitch mm, a piercing shift (p, p) of p px a move of p × pitch mm along u and along v on the
    /// detector.
    pub fn pixel_pitch_mm(&self) -> Option<f64> {
        let (g, _) = self.geometry_config().ok()?;
        g.detector.stated_pixel_spacing_mm().map(|s| s[0])
    }

    pub fn geometry_config(&self) -> Result<(GeometryConfig, String)> {
        let (text, origin) = match &self.geometry.file {
            Some(path) => (
                std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?,
                path.display().to_string(),
            ),
            None => (
                DEFAULT_GEOMETRY_TOML.to_string(),
                "built-in geometry".into(),
            ),
        };
        let mut g: GeometryConfig =
            toml::from_str(&text).map_err(|e| Error::format(&origin, e.to_string()))?;
        let b = self.geometry.binning;
        if b > 1 {
            let d = &mut g.detector;
            if d.k.is_some() {
                return Err(Error::invalid(
                    "geometry.binning",
                    format!("{origin} gives an explicit K; binning needs pixel spacing"),
                ));
            }
            if !d.width.is_multiple_of(b) || !d.height.is_multiple_of(b) {
                return Err(Error::invalid(
                    "geometry.binning",
                    format!(
                        "{b} does not divide the {} × {} px detector of {origin}: binning merges b × b \
                         pixels, so it must divide both sides",
                        d.width, d.height
                    ),
                ));
            }
            let bf = f64::from(b);
            d.width /= b;
            d.height /= b;
            d.pixel_spacing_mm = d.pixel_spacing_mm.map(|p| p.map(|s| s * bf));
            d.principal_point_px = d
                .principal_point_px
                .map(|c| c.map(|c| (c + 0.5) / bf - 0.5));
            d.skew_px = d.skew_px.map(|s| s / bf);
        }
        Ok((g, origin))
    }

    /// Whether experiment `e` runs.
    pub fn runs(&self, e: Experiment) -> bool {
        self.experiments.contains(&e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::anatomy::ct::Alignment;
    use crate::anatomy::labels::LabelConvention;
    use crate::render::volume::VolumeMethod;

    #[test]
    fn defaults_and_quick_validate() {
        StudyConfig::default().validate().unwrap();
        StudyConfig::quick().validate().unwrap();
    }

    #[test]
    fn binning_scales_k_like_merging_pixels() {
        // 1024 px at 0.30 mm, SDD 1350 → fx = 4500, cx = 511.5; binned ×2: 512 px at 0.60 mm → fx = 2250,
        // and the detector centre (511.5 + 0.5) / 2 − 0.5 = 255.5.
        let mut cfg = StudyConfig::default();
        cfg.geometry.binning = 2;
        let k = cfg.carm().unwrap().view("ap").unwrap().intrinsics;
        assert_eq!((k.width, k.height), (512, 512));
        assert!((k.fx - 2250.0).abs() < 1e-9 && (k.fy - 2250.0).abs() < 1e-9);
        assert!((k.cx - 255.5).abs() < 1e-9 && (k.cy - 255.5).abs() < 1e-9);
    }

    #[test]
    fn ct_levels_name_their_targets_and_reject_duplicates() {
        let mut c = CtTarget {
            name: "p".into(),
            ct: "ct.nii".into(),
            seg: "seg.nii".into(),
            labels: LabelConvention::TotalSegmentator,
            levels: vec!["L1".into(), "vertebrae_l3".into(), "27".into()],
            landmarks: None,
            segment: true,
            align: Alignment::None,
            smooth_iterations: 0,
            method: VolumeMethod::Siddon,
        };
        let t = c.level_targets().unwrap();
        assert_eq!(
            t,
            vec![
                ("p-L1".into(), 31),
                ("p-L3".into(), 29),
                ("p-id27".into(), 27)
            ]
        );
        assert_eq!(c.segment_target(), "p-segment");
        c.levels = vec!["L1".into(), "31".into()];
        let e = c.level_targets().unwrap_err().to_string();
        assert!(
            e.contains("anatomy.ct.levels") && e.contains("twice"),
            "{e}"
        );
        c.labels = LabelConvention::Verse;
        c.levels = vec!["L1".into()];
        assert_eq!(c.level_targets().unwrap()[0].1, 20, "VerSe L1 = 20");
    }

    #[test]
    fn config_round_trips_through_toml() {
        let q = StudyConfig::quick();
        let text = toml::to_string(&q).unwrap();
        assert_eq!(StudyConfig::from_toml_str(&text, "test").unwrap(), q);
    }
}
