//! The report's intensity-registration section: how the registrations were run, the per-cell summary,
//! and intensity-based beside landmark registration under the same assumed K, in words computed from
//! this run's tables.

use std::fmt::Write as _;

use super::grid::Pitch;
use super::layout;
use super::layout::{mean_text, num};
use crate::registration::intensity::{CAPTURE_MIN_STARTS, CAPTURE_SUCCESS_RATE, SUCCESS_MTRE_MM};
use crate::study::config::{FixedScope, StudyConfig};
use crate::study::figures::{FigureEntry, Section};
use crate::study::schema::{IntensitySummaryRow, OPTIMUM_RESTART_MM, StudyTables, ci95_half_width};

/// The section heading.
pub const HEADING: &str = "Intensity-based registration: DRR against radiograph";

/// Writes the section (nothing when the experiment did not run).
pub fn section(
    md: &mut String,
    cfg: &StudyConfig,
    tables: &StudyTables,
    figs: &[FigureEntry],
    n: &mut usize,
) {
    let rows = &tables.intensity_summary;
    if rows.is_empty() {
        return;
    }
    let s = &cfg.intensity_registration;
    let pitch = Pitch::of(cfg);
    let _ = writeln!(md, "## {HEADING}\n");
    let fixed = match s.fixed {
        FixedScope::Level => "the level alone".to_string(),
        FixedScope::Anatomy => {
            "the whole phantom (L1–L5, discs, soft tissue), the moving DRR the level alone"
                .to_string()
        }
    };
    let fixed = if s.images.iter().any(|i| i.is_spectral()) {
        format!(
            "{fixed} (monochromatic in the table's `mono` rows; the spectral rows are compared in *Spectral \
fixed images* below)"
        )
    } else {
        fixed
    };
    let noise = if s.photons > 0.0 {
        format!(
            "through the X-ray image model (Poisson noise at I0 = {} photons per pixel, Gaussian blur σ = {} px, log conversion)",
            s.photons, s.blur_px
        )
    } else {
        "noise-free (the line integrals themselves)".to_string()
    };
    let _ = writeln!(
        md,
        "The level's pose is registered by matching DRRs rendered with the **assumed** K (true, or \
perturbed by Δf ∈ {{{}}} px and piercing shifts (p, p), p ∈ {{{}}} px{}){} to fixed images rendered with the \
true K: {fixed}, {noise}. Similarity {}, summed over the views of a set; pyramid binning {:?} of the study \
detector{}, then Levenberg–Marquardt at every level. Starts: {} per bin of initial mTRE {:?} mm (uniform \
in the bin, random direction in the six pose parameters), measured over the level's cortical surface \
vertices; success = final mTRE < {SUCCESS_MTRE_MM} mm, capture range = the last bin edge of the leading \
run of bins with ≥ {:.0} % success, stated only with ≥ {CAPTURE_MIN_STARTS} starts in every bin{}. Beside each cell: the **landmark** registration of the same level \
under the same assumed K (direct LM over the same views, the landmarks' exact true-K projections \
observed, started at the truth), its mTRE over the same target points. The **intensity optimum** under \
each K is the registration started at the truth (local stage only): its mTRE is the bias, free of capture \
failures. Every bin of a cell searches it once — the first from the truth, the others from {} mm away (a \
seeded direction, the same for every fixed-image model) — and the spread of those searches' mTRE is how \
reproducible the bias is: on a flat valley floor the optimiser's path decides where it stops. A difference \
between two cells' biases no larger than their two spreads together is not put down to the cells' \
difference.{}\n",
        list(&s.df_px),
        list(&s.piercing_px),
        grid_mm(s, pitch),
        physical_words(s),
        s.similarity,
        s.levels,
        if s.global {
            ", CMA-ES at the coarsest level"
        } else {
            ""
        },
        s.starts_per_bin,
        s.init_mtre_mm,
        100.0 * CAPTURE_SUCCESS_RATE,
        if s.starts_per_bin < CAPTURE_MIN_STARTS {
            format!(
                " (this run has {} per bin, so it states no capture range and its success rates are \
counts of a few starts, not rates)",
                s.starts_per_bin
            )
        } else {
            String::new()
        },
        super::grid::short(OPTIMUM_RESTART_MM, 2),
        if s.init_mtre_mm.len() < 3 {
            " This run has one bin per cell, so it searches each optimum once and its reproducibility is \
not measured."
        } else {
            ""
        },
    );
    layout::figures(md, figs, Section::Intensity, n);
    summary_table(md, rows, pitch);
}

/// The physical errors of the section in words (empty without any).
fn physical_words(s: &crate::study::config::IntensitySection) -> String {
    let cells: Vec<String> = s
        .physical
        .cells()
        .unwrap_or_default()
        .iter()
        .map(|p| format!("`{p}`"))
        .collect();
    if cells.is_empty() {
        return String::new();
    }
    format!(
        ", or with the camera of a physical error of the focal spot or detector ({}; see *{}*: K and \
the camera's pose both change)",
        cells.join(", "),
        super::physical::HEADING
    )
}

