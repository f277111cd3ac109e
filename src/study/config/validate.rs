//! [`StudyConfig::validate`]: every key checked before any work; errors name the key and the value.
//! (Enumerated values — experiments, methods, label conventions — are checked when the TOML is parsed.)

use super::StudyConfig;
use crate::{Error, Result};

impl StudyConfig {
    /// Checks every key before any work; errors name the key and the value.
    pub fn validate(&self) -> Result<()> {
        let a = &self.anatomy;
        if a.levels.is_empty() && a.meshes.is_empty() && a.ct.is_empty() {
            return Err(Error::invalid(
                "anatomy.levels",
                "must list at least one level (or give [[anatomy.meshes]] or [[anatomy.ct]])",
            ));
        }
        self.levels()?;
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
        self.validate_registration()
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
            for f in m.files.iter().chain([&m.landmarks]) {
                if !f.is_file() {
                    return Err(Error::invalid(
                        "anatomy.meshes",
                        format!("target '{}': no such file {}", m.name, f.display()),
                    ));
                }
            }
            if !m.mu_per_mm.is_finite() {
                return Err(Error::invalid(
                    "anatomy.meshes.mu_per_mm",
                    format!("{} is not finite", m.mu_per_mm),
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

fn finite_list(key: &str, v: &[f64]) -> Result<()> {
    match v.iter().find(|x| !x.is_finite()) {
        Some(x) => Err(Error::invalid(key, format!("{x} is not finite"))),
        None => Ok(()),
    }
}
