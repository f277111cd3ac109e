//! Tables of the intensity-registration experiment: one row per start (`intensity_registration.csv`),
//! per cell and initial-mTRE bin (`intensity_registration_bins.csv`: the van de Kraats success rate) and
//! per cell (`intensity_registration_summary.csv`: success rate, capture range, final mTRE mean/sd).

use serde::{Deserialize, Serialize};

use super::{mean_sd, num};
use crate::registration::intensity::{
    BinSummary, SUCCESS_MTRE_MM, TrialOutcome, capture_range_mm, summarise,
};

/// How far from the truth (mTRE, mm) the searches of the intensity optimum in a cell's bins after the
/// first start: far enough to leave the truth's rounding-level neighbourhood (on a flat valley floor the
/// optimiser's path, not only the optimum, decides where it stops), well inside the capture ranges
/// measured.
pub const OPTIMUM_RESTART_MM: f64 = 0.5;

/// One registration from one start.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IntensityRow {
    pub target: String,
    /// View set (`ap`, `lat`, `ap+lat`).
    pub views: String,
    #[serde(with = "num")]
    pub df_px: f64,
    #[serde(with = "num")]
    pub piercing_px: f64,
    /// The physical error of a physical cell (`src_dx_mm=4`; Δf and piercing are then 0), empty for
    /// a Δf × piercing cell.
    #[serde(default)]
    pub physical: String,
    /// The fixed images' model: `mono` or `spectral` (`[intensity_registration] images`).
    #[serde(default = "mono")]
    pub fixed_image: String,
    pub bin: usize,
    #[serde(with = "num")]
    pub bin_lo_mm: f64,
    #[serde(with = "num")]
    pub bin_hi_mm: f64,
    pub start: usize,
    #[serde(with = "num")]
    pub initial_mtre_mm: f64,
    /// mTRE of the registered pose to the true one over the level's target points.
    #[serde(with = "num")]
    pub final_mtre_mm: f64,
    pub success: bool,
    #[serde(with = "num")]
    pub rot_err_deg: f64,
    #[serde(with = "num")]
    pub trans_err_mm: f64,
    /// Mean projected target error through the true K of each view of the set (NaN when not in it).
    #[serde(with = "num")]
    pub ptre_ap_px: f64,
    #[serde(with = "num")]
    pub ptre_lat_px: f64,
    /// Final similarity (mean over the set's views) at the finest level.
    #[serde(with = "num")]
    pub similarity: f64,
    /// Pose evaluations (each renders every view of the set once).
    pub evaluations: u64,
    pub converged: bool,
    /// The registered pose (model → world): rotation vector (rad) and translation (mm).
    #[serde(with = "num")]
    pub rx: f64,
    #[serde(with = "num")]
    pub ry: f64,
    #[serde(with = "num")]
    pub rz: f64,
    #[serde(with = "num")]
    pub tx_mm: f64,
    #[serde(with = "num")]
    pub ty_mm: f64,
    #[serde(with = "num")]
    pub tz_mm: f64,
    /// Landmark registration of the same level under the same assumed K (direct LM over the set's
    /// views, the landmarks' true-K projections observed, started at the truth): its mTRE over the same
    /// target points.
    #[serde(with = "num")]
    pub landmark_mtre_mm: f64,
    /// Where this bin's search of the intensity optimum started: its mTRE to the truth (0 in the first
    /// bin, the truth itself; [`OPTIMUM_RESTART_MM`] in the others). NaN in a table written before the
    /// column existed (whose every search started at the truth).
    #[serde(default = "nan", with = "num")]
    pub optimum_start_mtre_mm: f64,
    /// The intensity optimum under this K (this bin's search: local stage only, from the start above):
    /// its mTRE to the truth, the calibration's bias free of capture failures.
    #[serde(with = "num")]
    pub optimum_mtre_mm: f64,
    /// The two optima side by side: their mTRE to each other over the target points, the distance of
    /// the target centre they place (mm) and the angle of the rotation between them (degrees). Under
    /// an inconsistent K they can have the same bias and still be different poses.
    #[serde(with = "num")]
    pub optimum_to_landmark_mm: f64,
    #[serde(with = "num")]
    pub optimum_to_landmark_centre_mm: f64,
    #[serde(with = "num")]
    pub optimum_to_landmark_rot_deg: f64,
    /// mTRE of this start's result to that optimum; `reached_optimum` when below the success radius.
    #[serde(with = "num")]
    pub to_optimum_mm: f64,
    pub reached_optimum: bool,
}

