//! Work units (independent pieces of a study, each resumable) and the table rows they produce.

use serde::{Deserialize, Serialize};

use super::config::{
    CalibrationCell, Experiment, IntensityCell, RegistrationMethod, RegistrationPhysicalCell,
    SEGMENT_TARGET, StudyConfig, TrackingCell,
};
use super::schema::{Family, UnitRows};
use crate::Result;
use crate::geometry::Perturbation;

/// A projection perturbation with its family.
#[derive(Debug, Clone, PartialEq)]
pub struct NamedPerturbation {
    pub family: Family,
    pub perturbation: Perturbation,
}

/// One independent piece of work.
#[derive(Debug, Clone, PartialEq)]
pub enum Unit {
    /// Silhouette, image and landmark metrics of `target` in `view` under one perturbation.
    Projection {
        target: String,
        view: String,
        p: NamedPerturbation,
    },
    /// Trials `first..first + count` of one registration cell.
    Registration {
        target: String,
        method: RegistrationMethod,
        df_px: f64,
        piercing_px: f64,
        first: usize,
        count: usize,
    },
    /// Trials of one registration cell under a physical error (`[perturbations.physical]`).
    RegistrationPhysical(RegistrationPhysicalCell),
    /// Trials of one (phantom, σ) of the calibration experiment.
    Calibration(CalibrationCell),
    /// Every start of one initial-mTRE bin of one intensity-registration cell.
    Intensity(IntensityCell),
    /// One tracking cell: a target registered at two poses under one perturbation.
    Tracking(TrackingCell),
    /// The planned pedicle screws of `target` under every perturbation of the grid.
    Screws { target: String },
}

impl Unit {
    /// A file-name-safe, unique id.
    pub fn id(&self) -> String {
        let raw = match self {
            Unit::Projection { target, view, p } if p.family == Family::Physical => {
                let spec = p.perturbation.to_string().replace(['=', ','], "");
                format!("proj_{target}_{view}_physical_{spec}")
            }
            Unit::Projection { target, view, p } => {
                let q = &p.perturbation;
                format!(
                    "proj_{target}_{view}_{}_df{}_cx{}_cy{}_s{}_sy{}",
                    p.family, q.df_px, q.dcx_px, q.dcy_px, q.skew_px, q.sy
                )
            }
            Unit::Registration {
                target,
                method,
                df_px,
                piercing_px,
                first,
                ..
            } => format!("reg_{target}_{method}_df{df_px}_p{piercing_px}_t{first}"),
            Unit::RegistrationPhysical(c) => c.id(),
            Unit::Calibration(c) => c.id(),
            Unit::Intensity(c) => c.id(),
            Unit::Tracking(c) => c.id(),
            Unit::Screws { target } => format!("screws_{target}"),
        };
        raw.replace('+', "_")
    }

    /// The cell in words, for error messages: target, view and perturbation, or the registration cell.
    pub fn describe(&self) -> String {
        match self {
            Unit::Projection { target, view, p } => format!(
                "target '{target}', view '{view}', perturbation {} (family {})",
                p.perturbation, p.family
            ),
            Unit::Registration {
                target,
                method,
                df_px,
                piercing_px,
                first,
                count,
            } => format!(
                "registration of target '{target}' by {method} at Δf = {df_px} px, piercing = \
                 {piercing_px} px, trials {first}..{}",
                first + count
            ),
            Unit::RegistrationPhysical(c) => c.describe(),
            Unit::Calibration(c) => c.describe(),
            Unit::Intensity(c) => c.describe(),
            Unit::Tracking(c) => c.describe(),
            Unit::Screws { target } => format!("pedicle screws of target '{target}'"),
        }
    }

    /// The anatomy target the unit studies (none for a calibration cell, which images a calibration
    /// phantom).
    pub fn target(&self) -> Option<&str> {
        match self {
            Unit::Projection { target, .. }
            | Unit::Registration { target, .. }
            | Unit::Screws { target } => Some(target),
            Unit::Intensity(c) => Some(&c.target),
            Unit::Tracking(c) => Some(&c.target),
            Unit::RegistrationPhysical(c) => Some(&c.target),
            Unit::Calibration(_) => None,
        }
    }

