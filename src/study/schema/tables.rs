//! `tables/*.csv`: tidy tables, one row per measurement, written and read with the `csv` crate.

use std::path::Path;

use serde::Serialize;
use serde::de::DeserializeOwned;

use super::{
    CalibrationAmbiguityRow, CalibrationPhysicalRow, CalibrationRow, CalibrationToleranceRow,
    IntensityBinRow, IntensityRow, IntensitySummaryRow, LandmarkRow, PhysicalRow, ProjectionRow,
    RegistrationPhysicalRow, RegistrationRow, RegistrationSummaryRow, ScrewNavigationRow, ScrewRow,
    StructureRow, TrackingRow, UnitRows,
};
use crate::io::write_atomic_bytes;
use crate::{Error, Result};

/// A row type and the table (`tables/<TABLE>.csv`) it belongs to.
pub trait TableRow: Serialize + DeserializeOwned {
    const TABLE: &'static str;
}

impl TableRow for ProjectionRow {
    const TABLE: &'static str = "projection";
}
impl TableRow for StructureRow {
    const TABLE: &'static str = "structures";
}
impl TableRow for LandmarkRow {
    const TABLE: &'static str = "landmarks";
}
impl TableRow for RegistrationRow {
    const TABLE: &'static str = "registration";
}
impl TableRow for RegistrationSummaryRow {
    const TABLE: &'static str = "registration_summary";
}
impl TableRow for CalibrationRow {
    const TABLE: &'static str = "calibration";
}
impl TableRow for CalibrationToleranceRow {
    const TABLE: &'static str = "calibration_tolerance";
}
impl TableRow for CalibrationAmbiguityRow {
    const TABLE: &'static str = "calibration_ambiguity";
}
impl TableRow for IntensityRow {
    const TABLE: &'static str = "intensity_registration";
}
impl TableRow for IntensityBinRow {
    const TABLE: &'static str = "intensity_registration_bins";
}
impl TableRow for IntensitySummaryRow {
    const TABLE: &'static str = "intensity_registration_summary";
}
impl TableRow for PhysicalRow {
    const TABLE: &'static str = "physical";
}
impl TableRow for TrackingRow {
    const TABLE: &'static str = "tracking";
}
impl TableRow for RegistrationPhysicalRow {
    const TABLE: &'static str = "registration_physical";
}
impl TableRow for CalibrationPhysicalRow {
    const TABLE: &'static str = "calibration_physical";
}
impl TableRow for ScrewRow {
    const TABLE: &'static str = "screws";
}
impl TableRow for ScrewNavigationRow {
    const TABLE: &'static str = "screw_navigation";
}

fn table_path<R: TableRow>(dir: &Path) -> std::path::PathBuf {
    dir.join(format!("{}.csv", R::TABLE))
}

/// Writes `dir/<table>.csv` (header from the field names, then `rows`) atomically.
pub fn write_rows<R: TableRow>(dir: &Path, rows: &[R]) -> Result<()> {
    let what = || format!("table {}", R::TABLE);
    let mut w = csv::Writer::from_writer(Vec::new());
    for r in rows {
        w.serialize(r).map_err(|e| Error::encode(what(), e))?;
    }
    let bytes = w.into_inner().map_err(|e| Error::encode(what(), e))?;
    write_atomic_bytes(&table_path::<R>(dir), &bytes)
}

/// Reads `dir/<table>.csv`; an absent table has no rows.
pub fn read_rows<R: TableRow>(dir: &Path) -> Result<Vec<R>> {
    let path = table_path::<R>(dir);
    if !path.exists() {
        return Ok(Vec::new());
    }
    let mut r = csv::Reader::from_path(&path).map_err(|e| Error::format(&path, e.to_string()))?;
    r.deserialize()
        .collect::<std::result::Result<Vec<R>, _>>()
        .map_err(|e| Error::format(&path, e.to_string()))
}

