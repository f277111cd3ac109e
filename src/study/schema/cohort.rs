//! The cohort tables (`tables/cohort.csv`, `tables/cohort_left_out.csv`): the spread of every metric
//! across patients, per perturbation cell.
//!
//! A sample is one (case, level) target of a dataset (the segment targets, several levels at once,
//! are not samples). For each metric and cell, scope `pooled` summarises the samples of every case,
//! and scope `<dataset>/<case>` those of one case (its levels): n, mean, sample standard deviation,
//! median and the 5th/95th percentiles. Non-finite values (a landmark off the detector, a failed
//! solve) are left out and not counted in n. Percentiles interpolate linearly between order
//! statistics (position p·(n − 1) in the sorted values: R's type 7, numpy's default).
//!
//! Cells: projection metrics per (view, family, Δf, Δcx, Δcy, skew, sy); landmark shifts per (view,
//! family, Δf, Δcx, Δcy) and landmark, plus landmark `*`, where a sample is the target's mean shift
//! over its landmarks; registration errors per (method, Δf, piercing) (Δcx = Δcy = the piercing shift),
//! a sample being the target's mean over its trials.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::tables::{TableRow, mean_sd};
use super::{LandmarkRow, ProjectionRow, RegistrationSummaryRow, StudyTables, num};

/// One metric in one cell, over the samples of one scope.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CohortRow {
    /// `pooled`, or `<dataset>/<case>`.
    pub scope: String,
    /// The table the samples come from: `projection`, `landmarks` or `registration`.
    pub table: String,
    pub metric: String,
    /// View (empty for registration).
    pub view: String,
    /// Registration method (empty otherwise).
    pub method: String,
    /// Perturbation family (empty for registration).
    pub family: String,
    #[serde(with = "num")]
    pub df_px: f64,
    #[serde(with = "num")]
    pub dcx_px: f64,
    #[serde(with = "num")]
    pub dcy_px: f64,
    #[serde(with = "num")]
    pub skew_px: f64,
    #[serde(with = "num")]
    pub sy: f64,
    /// Landmark name (`*`: the mean over a target's landmarks; empty for other tables).
    pub landmark: String,
    pub n: usize,
    #[serde(with = "num")]
    pub mean: f64,
    #[serde(with = "num")]
    pub sd: f64,
    #[serde(with = "num")]
    pub median: f64,
    #[serde(with = "num")]
    pub p5: f64,
    #[serde(with = "num")]
    pub p95: f64,
}

/// A case left out of the cohort (table `cohort_left_out.csv`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LeftOutRow {
    pub dataset: String,
    pub case: String,
    pub file: String,
    pub reason: String,
}

impl TableRow for CohortRow {
    const TABLE: &'static str = "cohort";
}
impl TableRow for LeftOutRow {
    const TABLE: &'static str = "cohort_left_out";
}

/// Summary statistics of the finite values of a sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stats {
    pub n: usize,
    pub mean: f64,
    pub sd: f64,
    pub median: f64,
    pub p5: f64,
    pub p95: f64,
}

/// The `p`-quantile (0 ≤ p ≤ 1) of sorted finite values, linear between order statistics.
pub fn quantile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let h = p * (sorted.len() - 1) as f64;
    let (lo, hi) = (h.floor() as usize, h.ceil() as usize);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

/// [`Stats`] of the finite values of `v` (all NaN when none; sd 0 for one value, as [`mean_sd`]).
pub fn stats(v: &[f64]) -> Stats {
    let mut x: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    x.sort_by(f64::total_cmp);
    let (mean, sd) = mean_sd(&x);
    Stats {
        n: x.len(),
        mean,
        sd,
        median: quantile(&x, 0.5),
        p5: quantile(&x, 0.05),
        p95: quantile(&x, 0.95),
    }
}

/// Which case (`<dataset>/<case>`) a target is a level of; targets not in the map are not samples.
pub type CaseOf = BTreeMap<String, String>;

/// A cell key: everything but the scope, the metric value and the statistics.
#[derive(Debug, Clone, PartialEq)]
struct Cell {
    table: &'static str,
    metric: &'static str,
    view: String,
    method: String,
    family: String,
    q: [f64; 5],
    landmark: String,
}

impl Cell {
    fn same(&self, o: &Cell) -> bool {
        self.table == o.table
            && self.metric == o.metric
            && self.view == o.view
            && self.method == o.method
            && self.family == o.family
            && self.landmark == o.landmark
            && self
                .q
                .iter()
                .zip(&o.q)
                .all(|(a, b)| a.to_bits() == b.to_bits())
    }
}

/// Samples per cell, each with its case, in the order the cells first appear.
#[derive(Default)]
struct Samples(Vec<(Cell, Vec<(String, f64)>)>);

impl Samples {
    fn push(&mut self, cell: Cell, case: &str, v: f64) {
        match self.0.iter_mut().find(|(c, _)| c.same(&cell)) {
            Some((_, s)) => s.push((case.to_string(), v)),
            None => self.0.push((cell, vec![(case.to_string(), v)])),
        }
    }
}

