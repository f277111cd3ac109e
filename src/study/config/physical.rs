//! `[perturbations.physical]`: the physical geometry errors of the projection experiments — a focal spot
//! or a detector displaced (mm) or a detector rotated (degrees), each value of each key alone (family
//! `physical`), in the view's camera axes (see [`crate::geometry::physical`]).

use serde::{Deserialize, Serialize};

use super::RegistrationMethod;
use crate::geometry::{PHYSICAL_KEYS, Perturbation};
use crate::{Error, Result};

/// One list of values per physical key; each value is a cell of its own. A `[perturbations.physical]`
/// table lists exactly the cells it wants: a key it leaves out has no cell (not the default's).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default = "PhysicalGrid::none")]
pub struct PhysicalGrid {
    pub src_dx_mm: Vec<f64>,
    pub src_dy_mm: Vec<f64>,
    pub src_dz_mm: Vec<f64>,
    pub det_dx_mm: Vec<f64>,
    pub det_dy_mm: Vec<f64>,
    pub det_dz_mm: Vec<f64>,
    pub det_roll_deg: Vec<f64>,
    pub det_tilt_u_deg: Vec<f64>,
    pub det_tilt_v_deg: Vec<f64>,
}

impl Default for PhysicalGrid {
    /// The sizes the literature reports (Warmerdam et al.: a 4 mm source or panel translation
    /// orthogonal to the imaging axis, a 2° panel rotation about it, panel tilts and magnification
    /// changes), one each: the focal spot and the detector 4 mm along u, the detector 10 mm farther
    /// from the source (+z), rolled 2° about the central ray and tilted 2° about its row axis; and the
    /// focal spot 2 mm and 50 mm along the central ray (Tersi & Stagni's worst-case focus-distance error,
    /// Jain et al.'s largest focal-spot mis-calibration).
    fn default() -> Self {
        PhysicalGrid {
            src_dx_mm: vec![4.0],
            src_dz_mm: vec![2.0, 50.0],
            det_dx_mm: vec![4.0],
            det_dz_mm: vec![10.0],
            det_roll_deg: vec![2.0],
            det_tilt_u_deg: vec![2.0],
            ..PhysicalGrid::none()
        }
    }
}

impl PhysicalGrid {
    /// No physical cell.
    pub fn none() -> Self {
        PhysicalGrid {
            src_dx_mm: Vec::new(),
            src_dy_mm: Vec::new(),
            src_dz_mm: Vec::new(),
            det_dx_mm: Vec::new(),
            det_dy_mm: Vec::new(),
            det_dz_mm: Vec::new(),
            det_roll_deg: Vec::new(),
            det_tilt_u_deg: Vec::new(),
            det_tilt_v_deg: Vec::new(),
        }
    }