/// The grid's Δf and piercing shifts in mm (empty without a pixel pitch).
fn grid_mm(s: &crate::study::config::IntensitySection, pitch: Pitch) -> String {
    let Some(mm) = pitch.0 else {
        return String::new();
    };
    let of = |v: &[f64]| {
        v.iter()
            .filter_map(|x| pitch.mm(*x))
            .collect::<Vec<_>>()
            .join(", ")
    };
    format!(
        "; at {} mm pixels an SDD error of {{{}}} mm and a move of {{{}}} mm along u and v on the detector",
        super::grid::short(mm, 3),
        of(&s.df_px),
        of(&s.piercing_px)
    )
}

/// The assumed geometry of a cell in words.
pub(super) fn assumed(r: &IntensitySummaryRow, pitch: Pitch) -> String {
    if !r.physical.is_empty() {
        format!("the physical error `{}`", r.physical)
    } else if r.df_px == 0.0 {
        pitch.p_words(r.piercing_px)
    } else if r.piercing_px == 0.0 {
        pitch.df_words(r.df_px)
    } else {
        format!(
            "{} with {}",
            pitch.df_words(r.df_px),
            pitch.p_words(r.piercing_px)
        )
    }
}

fn list(v: &[f64]) -> String {
    v.iter()
        .map(|x| x.to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// The final mTRE of a cell's successful starts: mean and 95 % CI where they vary, one value where there
/// is one success or they all agree (within 1 µm), "no success" where none succeeded.
fn successes_mtre(r: &IntensitySummaryRow) -> String {
    let (n, mean, sd) = (r.successes, r.final_mtre_mean_mm, r.final_mtre_sd_mm);
    if n == 0 || !mean.is_finite() {
        return "no success".into();
    }
    let agree = n > 1 && sd <= 1e-3;
    let text = mean_text(mean, ci95_half_width(sd, n), n, agree);
    if n > 1 && !agree {
        format!("{text} (n = {n})")
    } else {
        text
    }
}

fn summary_table(md: &mut String, rows: &[IntensitySummaryRow], pitch: Pitch) {
    let _ = writeln!(
        md,
        "| target | views | fixed image | Δf, {u} | piercing p, {v} | physical error | starts | success | capture (mm) | final mTRE of the successes (mm): mean [95 % CI], or the value | median final mTRE (mm) | intensity optimum mTRE (mm) | spread of the optimum's searches (mm) | reached optimum | landmark mTRE (mm) | intensity vs landmark optimum: mTRE (mm), rotation (°) | DRR evaluations |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        u = pitch.unit("SDD error"),
        v = pitch.unit("along u and v on the detector")
    );
    for r in rows {
        let (df, p, physical) = if r.physical.is_empty() {
            (
                pitch.df_cell(r.df_px),
                pitch.p_cell(r.piercing_px),
                "—".to_string(),
            )
        } else {
            (
                "—".to_string(),
                "—".to_string(),
                r.physical.replace('=', " = "),
            )
        };
        let _ = writeln!(
            md,
            "| {} | {} | {} | {df} | {p} | {physical} | {} | {:.0} % | {} | {} | {} | {} | {} | {:.0} % | {} | {}, {} | {:.0} |",
            r.target,
            r.views,
            r.fixed_image,
            r.trials,
            100.0 * r.success_rate,
            capture(r.capture_range_mm),
            successes_mtre(r),
            num(r.final_mtre_median_mm, 3),
            num(r.optimum_mtre_mm, 3),
            spread_cell(r),
            100.0 * r.reached_optimum_rate,
            num(r.landmark_mtre_mm, 3),
            num(r.optimum_to_landmark_mm, 3),
            num(r.optimum_to_landmark_rot_deg, 2),
            r.evaluations_mean
        );
    }
    let _ = writeln!(md);
}

/// A cell's spread of its optimum's searches as the summary table prints it.
fn spread_cell(r: &IntensitySummaryRow) -> String {
    if r.optimum_spread_mm.is_finite() {
        format!(
            "{} ({} searches)",
            num(r.optimum_spread_mm, 3),
            r.optimum_searches
        )
    } else if r.optimum_searches == 1 {
        "one search".into()
    } else {
        "n/a".into()
    }
}

/// The resolution of a comparison of two cells' biases: each bias is known only within its optimum's
/// spread over its searches, so their difference within the sum of the two spreads (None when either
/// was searched once, or a search failed).
pub(super) fn bias_resolution(a: &IntensitySummaryRow, b: &IntensitySummaryRow) -> Option<f64> {
    (a.optimum_spread_mm.is_finite() && b.optimum_spread_mm.is_finite())
        .then_some(a.optimum_spread_mm + b.optimum_spread_mm)
}

/// A cell's optimum's reproducibility in words, for after its bias.
pub(super) fn spread_words(r: &IntensitySummaryRow) -> String {
    if r.optimum_spread_mm.is_finite() {
        format!(
            "its {} searches, from the truth and from {} mm away, give biases within {} mm of each other",
            r.optimum_searches,
            super::grid::short(OPTIMUM_RESTART_MM, 2),
            num(r.optimum_spread_mm, 3)
        )
    } else {
        "its reproducibility not measured".into()
    }
}

/// A capture range as the table prints it: not stated (NaN) below [`CAPTURE_MIN_STARTS`] starts per bin.
fn capture(mm: f64) -> String {
    if mm.is_nan() {
        format!("not stated (< {CAPTURE_MIN_STARTS} starts per bin)")
    } else {
        num(mm, 1)
    }
}