/// One initial-mTRE bin of one cell.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IntensityBinRow {
    pub target: String,
    pub views: String,
    #[serde(with = "num")]
    pub df_px: f64,
    #[serde(with = "num")]
    pub piercing_px: f64,
    /// The physical error of a physical cell (`src_dx_mm=4`; Δf and piercing are then 0), empty for
    /// a Δf × piercing cell.
    #[serde(default)]
    pub physical: String,
    /// The fixed images' model: `mono` or `spectral` (`[intensity_registration] images`).
    #[serde(default = "mono")]
    pub fixed_image: String,
    #[serde(with = "num")]
    pub bin_lo_mm: f64,
    #[serde(with = "num")]
    pub bin_hi_mm: f64,
    pub trials: usize,
    pub successes: usize,
    #[serde(with = "num")]
    pub success_rate: f64,
    /// Mean final mTRE of the successful starts (NaN without one).
    #[serde(with = "num")]
    pub final_mtre_success_mean_mm: f64,
    /// Share of the starts that ended within the success radius of the cell's intensity optimum.
    #[serde(with = "num")]
    pub reached_optimum_rate: f64,
}

/// One cell (target, view set, Δf, piercing) over every start.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IntensitySummaryRow {
    pub target: String,
    pub views: String,
    #[serde(with = "num")]
    pub df_px: f64,
    #[serde(with = "num")]
    pub piercing_px: f64,
    /// The physical error of a physical cell (`src_dx_mm=4`; Δf and piercing are then 0), empty for
    /// a Δf × piercing cell.
    #[serde(default)]
    pub physical: String,
    /// The fixed images' model: `mono` or `spectral` (`[intensity_registration] images`).
    #[serde(default = "mono")]
    pub fixed_image: String,
    pub trials: usize,
    pub successes: usize,
    #[serde(with = "num")]
    pub success_rate: f64,
    /// Upper edge of the last bin of the leading run (from 0 mm) with ≥ 95 % success.
    #[serde(with = "num")]
    pub capture_range_mm: f64,
    /// Final mTRE of the successful starts: mean and sample sd.
    #[serde(with = "num")]
    pub final_mtre_mean_mm: f64,
    #[serde(with = "num")]
    pub final_mtre_sd_mm: f64,
    /// Median final mTRE over every start.
    #[serde(with = "num")]
    pub final_mtre_median_mm: f64,
    #[serde(with = "num")]
    pub landmark_mtre_mm: f64,
    /// The intensity optimum's mTRE to the truth from the search started at the truth (the first bin's).
    #[serde(with = "num")]
    pub optimum_mtre_mm: f64,
    /// How many searches of the optimum the cell ran (one per bin: the first from the truth, the others
    /// from starts [`OPTIMUM_RESTART_MM`] away), and the largest minus the smallest of their optima's
    /// mTRE to the truth: how reproducible the bias is. NaN with one search, or when a search failed or
    /// its start is not recorded.
    #[serde(default)]
    pub optimum_searches: usize,
    #[serde(default = "nan", with = "num")]
    pub optimum_spread_mm: f64,
    /// See [`IntensityRow::optimum_to_landmark_mm`] and the two after it.
    #[serde(with = "num")]
    pub optimum_to_landmark_mm: f64,
    #[serde(with = "num")]
    pub optimum_to_landmark_centre_mm: f64,
    #[serde(with = "num")]
    pub optimum_to_landmark_rot_deg: f64,
    #[serde(with = "num")]
    pub reached_optimum_rate: f64,
    #[serde(with = "num")]
    pub evaluations_mean: f64,
}

/// The fixed-image model of a table written before the column existed.
fn mono() -> String {
    "mono".into()
}

/// A measurement a table written before its column existed does not have.
fn nan() -> f64 {
    f64::NAN
}