    /// Each key with its values, in [`PHYSICAL_KEYS`] order.
    pub fn keys(&self) -> [(&'static str, &[f64]); 9] {
        let v = [
            &self.src_dx_mm,
            &self.src_dy_mm,
            &self.src_dz_mm,
            &self.det_dx_mm,
            &self.det_dy_mm,
            &self.det_dz_mm,
            &self.det_roll_deg,
            &self.det_tilt_u_deg,
            &self.det_tilt_v_deg,
        ];
        std::array::from_fn(|i| (PHYSICAL_KEYS[i], v[i].as_slice()))
    }

    /// The cells: each value of each key alone, keys in [`PHYSICAL_KEYS`] order; a value the
    /// perturbation syntax refuses (0, non-finite, beyond its limit, repeated) is an error naming
    /// `perturbations.physical.KEY`.
    pub fn cells(&self) -> Result<Vec<Perturbation>> {
        self.cells_of("perturbations.physical")
    }

    /// [`Self::cells`] of the grid at `table` (its errors name `TABLE.KEY`).
    pub fn cells_of(&self, table: &str) -> Result<Vec<Perturbation>> {
        let mut out = Vec::new();
        for (key, values) in self.keys() {
            let field = format!("{table}.{key}");
            for (i, v) in values.iter().enumerate() {
                if *v == 0.0 {
                    return Err(Error::invalid(
                        field,
                        "0 is no perturbation (the reference itself): leave it out",
                    ));
                }
                if values[..i].contains(v) {
                    return Err(Error::invalid(field, format!("{v} is listed twice")));
                }
                let p = Perturbation::parse(&format!("{key}={v}"))
                    .map_err(|e| Error::invalid(field.clone(), e.to_string()))?;
                out.push(p);
            }
        }
        Ok(out)
    }

    /// The first value of the first key that has one (the quick grid's smoke test of the family).
    pub fn first_only(&self) -> PhysicalGrid {
        let mut g = PhysicalGrid::none();
        if let Some((key, values)) = self.keys().into_iter().find(|(_, v)| !v.is_empty()) {
            let one = vec![values[0]];
            match key {
                "src_dx_mm" => g.src_dx_mm = one,
                "src_dy_mm" => g.src_dy_mm = one,
                "src_dz_mm" => g.src_dz_mm = one,
                "det_dx_mm" => g.det_dx_mm = one,
                "det_dy_mm" => g.det_dy_mm = one,
                "det_dz_mm" => g.det_dz_mm = one,
                "det_roll_deg" => g.det_roll_deg = one,
                "det_tilt_u_deg" => g.det_tilt_u_deg = one,
                _ => g.det_tilt_v_deg = one,
            }
        }
        g
    }
}

/// Trials `first..first + count` of the Monte-Carlo landmark registration of `target` by `method`
/// under one physical cell (table `registration_physical.csv`).
#[derive(Debug, Clone, PartialEq)]
pub struct RegistrationPhysicalCell {
    pub target: String,
    pub method: RegistrationMethod,
    pub perturbation: Perturbation,
    pub first: usize,
    pub count: usize,
}

impl RegistrationPhysicalCell {
    /// File-name-safe id (`+` of a method name is replaced by the caller's id rule).
    pub fn id(&self) -> String {
        let spec = self.perturbation.to_string().replace(['=', ','], "");
        format!(
            "regphys_{}_{}_{spec}_t{}",
            self.target, self.method, self.first
        )
    }

    /// The key of the cell's random draws (without the trial chunk: a trial draws the same numbers
    /// whatever `trials_per_unit` is).
    pub fn seed_key(&self) -> String {
        format!(
            "regphys/{}/{}/{}",
            self.target, self.method, self.perturbation
        )
    }

    pub fn describe(&self) -> String {
        format!(
            "registration of target '{}' by {} under the physical error {}, trials {}..{}",
            self.target,
            self.method,
            self.perturbation,
            self.first,
            self.first + self.count
        )
    }
}

/// The physical key a cell of the family sets and its value (`None` for a cell of another family).
pub fn cell_key(p: &Perturbation) -> Option<(&'static str, f64)> {
    let spec = p.to_string();
    let (key, value) = spec.split_once('=')?;
    let key = PHYSICAL_KEYS.into_iter().find(|k| *k == key)?;
    (!spec.contains(',')).then_some(())?;
    value.parse().ok().map(|v| (key, v))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_are_each_value_of_each_key_alone() {
        let g = PhysicalGrid {
            src_dy_mm: vec![-2.0, 3.0],
            det_roll_deg: vec![0.5],
            ..PhysicalGrid::none()
        };
        let cells = g.cells().unwrap();
        let specs: Vec<String> = cells.iter().map(|p| p.to_string()).collect();
        assert_eq!(specs, ["src_dy_mm=-2", "src_dy_mm=3", "det_roll_deg=0.5"]);
        assert_eq!(cell_key(&cells[2]), Some(("det_roll_deg", 0.5)));
        assert_eq!(cell_key(&Perturbation::focal(100.0)), None);
        assert_eq!(g.first_only().cells().unwrap().len(), 1);
        for (bad, says) in [
            (vec![0.0], "0 is no perturbation"),
            (vec![1.0, 1.0], "listed twice"),
            (vec![700.0], "beyond"),
        ] {
            let g = PhysicalGrid {
                det_dz_mm: bad,
                ..PhysicalGrid::none()
            };
            let e = g.cells().unwrap_err().to_string();
            assert!(
                e.contains("perturbations.physical.det_dz_mm") && e.contains(says),
                "{e}"
            );
        }
    }
}
