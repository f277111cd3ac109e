//! Limits on the work a study config may ask for, checked by arithmetic before any unit is enumerated
//! (enumerating `trials = 1000000000` would itself take gigabytes): the number of work units (each is a
//! file under `units/`), the registration trials in all, and the trials in one unit (the resume
//! granularity: a unit is redone whole after an interruption).

use super::{Experiment, StudyConfig};
use crate::{Error, Result};

/// At most this many work units (the default study has 1 560).
pub const MAX_UNITS: u64 = 100_000;
/// At most this many registration trials in all (the default study runs 25 920).
pub const MAX_REGISTRATION_TRIALS: u64 = 1_000_000;
/// At most this many trials in one unit (the default is 20).
pub const MAX_TRIALS_PER_UNIT: usize = 10_000;
/// At most this many intensity-registration starts in all (each renders hundreds of DRRs; the full
/// grid of `examples/intensity_registration.toml` has 7 200, the default study 8).
pub const MAX_INTENSITY_STARTS: u64 = 10_000;

/// The work a config asks for, counted without enumerating it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WorkEstimate {
    /// Projection units: targets × views × perturbations.
    pub projection_units: u64,
    /// Registration cells: targets × methods × (Δf values × piercing shifts + physical cells).
    pub registration_cells: u64,
    /// Registration units: cells × ⌈trials / trials_per_unit⌉.
    pub registration_units: u64,
    /// Registration trials: cells × trials.
    pub registration_trials: u64,
    /// Calibration units (phantoms × σ × trial chunks × (1 + physical errors)), tracking units (targets × methods × cells) and
    /// intensity-registration units (targets ×
    /// view sets × (Δf × piercing + physical errors) × initial-mTRE bins).
    pub other_units: u64,
    /// Intensity-registration starts: intensity units × starts per bin.
    pub intensity_starts: u64,
}

impl WorkEstimate {
    /// Every unit of the study.
    pub fn units(&self) -> u64 {
        self.projection_units
            .saturating_add(self.registration_units)
            .saturating_add(self.other_units)
    }
}

impl StudyConfig {
    /// Counts the study's units and trials (saturating, so an absurd config cannot overflow).
    pub fn work_estimate(&self) -> WorkEstimate {
        let n = |x: usize| x as u64;
        // The counts of `units::targets` and `units::projection_perturbations` (the test below checks
        // them against enumeration).
        let a = &self.anatomy;
        let ct_targets: u64 =
            a.ct.iter()
                .map(|c| n(c.levels.len()) + u64::from(c.segment))
                .sum();
        let n_targets = n(a.levels.len())
            + u64::from(a.segment && !a.levels.is_empty())
            + n(a.meshes.len())
            + ct_targets;
        let g = &self.perturbations;
        let nonzero = g.piercing_px.iter().filter(|p| **p != 0.0).count();
        let n_perturbations = n(g.df_px.len()
            + nonzero
            + g.df_px.len().min(nonzero)
            + g.skew_px.len()
            + g.pixel_scale.len()
            + if self.runs(Experiment::Projection) {
                g.physical.keys().iter().map(|(_, v)| v.len()).sum()
            } else {
                0
            });
        let projection_units =
            if self.runs(Experiment::Projection) || self.runs(Experiment::Landmarks) {
                n_targets
                    .saturating_mul(n(self.geometry.views.len()))
                    .saturating_mul(n_perturbations)
            } else {
                0
            };
        let r = &self.registration;
        let physical_cells: usize = g.physical.keys().iter().map(|(_, v)| v.len()).sum();
        let (cells, chunks) = if self.runs(Experiment::Registration) {
            let cells = n_targets.saturating_mul(n(r.methods.len())).saturating_mul(
                n(r.df_px.len())
                    .saturating_mul(n(r.piercing_px.len()))
                    .saturating_add(n(physical_cells)),
            );
            (cells, n(r.trials.div_ceil(r.trials_per_unit.max(1))))
        } else {
            (0, 0)
        };
        let c = &self.calibration;
        let calibration_units = if self.runs(Experiment::Calibration) {
            let physical: usize = c.physical.keys().iter().map(|(_, v)| v.len()).sum();
            n(c.phantoms.len())
                .saturating_mul(n(c.noise_px.len()))
                .saturating_mul(n(c.trials.div_ceil(c.trials_per_unit.max(1))))
                .saturating_mul(n(1 + physical))
        } else {
            0
        };
        let i = &self.intensity_registration;
        let intensity_units = if self.runs(Experiment::IntensityRegistration) {
            let physical: usize = i.physical.keys().iter().map(|(_, v)| v.len()).sum();
            n(i.targets.len())
                .saturating_mul(n(i.views.len()))
                .saturating_mul(n(i.images.len()))
                .saturating_mul(
                    n(i.df_px.len())
                        .saturating_mul(n(i.piercing_px.len()))
                        .saturating_add(n(physical)),
                )
                .saturating_mul(n(i.init_mtre_mm.len().saturating_sub(1)))
        } else {
            0
        };
        let tr = &self.tracking;
        let tracking_units = if self.runs(Experiment::Tracking) {
            n_targets
                .saturating_mul(n(tr.methods.len()))
                .saturating_mul(n(tr.df_px.len() + physical_cells))
        } else {
            0
        };
        let screw_units = if self.runs(Experiment::Screws) {
            n_targets
        } else {
            0
        };
        WorkEstimate {
            other_units: calibration_units
                .saturating_add(intensity_units)
                .saturating_add(tracking_units)
                .saturating_add(screw_units),
            intensity_starts: intensity_units.saturating_mul(n(i.starts_per_bin)),
            projection_units,
            registration_cells: cells,
            registration_units: cells.saturating_mul(chunks),
            registration_trials: if cells == 0 {
                0
            } else {
                cells.saturating_mul(n(r.trials))
            },
        }
    }

