//! CSV tables: tidy, one row per measurement, units in column names. Numbers are written with Rust's
//! shortest round-trip formatting, so a table read back gives the exact f64 the study computed.

use std::collections::BTreeMap;
use std::path::Path;

use super::units::{LandmarkRow, ProjectionRow, RegistrationRow, StructureRow, UnitRows};
use crate::{Error, Result};

/// Table names, in the order they are written.
pub const TABLES: [&str; 5] = [
    "projection",
    "structures",
    "landmarks",
    "registration",
    "registration_summary",
];

/// A row that knows its CSV header and fields.
pub trait CsvRow {
    const HEADER: &'static str;
    fn fields(&self) -> Vec<String>;
    fn line(&self) -> String {
        self.fields().join(",")
    }
}

fn f(x: f64) -> String {
    format!("{x}")
}

impl CsvRow for ProjectionRow {
    const HEADER: &'static str = "target,view,family,df_px,dcx_px,dcy_px,skew_px,sy,dice,iou,\
chamfer_mean_px,hausdorff_px,hd95_px,edge_distance_mean_px,ncc,ssim,mutual_information_nats,\
gradient_correlation,mean_abs_diff_per_mm";
    fn fields(&self) -> Vec<String> {
        let mut v = vec![self.target.clone(), self.view.clone(), self.family.clone()];
        v.extend(
            [
                self.df_px,
                self.dcx_px,
                self.dcy_px,
                self.skew_px,
                self.sy,
                self.dice,
                self.iou,
                self.chamfer_mean_px,
                self.hausdorff_px,
                self.hd95_px,
                self.edge_distance_mean_px,
                self.ncc,
                self.ssim,
                self.mutual_information_nats,
                self.gradient_correlation,
                self.mean_abs_diff_per_mm,
            ]
            .map(f),
        );
        v
    }
}

impl CsvRow for StructureRow {
    const HEADER: &'static str = "target,view,family,df_px,dcx_px,dcy_px,structure,dice,iou";
    fn fields(&self) -> Vec<String> {
        let mut v = vec![self.target.clone(), self.view.clone(), self.family.clone()];
        v.extend([self.df_px, self.dcx_px, self.dcy_px].map(f));
        v.push(self.structure.clone());
        v.extend([self.dice, self.iou].map(f));
        v
    }
}

impl CsvRow for LandmarkRow {
    const HEADER: &'static str = "target,view,family,df_px,dcx_px,dcy_px,landmark,ref_u_px,ref_v_px,\
meas_u_px,meas_v_px,shift_px,pred_u_px,pred_v_px,pred_shift_px,pred_error_px";
    fn fields(&self) -> Vec<String> {
        let mut v = vec![self.target.clone(), self.view.clone(), self.family.clone()];
        v.extend([self.df_px, self.dcx_px, self.dcy_px].map(f));
        v.push(self.landmark.clone());
        v.extend(
            [
                self.ref_u_px,
                self.ref_v_px,
                self.meas_u_px,
                self.meas_v_px,
                self.shift_px,
                self.pred_u_px,
                self.pred_v_px,
                self.pred_shift_px,
                self.pred_error_px,
            ]
            .map(f),
        );
        v
    }
}

impl CsvRow for RegistrationRow {
    const HEADER: &'static str = "target,method,df_px,piercing_px,trial,rot_err_deg,trans_err_mm,\
residual_px,iterations,converged";
    fn fields(&self) -> Vec<String> {
        let mut v = vec![self.target.clone(), self.method.clone()];
        v.extend([self.df_px, self.piercing_px].map(f));
        v.push(self.trial.to_string());
        v.extend([self.rot_err_deg, self.trans_err_mm, self.residual_px].map(f));
        v.push(self.iterations.to_string());
        v.push(self.converged.to_string());
        v
    }
}

/// The header of each table.
pub fn header(table: &str) -> &'static str {
    match table {
        "projection" => ProjectionRow::HEADER,
        "structures" => StructureRow::HEADER,
        "landmarks" => LandmarkRow::HEADER,
        "registration" => RegistrationRow::HEADER,
        _ => SUMMARY_HEADER,
    }
}

/// A unit's rows as CSV lines per table (empty tables omitted).
pub fn unit_lines(rows: &UnitRows) -> BTreeMap<String, Vec<String>> {
    let mut m = BTreeMap::new();
    let mut put = |name: &str, lines: Vec<String>| {
        if !lines.is_empty() {
            m.insert(name.to_string(), lines);
        }
    };
    put(
        "projection",
        rows.projection.iter().map(CsvRow::line).collect(),
    );
    put(
        "structures",
        rows.structures.iter().map(CsvRow::line).collect(),
    );
    put(
        "landmarks",
        rows.landmarks.iter().map(CsvRow::line).collect(),
    );
    put(
        "registration",
        rows.registration.iter().map(CsvRow::line).collect(),
    );
    m
}

/// Writes `dir/<table>.csv` from header + lines, atomically.
pub fn write_table(dir: &Path, table: &str, lines: &[String]) -> Result<()> {
    let path = dir.join(format!("{table}.csv"));
    let mut text = String::from(header(table));
    text.push('\n');
    for l in lines {
        text.push_str(l);
        text.push('\n');
    }
    crate::io::write_atomic_bytes(&path, text.as_bytes())
}