/// The cell's searches of the intensity optimum (one per bin): the row of the search started at the
/// truth (the first bin's), how many there were, and the spread of their optima's mTRE to the truth
/// (NaN with one, or when one failed or its start is unknown).
fn optimum_searches<'a>(c: &[&'a IntensityRow]) -> (&'a IntensityRow, usize, f64) {
    let mut first: Vec<&IntensityRow> = Vec::new();
    for r in c {
        if !first.iter().any(|f| f.bin == r.bin) {
            first.push(r);
        }
    }
    first.sort_by_key(|r| r.bin);
    // The search started at the truth (the first bin's; every search of an older table started there).
    let at_truth = first
        .iter()
        .copied()
        .find(|r| r.optimum_start_mtre_mm == 0.0)
        .unwrap_or(first[0]);
    let known = first
        .iter()
        .all(|r| r.optimum_mtre_mm.is_finite() && r.optimum_start_mtre_mm.is_finite());
    let spread = if first.len() < 2 || !known {
        f64::NAN
    } else {
        let (lo, hi) = first
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| {
                (lo.min(r.optimum_mtre_mm), hi.max(r.optimum_mtre_mm))
            });
        hi - lo
    };
    (at_truth, first.len(), spread)
}

/// The rows of each cell, in first-appearance order.
fn cells(rows: &[IntensityRow]) -> Vec<Vec<&IntensityRow>> {
    let mut out: Vec<Vec<&IntensityRow>> = Vec::new();
    for r in rows {
        let same = |a: &IntensityRow| {
            a.target == r.target
                && a.views == r.views
                && a.df_px == r.df_px
                && a.piercing_px == r.piercing_px
                && a.physical == r.physical
                && a.fixed_image == r.fixed_image
        };
        match out.iter_mut().find(|c| same(c[0])) {
            Some(c) => c.push(r),
            None => out.push(vec![r]),
        }
    }
    out
}

/// Bin edges of a cell's rows.
fn edges(c: &[&IntensityRow]) -> Vec<f64> {
    let nbins = c.iter().map(|r| r.bin + 1).max().unwrap_or(0);
    let mut e = vec![f64::NAN; nbins + 1];
    for r in c {
        e[r.bin] = r.bin_lo_mm;
        e[r.bin + 1] = r.bin_hi_mm;
    }
    e
}

fn outcomes(c: &[&IntensityRow]) -> Vec<TrialOutcome> {
    c.iter()
        .map(|r| TrialOutcome {
            bin: r.bin,
            initial_mtre_mm: r.initial_mtre_mm,
            final_mtre_mm: r.final_mtre_mm,
        })
        .collect()
}

fn bin_summaries(c: &[&IntensityRow]) -> Vec<BinSummary> {
    summarise(&edges(c), &outcomes(c))
}

fn reached_rate<'a>(rows: impl Iterator<Item = &'a &'a IntensityRow>) -> f64 {
    let (mut n, mut k) = (0usize, 0usize);
    for r in rows {
        n += 1;
        k += usize::from(r.reached_optimum);
    }
    if n == 0 {
        f64::NAN
    } else {
        k as f64 / n as f64
    }
}

/// The per-bin table.
pub fn bins(rows: &[IntensityRow]) -> Vec<IntensityBinRow> {
    let mut out = Vec::new();
    for c in cells(rows) {
        let r0 = c[0];
        for b in bin_summaries(&c).into_iter().filter(|b| b.trials > 0) {
            out.push(IntensityBinRow {
                target: r0.target.clone(),
                views: r0.views.clone(),
                df_px: r0.df_px,
                piercing_px: r0.piercing_px,
                physical: r0.physical.clone(),
                fixed_image: r0.fixed_image.clone(),
                bin_lo_mm: b.lo_mm,
                bin_hi_mm: b.hi_mm,
                trials: b.trials,
                successes: b.successes,
                success_rate: b.success_rate,
                final_mtre_success_mean_mm: b.mean_final_mtre_success_mm,
                reached_optimum_rate: reached_rate(
                    c.iter()
                        .filter(|r| r.bin_lo_mm == b.lo_mm && r.bin_hi_mm == b.hi_mm),
                ),
            });
        }
    }
    out
}