type ProjectionMetric = (&'static str, fn(&ProjectionRow) -> f64);

/// The projection metrics summarised.
pub const PROJECTION_METRICS: [ProjectionMetric; 11] = [
    ("dice", |r| r.dice),
    ("iou", |r| r.iou),
    ("chamfer_mean_px", |r| r.chamfer_mean_px),
    ("hausdorff_px", |r| r.hausdorff_px),
    ("hd95_px", |r| r.hd95_px),
    ("edge_distance_mean_px", |r| r.edge_distance_mean_px),
    ("ncc", |r| r.ncc),
    ("ssim", |r| r.ssim),
    ("mutual_information_nats", |r| r.mutual_information_nats),
    ("gradient_correlation", |r| r.gradient_correlation),
    ("mean_abs_diff", |r| r.mean_abs_diff),
];

type RegistrationMetric = (&'static str, fn(&RegistrationSummaryRow) -> f64);

const REGISTRATION_METRICS: [RegistrationMetric; 3] = [
    ("rot_err_deg", |r| r.rot_err_deg_mean),
    ("trans_err_mm", |r| r.trans_err_mm_mean),
    ("residual_px", |r| r.residual_px_mean),
];

fn projection_samples(rows: &[ProjectionRow], case_of: &CaseOf, s: &mut Samples) {
    for r in rows {
        let Some(case) = case_of.get(&r.target) else {
            continue;
        };
        for (metric, f) in PROJECTION_METRICS {
            let cell = Cell {
                table: "projection",
                metric,
                view: r.view.clone(),
                method: String::new(),
                family: r.family.to_string(),
                q: [r.df_px, r.dcx_px, r.dcy_px, r.skew_px, r.sy],
                landmark: String::new(),
            };
            s.push(cell, case, f(r));
        }
    }
}

fn landmark_samples(rows: &[LandmarkRow], case_of: &CaseOf, s: &mut Samples) {
    let cell = |r: &LandmarkRow, metric: &'static str, landmark: &str| Cell {
        table: "landmarks",
        metric,
        view: r.view.clone(),
        method: String::new(),
        family: r.family.to_string(),
        q: [r.df_px, r.dcx_px, r.dcy_px, 0.0, 1.0],
        landmark: landmark.to_string(),
    };
    // Per target and cell, the landmarks' shifts (for the `*` sample: their mean).
    let mut per_target: Vec<(Cell, String, Vec<f64>)> = Vec::new();
    for r in rows {
        let Some(case) = case_of.get(&r.target) else {
            continue;
        };
        s.push(cell(r, "shift_px", &r.landmark), case, r.shift_px);
        s.push(cell(r, "pred_error_px", &r.landmark), case, r.pred_error_px);
        let all = cell(r, "shift_px", "*");
        let key = format!("{}\u{1f}{}", r.target, case);
        match per_target
            .iter_mut()
            .find(|(c, k, _)| *k == key && c.same(&all))
        {
            Some((_, _, v)) => v.push(r.shift_px),
            None => per_target.push((all, key, vec![r.shift_px])),
        }
    }
    for (c, key, v) in per_target {
        let case = key.split('\u{1f}').nth(1).unwrap_or_default().to_string();
        s.push(c, &case, mean_sd(&v).0);
    }
}

fn registration_samples(rows: &[RegistrationSummaryRow], case_of: &CaseOf, s: &mut Samples) {
    for r in rows {
        let Some(case) = case_of.get(&r.target) else {
            continue;
        };
        for (metric, f) in REGISTRATION_METRICS {
            let cell = Cell {
                table: "registration",
                metric,
                view: String::new(),
                method: r.method.to_string(),
                family: String::new(),
                q: [r.df_px, r.piercing_px, r.piercing_px, 0.0, 1.0],
                landmark: String::new(),
            };
            s.push(cell, case, f(r));
        }
    }
}

fn row(scope: &str, c: &Cell, st: Stats) -> CohortRow {
    CohortRow {
        scope: scope.to_string(),
        table: c.table.to_string(),
        metric: c.metric.to_string(),
        view: c.view.clone(),
        method: c.method.clone(),
        family: c.family.clone(),
        df_px: c.q[0],
        dcx_px: c.q[1],
        dcy_px: c.q[2],
        skew_px: c.q[3],
        sy: c.q[4],
        landmark: c.landmark.clone(),
        n: st.n,
        mean: st.mean,
        sd: st.sd,
        median: st.median,
        p5: st.p5,
        p95: st.p95,
    }
}

/// The cohort table of `tables`: per cell, the pooled row, then one row per case (cases in order
/// of first appearance); cells in the order of the study's tables.
pub fn cohort_rows(tables: &StudyTables, case_of: &CaseOf) -> Vec<CohortRow> {
    let mut s = Samples::default();
    projection_samples(&tables.projection, case_of, &mut s);
    landmark_samples(&tables.landmarks, case_of, &mut s);
    registration_samples(&tables.registration_summary, case_of, &mut s);
    let mut out = Vec::new();
    for (cell, samples) in &s.0 {
        let all: Vec<f64> = samples.iter().map(|(_, v)| *v).collect();
        out.push(row("pooled", cell, stats(&all)));
        let mut cases: Vec<&str> = Vec::new();
        for (c, _) in samples {
            if !cases.contains(&c.as_str()) {
                cases.push(c);
            }
        }
        for case in cases {
            let v: Vec<f64> = samples
                .iter()
                .filter(|(c, _)| c == case)
                .map(|(_, v)| *v)
                .collect();
            out.push(row(case, cell, stats(&v)));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_interpolate_between_order_statistics() {
        let x = [1.0, 2.0, 3.0, 4.0, 5.0];
        assert_eq!(quantile(&x, 0.5), 3.0);
        // h = 0.05 · 4 = 0.2: 1 + 0.2 · (2 − 1).
        assert!((quantile(&x, 0.05) - 1.2).abs() < 1e-12);
        assert!((quantile(&x, 0.95) - 4.8).abs() < 1e-12);
        assert_eq!(quantile(&[7.0], 0.95), 7.0);
        assert!(quantile(&[], 0.5).is_nan());
        let s = stats(&[3.0, f64::NAN, 1.0, 2.0]);
        assert_eq!((s.n, s.mean, s.sd, s.median), (3, 2.0, 1.0, 2.0));
    }
}