/// A parsed CSV table: header names and string cells.
#[derive(Debug, Clone)]
pub struct Table {
    pub columns: Vec<String>,
    pub rows: Vec<Vec<String>>,
}

impl Table {
    /// Reads a table written by [`write_table`] (no quoting: our cells never hold commas).
    pub fn read(path: &Path) -> Result<Table> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let mut lines = text.lines();
        let columns: Vec<String> = lines
            .next()
            .ok_or_else(|| Error::format(path, "empty table"))?
            .split(',')
            .map(String::from)
            .collect();
        let rows: Vec<Vec<String>> = lines
            .map(|l| l.split(',').map(String::from).collect::<Vec<_>>())
            .collect();
        if let Some(r) = rows.iter().find(|r| r.len() != columns.len()) {
            return Err(Error::format(
                path,
                format!("row has {} cells, header {}", r.len(), columns.len()),
            ));
        }
        Ok(Table { columns, rows })
    }

    /// Index of column `name`.
    pub fn col(&self, name: &str) -> Result<usize> {
        self.columns
            .iter()
            .position(|c| c == name)
            .ok_or_else(|| Error::invalid("column", format!("no column '{name}'")))
    }

    /// Cell `name` of `row` as f64 (NaN when unparsable).
    pub fn num(&self, row: &[String], name: &str) -> Result<f64> {
        Ok(row[self.col(name)?].parse().unwrap_or(f64::NAN))
    }

    /// Cell `name` of `row`.
    pub fn str<'a>(&self, row: &'a [String], name: &str) -> Result<&'a str> {
        Ok(&row[self.col(name)?])
    }
}

const SUMMARY_HEADER: &str = "target,method,df_px,piercing_px,trials,failed,rot_err_deg_mean,\
rot_err_deg_sd,trans_err_mm_mean,trans_err_mm_sd,residual_px_mean,residual_px_sd";

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

/// `registration_summary.csv`: per (target, method, Δf, piercing) the mean and spread over trials,
/// in the order the cells first appear in `registration.csv`.
pub fn summarize_registration(dir: &Path) -> Result<()> {
    let t = Table::read(&dir.join("registration.csv"))?;
    let mut order: Vec<String> = Vec::new();
    let mut cells: BTreeMap<String, Vec<[f64; 3]>> = BTreeMap::new();
    for r in &t.rows {
        let key = [
            t.str(r, "target")?,
            t.str(r, "method")?,
            t.str(r, "df_px")?,
            t.str(r, "piercing_px")?,
        ]
        .join(",");
        let vals = [
            t.num(r, "rot_err_deg")?,
            t.num(r, "trans_err_mm")?,
            t.num(r, "residual_px")?,
        ];
        if !cells.contains_key(&key) {
            order.push(key.clone());
        }
        cells.entry(key).or_default().push(vals);
    }
    let mut lines = Vec::new();
    for key in order {
        let v = &cells[&key];
        let failed = v.iter().filter(|x| !x[0].is_finite()).count();
        let mut line = format!("{key},{},{failed}", v.len());
        for i in 0..3 {
            let (m, s) = mean_sd(&v.iter().map(|x| x[i]).collect::<Vec<_>>());
            line.push_str(&format!(",{},{}", f(m), f(s)));
        }
        lines.push(line);
    }
    write_table(dir, "registration_summary", &lines)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_and_sample_sd_match_hand_values_and_skip_nan() {
        // mean 2.5; Σ(x − m)² = 5 → sample variance 5/3.
        let (m, s) = mean_sd(&[1.0, 2.0, f64::NAN, 3.0, 4.0]);
        assert_eq!(m, 2.5);
        assert!((s - (5.0f64 / 3.0).sqrt()).abs() < 1e-15);
        assert!(mean_sd(&[f64::NAN]).0.is_nan());
    }

    #[test]
    fn rows_round_trip_exactly_through_a_written_table() {
        let dir = tempfile::tempdir().unwrap();
        let row = RegistrationRow {
            target: "L1".into(),
            method: "kabsch".into(),
            df_px: 100.0,
            piercing_px: 0.1 + 0.2,
            trial: 3,
            rot_err_deg: 1.0 / 3.0,
            trans_err_mm: f64::NAN,
            residual_px: 1e-300,
            iterations: 7,
            converged: true,
        };
        write_table(dir.path(), "registration", &[row.line()]).unwrap();
        let t = Table::read(&dir.path().join("registration.csv")).unwrap();
        let r = &t.rows[0];
        assert_eq!(t.num(r, "piercing_px").unwrap(), 0.1 + 0.2);
        assert_eq!(t.num(r, "rot_err_deg").unwrap(), 1.0 / 3.0);
        assert_eq!(t.num(r, "residual_px").unwrap(), 1e-300);
        assert!(t.num(r, "trans_err_mm").unwrap().is_nan());
        assert_eq!(t.str(r, "converged").unwrap(), "true");
    }
}
