//! [`StudyConfig::validate`]: every key checked before any work; errors name the key and the value.
//! (Enumerated values — experiments, methods, label conventions — are checked when the TOML is parsed.)

use std::fmt::Display;

use super::StudyConfig;
use crate::anatomy::parse_levels;
use crate::geometry::{CArm, Perturbation};
use crate::{Error, Result};

impl StudyConfig {
    /// Checks every key before any work; errors name the key and the value.
    pub fn validate(&self) -> Result<()> {
        let a = &self.anatomy;
        if a.levels.is_empty() && a.meshes.is_empty() && a.ct.is_empty() && a.dataset.is_empty() {
            return Err(Error::invalid(
                "anatomy.levels",
                "must list at least one level (or give [[anatomy.meshes]], [[anatomy.ct]] or \
                 [[anatomy.dataset]])",
            ));
        }
        for d in &a.dataset {
            d.check()?;
        }
        unique("anatomy.dataset.name", &a.dataset, |d| d.name.clone())?;
        if self.experiments.is_empty() {
            return Err(Error::invalid(
                "experiments",
                "must list at least one of \"projection\", \"landmarks\", \"registration\"",
            ));
        }
        unique("experiments", &self.experiments, |e| e.name())?;
        self.levels()?;
        let parsed = a
            .levels
            .iter()
            .map(|l| parse_levels(l))
            .collect::<Result<Vec<_>>>()
            .map_err(|e| Error::invalid("anatomy.levels", e.to_string()))?;
        if let Some(i) = (1..parsed.len()).find(|&i| parsed[..i].contains(&parsed[i])) {
            return Err(Error::invalid(
                "anatomy.levels",
                format!(
                    "{:?} is listed twice: each level is studied once",
                    a.levels[i]
                ),
            ));
        }
        let mut names: Vec<String> = a.levels.clone();
        names.push(super::SEGMENT_TARGET.into());
        self.validate_meshes(&mut names)?;
        self.validate_ct(&mut names)?;
        positive("anatomy.voxel_mm", self.anatomy.voxel_mm)?;
        positive("anatomy.marker_radius_mm", self.anatomy.marker_radius_mm)?;
        if self.geometry.binning == 0 {
            return Err(Error::invalid("geometry.binning", "must be at least 1"));
        }
        let carm = self.carm()?;
        if self.geometry.views.is_empty() {
            return Err(Error::invalid(
                "geometry.views",
                "must list at least one view",
            ));
        }
        for v in &self.geometry.views {
            carm.view(v)
                .map_err(|e| Error::invalid("geometry.views", e.to_string()))?;
        }
        unique("geometry.views", &self.geometry.views, |v| v.clone())?;
        let p = &self.perturbations;
        finite_list("perturbations.df_px", &p.df_px)?;
        finite_list("perturbations.piercing_px", &p.piercing_px)?;
        finite_list("perturbations.skew_px", &p.skew_px)?;
        finite_list("perturbations.pixel_scale", &p.pixel_scale)?;
        if let Some(s) = p.pixel_scale.iter().find(|s| **s <= 0.0) {
            return Err(Error::invalid(
                "perturbations.pixel_scale",
                format!("{s} must be > 0"),
            ));
        }
        finite_list("heatmaps_df_px", &self.heatmaps_df_px)?;
        self.validate_registration()?;
        if self.runs(super::Experiment::Calibration) {
            self.calibration.validate()?;
            for q in self.calibration.physical.cells()? {
                for v in self.studied_views(&carm) {
                    v.perturbed(&q).map_err(|e| {
                        Error::invalid(
                            "calibration.physical",
                            format!("perturbation {q} in view '{}': {e}", v.name),
                        )
                    })?;
                }
            }
        }
        if self.runs(super::Experiment::IntensityRegistration) {
            self.intensity_registration
                .validate(&carm, &self.geometry.views)?;
        }
        if self.runs(super::Experiment::Tracking) {
            self.tracking.validate()?;
            for m in &self.tracking.methods {
                for v in m.views() {
                    carm.view(v).map_err(|e| {
                        Error::invalid("tracking.methods", format!("{}: {e}", m.name()))
                    })?;
                }
            }
            for (family, q) in self.tracking.perturbations(self) {
                for m in &self.tracking.methods {
                    for name in m.views() {
                        let v = carm.view(name)?;
                        v.perturbed(&q).map_err(|e| {
                            Error::invalid(
                                if family == super::Family::Focal {
                                    "tracking.df_px"
                                } else {
                                    "perturbations.physical"
                                },
                                format!("perturbation {q} in view '{name}': {e}"),
                            )
                        })?;
                    }
                }
            }
        }
        if self.runs(super::Experiment::Screws) {
            // The screw figure's radiographs use the spectral technique.
            self.intensity_registration.spectral.model()?;
        }
        self.validate_grid_intrinsics(&carm)?;
        // A listed heatmap the focal grid never renders would silently never be drawn; the default list
        // (not the user's) draws what the grid has of it.
        if self.runs(super::Experiment::Projection)
            && self.heatmaps_df_px != super::DEFAULT_HEATMAPS_DF_PX
            && let Some(df) = self.heatmaps_df_px.iter().find(|d| !p.df_px.contains(d))
        {
            let grid: Vec<String> = p.df_px.iter().map(|d| d.to_string()).collect();
            return Err(Error::invalid(
                "heatmaps_df_px",
                format!(
                    "{df} px is not in perturbations.df_px [{}]: a heatmap is drawn only at a Δf the \
                     focal family renders; add {df} there or remove it here",
                    grid.join(", ")
                ),
            ));
        }
        self.check_work()
    }