/// The per-cell summary.
pub fn summary(rows: &[IntensityRow]) -> Vec<IntensitySummaryRow> {
    cells(rows)
        .into_iter()
        .map(|c| {
            let r0 = c[0];
            let ok: Vec<f64> = c
                .iter()
                .filter(|r| r.final_mtre_mm < SUCCESS_MTRE_MM)
                .map(|r| r.final_mtre_mm)
                .collect();
            let (mean, sd) = mean_sd(&ok);
            let all: Vec<f64> = c.iter().map(|r| r.final_mtre_mm).collect();
            let (at_truth, searches, spread) = optimum_searches(&c);
            IntensitySummaryRow {
                target: r0.target.clone(),
                views: r0.views.clone(),
                df_px: r0.df_px,
                piercing_px: r0.piercing_px,
                physical: r0.physical.clone(),
                fixed_image: r0.fixed_image.clone(),
                trials: c.len(),
                successes: ok.len(),
                success_rate: ok.len() as f64 / c.len() as f64,
                capture_range_mm: capture_range_mm(&bin_summaries(&c)),
                final_mtre_mean_mm: mean,
                final_mtre_sd_mm: sd,
                final_mtre_median_mm: crate::analysis::percentile(&all, 50.0),
                landmark_mtre_mm: r0.landmark_mtre_mm,
                optimum_mtre_mm: at_truth.optimum_mtre_mm,
                optimum_searches: searches,
                optimum_spread_mm: spread,
                optimum_to_landmark_mm: at_truth.optimum_to_landmark_mm,
                optimum_to_landmark_centre_mm: at_truth.optimum_to_landmark_centre_mm,
                optimum_to_landmark_rot_deg: at_truth.optimum_to_landmark_rot_deg,
                reached_optimum_rate: reached_rate(c.iter()),
                evaluations_mean: c.iter().map(|r| r.evaluations as f64).sum::<f64>()
                    / c.len() as f64,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(bin: usize, start_mm: f64, optimum_mm: f64) -> IntensityRow {
        IntensityRow {
            target: "L3".into(),
            views: "ap+lat".into(),
            df_px: 300.0,
            piercing_px: 0.0,
            physical: String::new(),
            fixed_image: "mono".into(),
            bin,
            bin_lo_mm: 5.0 * bin as f64,
            bin_hi_mm: 5.0 * (bin + 1) as f64,
            start: 0,
            initial_mtre_mm: 5.0 * bin as f64 + 1.0,
            final_mtre_mm: optimum_mm,
            success: optimum_mm < SUCCESS_MTRE_MM,
            rot_err_deg: 0.1,
            trans_err_mm: 0.1,
            ptre_ap_px: 1.0,
            ptre_lat_px: 1.0,
            similarity: 0.99,
            evaluations: 100,
            converged: true,
            rx: 0.0,
            ry: 0.0,
            rz: 0.0,
            tx_mm: 0.0,
            ty_mm: 0.0,
            tz_mm: 0.0,
            landmark_mtre_mm: 1.1,
            optimum_start_mtre_mm: start_mm,
            optimum_mtre_mm: optimum_mm,
            optimum_to_landmark_mm: 0.2 + optimum_mm,
            optimum_to_landmark_centre_mm: 0.1,
            optimum_to_landmark_rot_deg: 0.1,
            to_optimum_mm: 0.0,
            reached_optimum: true,
        }
    }

    /// The cell's bias is the search from the truth whatever the rows' order; its spread is the range
    /// over the bins' searches; a table written before the start column existed reads the start as
    /// NaN, and its spread is "not measured", not a perfect 0.
    #[test]
    fn the_optimum_s_spread_is_the_range_of_the_bins_searches() {
        let rows = vec![
            row(1, OPTIMUM_RESTART_MM, 1.5),
            row(0, 0.0, 1.25),
            row(2, 0.5, 1.375),
        ];
        let s = &summary(&rows)[0];
        assert_eq!(s.optimum_mtre_mm, 1.25);
        assert_eq!(s.optimum_to_landmark_mm, 1.45);
        assert_eq!(s.optimum_searches, 3);
        assert_eq!(s.optimum_spread_mm, 0.25);
        assert!(summary(&rows[1..2])[0].optimum_spread_mm.is_nan());

        let mut w = csv::Writer::from_writer(Vec::new());
        for r in &rows {
            w.serialize(r).unwrap();
        }
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        let col = text
            .lines()
            .next()
            .unwrap()
            .split(',')
            .position(|c| c == "optimum_start_mtre_mm")
            .unwrap();
        let old: String = text
            .lines()
            .map(|l| {
                let mut f: Vec<&str> = l.split(',').collect();
                f.remove(col);
                f.join(",") + "\n"
            })
            .collect();
        let read: Vec<IntensityRow> = csv::Reader::from_reader(old.as_bytes())
            .deserialize()
            .collect::<std::result::Result<_, _>>()
            .unwrap();
        assert!(read.iter().all(|r| r.optimum_start_mtre_mm.is_nan()));
        let s = &summary(&read)[0];
        assert_eq!((s.optimum_mtre_mm, s.optimum_searches), (1.25, 3));
        assert!(s.optimum_spread_mm.is_nan());
    }
}