/// Every table of a study, typed.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StudyTables {
    pub projection: Vec<ProjectionRow>,
    pub structures: Vec<StructureRow>,
    pub landmarks: Vec<LandmarkRow>,
    pub registration: Vec<RegistrationRow>,
    pub registration_summary: Vec<RegistrationSummaryRow>,
    pub calibration: Vec<CalibrationRow>,
    pub calibration_tolerance: Vec<CalibrationToleranceRow>,
    pub calibration_ambiguity: Vec<CalibrationAmbiguityRow>,
    pub intensity: Vec<IntensityRow>,
    pub intensity_bins: Vec<IntensityBinRow>,
    pub intensity_summary: Vec<IntensitySummaryRow>,
    pub physical: Vec<PhysicalRow>,
    pub tracking: Vec<TrackingRow>,
    pub registration_physical: Vec<RegistrationPhysicalRow>,
    pub calibration_physical: Vec<CalibrationPhysicalRow>,
    pub screws: Vec<ScrewRow>,
    pub screw_navigation: Vec<ScrewNavigationRow>,
}

impl StudyTables {
    /// The tables of the units' rows, concatenated in the given (unit) order, with the registration
    /// summary computed from them.
    pub fn from_units(units: impl IntoIterator<Item = UnitRows>) -> StudyTables {
        let mut t = StudyTables::default();
        for u in units {
            t.projection.extend(u.projection);
            t.structures.extend(u.structures);
            t.landmarks.extend(u.landmarks);
            t.registration.extend(u.registration);
            t.calibration.extend(u.calibration);
            t.intensity.extend(u.intensity);
            t.physical.extend(u.physical);
            t.tracking.extend(u.tracking);
            t.registration_physical.extend(u.registration_physical);
            t.calibration_physical.extend(u.calibration_physical);
            t.screws.extend(u.screws);
            t.screw_navigation.extend(u.screw_navigation);
        }
        t.registration_summary = summarize_registration(&t.registration);
        t.calibration_tolerance = super::calibration::tolerance(&t.calibration);
        t.calibration_ambiguity = super::calibration::ambiguity(&t.calibration);
        t.intensity_bins = super::intensity::bins(&t.intensity);
        t.intensity_summary = super::intensity::summary(&t.intensity);
        t
    }

    /// Writes every non-empty table to `dir` (`out/tables`); returns how many.
    pub fn write(&self, dir: &Path) -> Result<usize> {
        fn put<R: TableRow>(dir: &Path, rows: &[R], n: &mut usize) -> Result<()> {
            if !rows.is_empty() {
                write_rows(dir, rows)?;
                *n += 1;
            }
            Ok(())
        }
        let mut n = 0;
        put(dir, &self.projection, &mut n)?;
        put(dir, &self.structures, &mut n)?;
        put(dir, &self.landmarks, &mut n)?;
        put(dir, &self.registration, &mut n)?;
        put(dir, &self.registration_summary, &mut n)?;
        put(dir, &self.calibration, &mut n)?;
        put(dir, &self.calibration_tolerance, &mut n)?;
        put(dir, &self.calibration_ambiguity, &mut n)?;
        put(dir, &self.intensity, &mut n)?;
        put(dir, &self.intensity_bins, &mut n)?;
        put(dir, &self.intensity_summary, &mut n)?;
        put(dir, &self.physical, &mut n)?;
        put(dir, &self.tracking, &mut n)?;
        put(dir, &self.registration_physical, &mut n)?;
        put(dir, &self.calibration_physical, &mut n)?;
        put(dir, &self.screws, &mut n)?;
        put(dir, &self.screw_navigation, &mut n)?;
        Ok(n)
    }

    /// Reads each table of the study in `out` (`out/tables/*.csv`) once; absent tables are empty.
    pub fn load(out: &Path) -> Result<StudyTables> {
        let dir = out.join("tables");
        Ok(StudyTables {
            projection: read_rows(&dir)?,
            structures: read_rows(&dir)?,
            landmarks: read_rows(&dir)?,
            registration: read_rows(&dir)?,
            registration_summary: read_rows(&dir)?,
            calibration: read_rows(&dir)?,
            calibration_tolerance: read_rows(&dir)?,
            calibration_ambiguity: read_rows(&dir)?,
            intensity: read_rows(&dir)?,
            intensity_bins: read_rows(&dir)?,
            intensity_summary: read_rows(&dir)?,
            physical: read_rows(&dir)?,
            tracking: read_rows(&dir)?,
            registration_physical: read_rows(&dir)?,
            calibration_physical: read_rows(&dir)?,
            screws: read_rows(&dir)?,
            screw_navigation: read_rows(&dir)?,
        })
    }
}

/// Mean and sample standard deviation of the finite values.
pub fn mean_sd(v: &[f64]) -> (f64, f64) {
    let x: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if x.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    let var = if x.len() > 1 {
        x.iter().map(|a| (a - m).powi(2)).sum::<f64>() / (n - 1.0)
    } else {
        0.0
    };
    (m, var.sqrt())
}