    /// Every perturbed K of the grid (projection cells in every view, registration cells in every
    /// view) must be a valid camera: fails before the first unit, naming the key and value.
    fn validate_grid_intrinsics(&self, carm: &CArm) -> Result<()> {
        // The cells of `units::projection_perturbations`, each with the keys its values come from.
        let cells: Vec<(&str, Perturbation)> = self
            .perturbations
            .cells()
            .into_iter()
            .map(|(family, q)| (family.config_keys(), q))
            .collect();
        let views: Vec<_> = self.studied_views(carm).collect();
        self.perturbations.physical.cells()?;
        for (key, q) in &cells {
            for v in &views {
                v.perturbed(q).map_err(|e| {
                    Error::invalid(*key, format!("perturbation {q} in view '{}': {e}", v.name))
                })?;
            }
        }
        if !self.runs(super::Experiment::Registration) {
            return Ok(());
        }
        let r = &self.registration;
        for &df in &r.df_px {
            for &pp in &r.piercing_px {
                let q = Perturbation {
                    df_px: df,
                    ..Perturbation::piercing(pp, pp)
                };
                for v in &carm.views {
                    q.apply(&v.intrinsics).map_err(|e| {
                        Error::invalid(
                            "registration.df_px / registration.piercing_px",
                            format!("perturbation {q} in view '{}': {e}", v.name),
                        )
                    })?;
                }
            }
        }
        // The physical cells the registration runs, in the views its methods observe.
        for q in self.perturbations.physical.cells()? {
            for m in &r.methods {
                for name in m.views() {
                    carm.view(name)?.perturbed(&q).map_err(|e| {
                        Error::invalid(
                            "perturbations.physical",
                            format!(
                                "perturbation {q} in view '{name}' (registration by {}): {e}",
                                m.name()
                            ),
                        )
                    })?;
                }
            }
        }
        Ok(())
    }