    /// The key every random draw of this unit derives from (trial chunking excluded, so the same trial
    /// draws the same numbers whatever `trials_per_unit` is).
    pub fn seed_key(&self) -> String {
        match self {
            Unit::Registration {
                target,
                method,
                df_px,
                piercing_px,
                ..
            } => format!("reg/{target}/{method}/{df_px}/{piercing_px}"),
            Unit::RegistrationPhysical(c) => c.seed_key(),
            Unit::Calibration(c) => c.seed_key(),
            Unit::Intensity(c) => c.seed_key(),
            other => other.id(),
        }
    }
}

/// A seed for `(seed, key, index)`: FNV-1a of the key mixed with the master seed and the index.
pub fn derive_seed(seed: u64, key: &str, index: u64) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in key.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    let mut z = h ^ seed.rotate_left(17) ^ index.wrapping_mul(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The projection perturbations of the grid, in table order ([`PerturbationGrid::cells`]); the
/// physical family only with the projection experiment (its table holds projection metrics).
pub fn projection_perturbations(cfg: &StudyConfig) -> Vec<NamedPerturbation> {
    cfg.perturbations
        .cells()
        .into_iter()
        .filter(|(family, _)| *family != Family::Physical || cfg.runs(Experiment::Projection))
        .map(|(family, perturbation)| NamedPerturbation {
            family,
            perturbation,
        })
        .collect()
}

/// The physical cells the landmark-registration experiment runs beside its Δf × piercing grid: those
/// of `[perturbations.physical]` (validated before any unit is made).
pub fn registration_physical_cells(cfg: &StudyConfig) -> Vec<Perturbation> {
    cfg.perturbations.physical.cells().unwrap_or_default()
}

/// The targets: each phantom level, then `segment` when enabled, then the mesh targets, then per
/// `[[anatomy.ct]]` entry its levels (`<name>-L1`, …) and `<name>-segment` when enabled. Call on a
/// validated config (CT level names that do not resolve are skipped here).
pub fn targets(cfg: &StudyConfig) -> Vec<String> {
    let mut t: Vec<String> = cfg.anatomy.levels.clone();
    if cfg.anatomy.segment && !t.is_empty() {
        t.push(SEGMENT_TARGET.into());
    }
    t.extend(cfg.anatomy.meshes.iter().map(|m| m.name.clone()));
    for c in &cfg.anatomy.ct {
        t.extend(
            c.level_targets()
                .unwrap_or_default()
                .into_iter()
                .map(|(n, _)| n),
        );
        if c.segment {
            t.push(c.segment_target());
        }
    }
    t
}

/// Every unit of the study in a fixed order (the order of the tables).
pub fn enumerate_units(cfg: &StudyConfig) -> Result<Vec<Unit>> {
    cfg.validate()?;
    let mut units = Vec::new();
    if cfg.runs(Experiment::Projection) || cfg.runs(Experiment::Landmarks) {
        for target in targets(cfg) {
            for view in &cfg.geometry.views {
                for p in projection_perturbations(cfg) {
                    units.push(Unit::Projection {
                        target: target.clone(),
                        view: view.clone(),
                        p,
                    });
                }
            }
        }
    }
    if cfg.runs(Experiment::Registration) {
        let r = &cfg.registration;
        for target in targets(cfg) {
            for method in &r.methods {
                for &df_px in &r.df_px {
                    for &piercing_px in &r.piercing_px {
                        for first in (0..r.trials).step_by(r.trials_per_unit) {
                            units.push(Unit::Registration {
                                target: target.clone(),
                                method: *method,
                                df_px,
                                piercing_px,
                                first,
                                count: r.trials_per_unit.min(r.trials - first),
                            });
                        }
                    }
                }
                for perturbation in registration_physical_cells(cfg) {
                    for first in (0..r.trials).step_by(r.trials_per_unit) {
                        units.push(Unit::RegistrationPhysical(RegistrationPhysicalCell {
                            target: target.clone(),
                            method: *method,
                            perturbation,
                            first,
                            count: r.trials_per_unit.min(r.trials - first),
                        }));
                    }
                }
            }
        }
    }
    if cfg.runs(Experiment::Calibration) {
        units.extend(cfg.calibration.cells().into_iter().map(Unit::Calibration));
    }
    if cfg.runs(Experiment::IntensityRegistration) {
        units.extend(
            cfg.intensity_registration
                .cells()
                .into_iter()
                .map(Unit::Intensity),
        );
    }
    if cfg.runs(Experiment::Tracking) {
        let cells = cfg.tracking.perturbations(cfg);
        for target in targets(cfg) {
            for method in &cfg.tracking.methods {
                for (family, perturbation) in &cells {
                    units.push(Unit::Tracking(TrackingCell {
                        target: target.clone(),
                        method: *method,
                        family: *family,
                        perturbation: *perturbation,
                    }));
                }
            }
        }
    }
    if cfg.runs(Experiment::Screws) {
        units.extend(
            targets(cfg)
                .into_iter()
                .map(|target| Unit::Screws { target }),
        );
    }
    Ok(units)
}

/// The file `units/<id>.json`: the unit's typed rows plus the config fingerprint they belong to. Its
/// f64 values are JSON strings in `{}` Display (`"0.1"`, `"NaN"`, `"-inf"`; see [`super::schema::num`]),
/// so NaN and infinities survive and the assembled tables are byte-identical to a fresh run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UnitFile {
    pub id: String,
    pub fingerprint: String,
    pub rows: UnitRows,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::study::config::Experiment;

    #[test]
    fn the_configs_work_estimate_counts_what_enumeration_makes() {
        let mut skewed = StudyConfig::quick();
        skewed.perturbations.skew_px = vec![1.0, 2.0];
        skewed.perturbations.pixel_scale = vec![1.01];
        skewed.perturbations.piercing_px = vec![0.0, 5.0, 10.0, 20.0];
        let mut calibration = StudyConfig::quick();
        calibration.experiments.push(Experiment::Calibration);
        calibration.calibration.trials = 7;
        calibration.calibration.trials_per_unit = 3;
        let mut intensity = StudyConfig::quick();
        if !intensity.runs(Experiment::IntensityRegistration) {
            intensity
                .experiments
                .push(Experiment::IntensityRegistration);
        }
        intensity.intensity_registration.views = vec!["ap".into(), "ap+lat".into()];
        intensity.intensity_registration.init_mtre_mm = vec![0.0, 1.0, 3.0, 7.0];
        intensity.intensity_registration.starts_per_bin = 5;
        for mut cfg in [
            StudyConfig::default(),
            StudyConfig::quick(),
            skewed,
            calibration,
            intensity,
        ] {
            cfg.registration.trials = 7;
            cfg.registration.trials_per_unit = 3;
            assert_eq!(
                cfg.work_estimate().projection_units,
                (targets(&cfg).len() * 2 * projection_perturbations(&cfg).len()) as u64
            );
            let units = enumerate_units(&cfg).unwrap();
            let w = cfg.work_estimate();
            assert_eq!(w.units(), units.len() as u64);
            let trials: usize = units
                .iter()
                .map(|u| match u {
                    Unit::Registration { count, .. } => *count,
                    Unit::RegistrationPhysical(c) => c.count,
                    _ => 0,
                })
                .sum();
            assert_eq!(w.registration_trials, trials as u64);
            let starts: usize = units
                .iter()
                .map(|u| match u {
                    Unit::Intensity(c) => c.starts,
                    _ => 0,
                })
                .sum();
            assert_eq!(w.intensity_starts, starts as u64);
        }
    }
}