/// The 95 % confidence half-width of a mean of `n` values with sample standard deviation `sd`:
/// t(0.975, n − 1)·sd/√n (NaN for n < 2).
pub fn ci95_half_width(sd: f64, n: usize) -> f64 {
    if n < 2 {
        return f64::NAN;
    }
    distrs::StudentsT::ppf(0.975, (n - 1) as f64) * sd / (n as f64).sqrt()
}

/// Spread (sample sd, in the error's unit: deg, mm, px) below which a registration cell's trials count
/// as one value: the solver's convergence tolerance, far below any observation noise worth modelling.
pub const SOLVER_SPREAD: f64 = 1e-4;

/// Per (target, method, Δf, piercing) the mean and spread over trials, in the order the cells first
/// appear in `rows`.
fn summarize_registration(rows: &[RegistrationRow]) -> Vec<RegistrationSummaryRow> {
    let same_cell = |a: &RegistrationRow, b: &RegistrationRow| {
        a.target == b.target
            && a.method == b.method
            && a.df_px.to_bits() == b.df_px.to_bits()
            && a.piercing_px.to_bits() == b.piercing_px.to_bits()
    };
    let mut cells: Vec<Vec<&RegistrationRow>> = Vec::new();
    for r in rows {
        match cells.iter_mut().find(|c| same_cell(c[0], r)) {
            Some(c) => c.push(r),
            None => cells.push(vec![r]),
        }
    }
    cells
        .into_iter()
        .map(|c| {
            // A trial succeeded when its solve converged to finite errors; the statistics are over
            // those. A solve that errored (NaN) or stopped without converging (its cap, or a pose that
            // cannot be the anatomy) is a failure, counted, never averaged in.
            let ok: Vec<&RegistrationRow> = c
                .iter()
                .copied()
                .filter(|r| r.converged && r.rot_err_deg.is_finite())
                .collect();
            let stat = |f: fn(&RegistrationRow) -> f64| {
                mean_sd(&ok.iter().map(|r| f(r)).collect::<Vec<_>>())
            };
            let (rot, trans, res) = (
                stat(|r| r.rot_err_deg),
                stat(|r| r.trans_err_mm),
                stat(|r| r.residual_px),
            );
            let n = ok.len();
            let failed = c.len() - n;
            let ci = |sd: f64| ci95_half_width(sd, n);
            RegistrationSummaryRow {
                target: c[0].target.clone(),
                method: c[0].method,
                df_px: c[0].df_px,
                piercing_px: c[0].piercing_px,
                trials: c.len(),
                failed,
                n,
                deterministic: n > 0 && [rot.1, trans.1, res.1].iter().all(|s| *s <= SOLVER_SPREAD),
                rot_err_deg_mean: rot.0,
                rot_err_deg_sd: rot.1,
                rot_err_deg_ci95: ci(rot.1),
                trans_err_mm_mean: trans.0,
                trans_err_mm_sd: trans.1,
                trans_err_mm_ci95: ci(trans.1),
                residual_px_mean: res.0,
                residual_px_sd: res.1,
                residual_px_ci95: ci(res.1),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::study::config::RegistrationMethod;
    use crate::study::schema::Family;

    #[test]
    fn mean_and_sample_sd_match_hand_values_and_skip_nan() {
        // mean 2.5; Σ(x − m)² = 5 → sample variance 5/3.
        let (m, s) = mean_sd(&[1.0, 2.0, f64::NAN, 3.0, 4.0]);
        assert_eq!(m, 2.5);
        assert!((s - (5.0f64 / 3.0).sqrt()).abs() < 1e-15);
        assert!(mean_sd(&[f64::NAN]).0.is_nan());
    }

    #[test]
    fn ci_half_width_uses_tabulated_student_t_quantiles() {
        // t(0.975, ν) from the standard tables: ν = 1: 12.706, 4: 2.776, 19: 2.093, ∞: 1.960.
        for (n, t) in [(2, 12.706), (5, 2.776), (20, 2.093), (100_001, 1.960)] {
            let h = ci95_half_width(2.0, n);
            assert!((h * (n as f64).sqrt() / 2.0 - t).abs() < 1e-3, "n {n}: {h}");
        }
        assert!(ci95_half_width(1.0, 1).is_nan());
    }

    fn trial(trial: usize, rot: f64) -> RegistrationRow {
        RegistrationRow {
            target: "L1".into(),
            method: RegistrationMethod::Kabsch,
            df_px: 100.0,
            piercing_px: 0.1 + 0.2,
            trial,
            rot_err_deg: rot,
            trans_err_mm: f64::NAN,
            residual_px: 2.5e-4,
            iterations: 7,
            converged: true,
        }
    }

    #[test]
    fn rows_round_trip_exactly_through_a_written_table_with_display_numbers() {
        let dir = tempfile::tempdir().unwrap();
        let rows = vec![trial(3, 1.0 / 3.0), trial(4, f64::NEG_INFINITY)];
        write_rows(dir.path(), &rows).unwrap();
        let text = std::fs::read_to_string(dir.path().join("registration.csv")).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines[0],
            "target,method,df_px,piercing_px,trial,rot_err_deg,trans_err_mm,residual_px,iterations,converged"
        );
        // `{}` Display, as the tables always had: `100`, not `100.0`; `NaN`, not an empty cell.
        assert_eq!(
            lines[1],
            "L1,kabsch,100,0.30000000000000004,3,0.3333333333333333,NaN,0.00025,7,true"
        );
        let back: Vec<RegistrationRow> = read_rows(dir.path()).unwrap();
        assert_eq!(back[0].piercing_px, 0.1 + 0.2);
        assert_eq!(back[0].rot_err_deg, 1.0 / 3.0);
        assert_eq!(back[1].rot_err_deg, f64::NEG_INFINITY);
        assert!(back[0].trans_err_mm.is_nan());
        assert_eq!(back[0].residual_px, 2.5e-4);
    }

    #[test]
    fn names_with_commas_and_quotes_are_quoted_and_come_back() {
        let dir = tempfile::tempdir().unwrap();
        let name = "tip, \"left\"";
        let row = StructureRow {
            target: "box".into(),
            view: "ap".into(),
            family: Family::Focal,
            df_px: 100.0,
            dcx_px: 0.0,
            dcy_px: -0.0,
            structure: name.into(),
            dice: 0.5,
            iou: 1.0 / 3.0,
        };
        write_rows(dir.path(), std::slice::from_ref(&row)).unwrap();
        let text = std::fs::read_to_string(dir.path().join("structures.csv")).unwrap();
        assert!(text.contains(",\"tip, \"\"left\"\"\","), "{text}");
        let back: Vec<StructureRow> = read_rows(dir.path()).unwrap();
        assert_eq!(back, vec![row]);
        assert!(back[0].dcy_px.is_sign_negative());
    }

    #[test]
    fn unit_rows_survive_json_with_nan_and_infinities() {
        let mut r = trial(0, f64::INFINITY);
        r.residual_px = 1e-300;
        let rows = UnitRows {
            registration: vec![r],
            ..UnitRows::default()
        };
        let text = serde_json::to_string(&rows).unwrap();
        assert!(
            text.contains("\"inf\"") && text.contains("\"NaN\""),
            "{text}"
        );
        let back: UnitRows = serde_json::from_str(&text).unwrap();
        assert_eq!(back.registration[0].rot_err_deg, f64::INFINITY);
        assert!(back.registration[0].trans_err_mm.is_nan());
        assert_eq!(back.registration[0].piercing_px, 0.1 + 0.2);
        assert_eq!(back.registration[0].residual_px, 1e-300);
    }

    #[test]
    fn summary_groups_cells_in_order_and_counts_failures() {
        let mut unconverged = trial(3, 100.0);
        unconverged.converged = false;
        let mut rows = vec![
            trial(0, 1.0),
            trial(1, f64::NAN),
            trial(2, 3.0),
            unconverged,
        ];
        let mut other = trial(0, 5.0);
        other.method = RegistrationMethod::DirectAp;
        rows.insert(1, other);
        let s = summarize_registration(&rows);
        assert_eq!(s.len(), 2);
        assert_eq!(
            (s[0].method, s[0].trials, s[0].failed, s[0].n),
            (RegistrationMethod::Kabsch, 4, 2, 2)
        );
        assert_eq!(s[0].rot_err_deg_mean, 2.0);
        assert_eq!(s[0].rot_err_deg_sd, 2f64.sqrt());
        assert_eq!(
            (s[1].method, s[1].trials),
            (RegistrationMethod::DirectAp, 1)
        );
    }
}