    fn validate_meshes(&self, names: &mut Vec<String>) -> Result<()> {
        for m in &self.anatomy.meshes {
            target_name("anatomy.meshes.name", &m.name, names)?;
            if m.files.is_empty() {
                return Err(Error::invalid(
                    "anatomy.meshes.files",
                    format!("target '{}' lists no files", m.name),
                ));
            }
            unique("anatomy.meshes.files", &m.files, |f| {
                f.display().to_string()
            })?;
            for f in m.files.iter().chain([&m.landmarks]) {
                if !f.is_file() {
                    return Err(Error::invalid(
                        "anatomy.meshes",
                        format!("target '{}': no such file {}", m.name, f.display()),
                    ));
                }
            }
            if !(m.mu_per_mm.is_finite() && m.mu_per_mm > 0.0) {
                return Err(Error::invalid(
                    "anatomy.meshes.mu_per_mm",
                    format!(
                        "target '{}': {} must be a finite attenuation above 0 mm⁻¹ (every file of the \
                         target takes it; at 0 the target attenuates nothing and every DRR is 0)",
                        m.name, m.mu_per_mm
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Static checks of `[[anatomy.ct]]` (names, files exist, convention, level names). Whether each
    /// label is present in its file is checked when the anatomy is loaded, still before any output.
    fn validate_ct(&self, names: &mut Vec<String>) -> Result<()> {
        for c in &self.anatomy.ct {
            target_name("anatomy.ct.name", &c.name, names)?;
            for (key, f) in [
                ("anatomy.ct.ct", Some(&c.ct)),
                ("anatomy.ct.seg", Some(&c.seg)),
                ("anatomy.ct.landmarks", c.landmarks.as_ref()),
            ] {
                if let Some(f) = f
                    && !f.is_file()
                {
                    return Err(Error::invalid(
                        key,
                        format!("target '{}': no such file {}", c.name, f.display()),
                    ));
                }
            }
            if c.levels.is_empty() {
                return Err(Error::invalid(
                    "anatomy.ct.levels",
                    format!("target '{}' lists no levels", c.name),
                ));
            }
            let mut sub: Vec<String> = c.level_targets()?.into_iter().map(|(n, _)| n).collect();
            if c.segment {
                sub.push(c.segment_target());
            }
            for n in sub {
                if names.contains(&n) {
                    return Err(Error::invalid(
                        "anatomy.ct.name",
                        format!("target '{n}' of '{}' clashes with another target", c.name),
                    ));
                }
                names.push(n);
            }
        }
        Ok(())
    }

    fn validate_registration(&self) -> Result<()> {
        let r = &self.registration;
        finite_list("registration.df_px", &r.df_px)?;
        finite_list("registration.piercing_px", &r.piercing_px)?;
        unique("registration.methods", &r.methods, |m| m.name())?;
        if r.trials == 0 {
            return Err(Error::invalid("registration.trials", "must be at least 1"));
        }
        if r.trials_per_unit == 0 {
            return Err(Error::invalid(
                "registration.trials_per_unit",
                "must be at least 1",
            ));
        }
        for (k, v) in [
            ("registration.init_rot_deg", r.init_rot_deg),
            ("registration.init_trans_mm", r.init_trans_mm),
            ("registration.noise_px", r.noise_px),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(k, format!("{v} must be finite and >= 0")));
            }
        }
        Ok(())
    }
}

/// A user target name: non-empty, letters/digits/'-' (it goes into file names), not yet taken.
fn target_name(key: &str, name: &str, names: &mut Vec<String>) -> Result<()> {
    let ok = !name.is_empty() && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '-');
    if !ok || names.iter().any(|n| n == name) {
        return Err(Error::invalid(
            key,
            format!("'{name}' must be unique, non-empty, letters/digits/'-' only"),
        ));
    }
    names.push(name.to_string());
    Ok(())
}

fn positive(key: &str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(Error::invalid(key, format!("{v} must be finite and > 0")))
    }
}

/// A finite list without repeats (a repeated value would run the same cells twice).
pub(super) fn finite_list(key: &str, v: &[f64]) -> Result<()> {
    if let Some(x) = v.iter().find(|x| !x.is_finite()) {
        return Err(Error::invalid(key, format!("{x} is not finite")));
    }
    unique(key, v, |x| *x)
}

/// Refuses a list in which two items have the same `identity` (each is studied once; a repeat would
/// run everything twice), naming the repeated item.
pub(super) fn unique<T, K: PartialEq + Display>(
    key: &str,
    items: &[T],
    identity: impl Fn(&T) -> K,
) -> Result<()> {
    let ids: Vec<K> = items.iter().map(identity).collect();
    match (1..ids.len()).find(|&i| ids[..i].contains(&ids[i])) {
        Some(i) => Err(Error::invalid(key, format!("{} is listed twice", ids[i]))),
        None => Ok(()),
    }
}