    /// Refuses a config whose work exceeds the limits above, naming the key and the estimate.
    pub(super) fn check_work(&self) -> Result<()> {
        let r = &self.registration;
        if r.trials_per_unit > MAX_TRIALS_PER_UNIT {
            return Err(Error::invalid(
                "registration.trials_per_unit",
                format!(
                    "{} trials in one work unit; at most {MAX_TRIALS_PER_UNIT} (a unit is the resume \
                     granularity and runs on one thread)",
                    r.trials_per_unit
                ),
            ));
        }
        let w = self.work_estimate();
        if w.registration_trials > MAX_REGISTRATION_TRIALS {
            return Err(Error::invalid(
                "registration.trials",
                format!(
                    "{} trials × {} registration cells (targets × methods × (df_px × piercing_px + the \
                     cells of [perturbations.physical])) = {} \
                     trials; at most {MAX_REGISTRATION_TRIALS}",
                    r.trials, w.registration_cells, w.registration_trials
                ),
            ));
        }
        if w.intensity_starts > MAX_INTENSITY_STARTS {
            let i = &self.intensity_registration;
            let bins = i.init_mtre_mm.len().saturating_sub(1);
            return Err(Error::invalid(
                "intensity_registration.init_mtre_mm",
                format!(
                    "{} targets × {} view sets × {} df_px × {} piercing_px × {bins} initial-mTRE bins \
                     (from {} edges) × {} starts_per_bin = {} intensity registrations; at most \
                     {MAX_INTENSITY_STARTS} (each renders some 300–1 000 DRRs: the default study's \
                     take about a second of CPU each, the full grid of \
                     examples/intensity_registration.toml has 7 200); use fewer, wider bins or fewer \
                     starts_per_bin",
                    i.targets.len(),
                    i.views.len(),
                    i.df_px.len(),
                    i.piercing_px.len(),
                    i.init_mtre_mm.len(),
                    i.starts_per_bin,
                    w.intensity_starts
                ),
            ));
        }
        if w.units() > MAX_UNITS {
            return Err(Error::invalid(
                "the study grid",
                format!(
                    "{} work units ({} projection: targets × geometry.views × perturbations; {} \
                     registration: cells × ⌈registration.trials / registration.trials_per_unit⌉); at \
                     most {MAX_UNITS}",
                    w.units(),
                    w.projection_units,
                    w.registration_units
                ),
            ));
        }
        Ok(())
    }
}
