//! Tables of the intensity-registration experiment: one row per start (`intensity_registration.csv`),
//! per cell and initial-mTRE bin (`intensity_registration_bins.csv`: the van de Kraats success rate) and
//! per cell (`intensity_registration_summary.csv`: success rate, capture range, final mTRE mean/sd).

use serde::{Deserialize, Serialize};

use super::{mean_sd, num};
use crate::registration::intensity::{
    BinSummary, SUCCESS_MTRE_MM, TrialOutcome, capture_range_mm, summarise,
};

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
    /// The intensity optimum under this K (the registration started at the truth, local stage only):
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
    #[serde(with = "num")]
    pub optimum_mtre_mm: f64,
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
                optimum_mtre_mm: r0.optimum_mtre_mm,
                optimum_to_landmark_mm: r0.optimum_to_landmark_mm,
                optimum_to_landmark_centre_mm: r0.optimum_to_landmark_centre_mm,
                optimum_to_landmark_rot_deg: r0.optimum_to_landmark_rot_deg,
                reached_optimum_rate: reached_rate(c.iter()),
                evaluations_mean: c.iter().map(|r| r.evaluations as f64).sum::<f64>()
                    / c.len() as f64,
            }
        })
        .collect()
}
