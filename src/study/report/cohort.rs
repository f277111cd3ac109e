//! The report's cohort section: how many cases, the population-level findings (the LAT/AP ratio of
//! landmark shift with its inter-patient range, Dice and registration error at the largest Δf, as
//! median and 5th–95th percentile across the cases' levels), the cohort figures, per-case rows and
//! the cases left out.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use super::shift_ratio::TargetRatio;
use crate::study::cohort::{self, Manifest};
use crate::study::config::StudyConfig;
use crate::study::figures::{FigureEntry, Section};
use crate::study::schema::cohort::{CaseOf, CohortRow, Stats, stats};
use crate::study::schema::{StudyTables, mean_sd};

/// The section's heading.
pub const HEADING: &str = "Cohort: spread across patients";

fn range(s: &Stats, digits: usize) -> String {
    format!(
        "{:.d$} (5th–95th percentile {:.d$}–{:.d$}, n = {})",
        s.median,
        s.p5,
        s.p95,
        s.n,
        d = digits
    )
}

fn pooled(rows: &[CohortRow], keep: impl Fn(&CohortRow) -> bool) -> Option<&CohortRow> {
    rows.iter().find(|r| r.scope == "pooled" && keep(r))
}

fn as_stats(r: &CohortRow) -> Stats {
    Stats {
        n: r.n,
        mean: r.mean,
        sd: r.sd,
        median: r.median,
        p5: r.p5,
        p95: r.p95,
    }
}

/// The population findings, one sentence each.
fn findings(
    ratios: &[TargetRatio],
    rows: &[CohortRow],
    case_of: &CaseOf,
    pitch: super::grid::Pitch,
) -> Vec<String> {
    let mut items = Vec::new();
    // The landmark table's measured LAT/AP ratios, one per level target on its fixed landmark set.
    let mine: Vec<(&str, &TargetRatio)> = ratios
        .iter()
        .filter_map(|r| Some((case_of.get(&r.target)?.as_str(), r)))
        .filter(|(_, r)| r.measured().is_finite())
        .collect();
    if let [df] = crate::study::figures::distinct(mine.iter().map(|r| r.1.df_px)).as_slice() {
        let s = stats(&mine.iter().map(|r| r.1.measured()).collect::<Vec<_>>());
        let mut per_case: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
        for (c, r) in &mine {
            per_case.entry(c).or_default().push(r.measured());
        }
        let case_means: Vec<f64> = per_case.values().map(|v| mean_sd(v).0).collect();
        let lo = case_means.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = case_means.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let per_patient = match per_case.len() {
            1 => format!("the one patient's mean over its levels is {lo:.2}"),
            n if format!("{lo:.2}") == format!("{hi:.2}") => {
                format!(
                    "per patient (mean over its levels) it is {lo:.2} in each of the {n} patients"
                )
            }
            n => format!(
                "per patient (mean over its levels) it ranges from {lo:.2} to {hi:.2} over {n} patients"
            ),
        };
        items.push(format!(
            "At {} the LAT/AP ratio of the RMS landmark shift (each level on its fixed landmark set, \
             the column \"LAT/AP measured\" of the table above) is {} across the cases' levels; \
             {per_patient}.",
            pitch.df_words(*df),
            range(&s, 2),
        ));
    }
    for view in ["ap", "lat"] {
        let last = rows
            .iter()
            .filter(|r| {
                r.scope == "pooled"
                    && r.table == "projection"
                    && r.metric == "dice"
                    && r.family == "focal"
                    && r.view == view
            })
            .max_by(|a, b| a.df_px.total_cmp(&b.df_px));
        if let Some(r) = last {
            items.push(format!(
                "{} silhouette Dice at {}: {}.",
                view.to_uppercase(),
                pitch.df_words(r.df_px),
                range(&as_stats(r), 4)
            ));
        }
    }
    let reg_df = rows
        .iter()
        .filter(|r| r.table == "registration")
        .map(|r| r.df_px)
        .fold(f64::NAN, f64::max);
    let methods = crate::study::figures::distinct(
        rows.iter()
            .filter(|r| r.table == "registration")
            .map(|r| r.method.clone()),
    );
    let parts: Vec<String> = methods
        .iter()
        .filter_map(|m| {
            pooled(rows, |r| {
                r.table == "registration"
                    && r.metric == "trans_err_mm"
                    && r.method == *m
                    && r.df_px == reg_df
                    && r.dcx_px == 0.0
            })
            .map(|r| format!("{m} {} mm", range(&as_stats(r), 2)))
        })
        .collect();
    if !parts.is_empty() {
        items.push(format!(
            "Registration translation error at {} and no piercing shift, per target the \
             mean over its trials: {}.",
            pitch.df_words(reg_df),
            parts.join("; ")
        ));
    }
    items
}

/// Writes the cohort section into `md` when the study has datasets (else nothing).
/// `ratios` are the landmark table's per-target LAT/AP ratios ([`super::shift_ratio::ratios`]).
pub fn section(
    md: &mut String,
    out: &Path,
    cfg: &StudyConfig,
    (t, ratios): (&StudyTables, &[TargetRatio]),
    (figs, n): (&[FigureEntry], &mut usize),
) {
    let Some((m, rows)) = cohort::cohort_of(out, cfg, t) else {
        return;
    };
    let case_of = cohort::case_of(cfg, &m);
    let pitch = super::grid::Pitch::of(cfg);
    let segments = cfg.anatomy.dataset.iter().any(|d| d.segment);
    write_section(
        md,
        (figs, n),
        (&m, segments),
        &rows,
        ratios,
        (&case_of, pitch),
    );
}

fn write_section(
    md: &mut String,
    (figs, n): (&[FigureEntry], &mut usize),
    (m, segments): (&Manifest, bool),
    rows: &[CohortRow],
    ratios: &[TargetRatio],
    (case_of, pitch): (&CaseOf, super::grid::Pitch),
) {
    let _ = writeln!(md, "## {HEADING}\n");
    let datasets = crate::study::figures::distinct(m.cases.iter().map(|c| c.dataset.clone()));
    let _ = writeln!(
        md,
        "{} cases from {} ({} level targets), {} left out. Every statistic is over the cases' level \
targets{}: median and 5th–95th percentile, per perturbation cell, in `tables/cohort.csv` (scope `pooled`, \
and one scope per case).\n",
        m.cases.len(),
        datasets.join(", "),
        case_of.len(),
        m.left_out.len(),
        if segments {
            " (the segment targets are not samples)"
        } else {
            ""
        }
    );
    for f in findings(ratios, rows, case_of, pitch) {
        let _ = writeln!(md, "- {f}");
    }
    let _ = writeln!(md);
    super::layout::figures(md, figs, Section::Cohort, n);
    let _ = writeln!(md, "### Cases\n");
    let _ = writeln!(
        md,
        "| case | levels | AP Dice, largest Δf (median) | LAT Dice, largest Δf (median) |"
    );
    let _ = writeln!(md, "|---|---|---|---|");
    let df_max = rows
        .iter()
        .filter(|r| r.table == "projection" && r.family == "focal")
        .map(|r| r.df_px)
        .fold(f64::NAN, f64::max);
    for c in &m.cases {
        let scope = format!("{}/{}", c.dataset, c.case);
        let levels = case_of.values().filter(|s| **s == scope).count();
        let dice = |v: &str| {
            rows.iter()
                .find(|r| {
                    r.scope == scope
                        && r.table == "projection"
                        && r.metric == "dice"
                        && r.family == "focal"
                        && r.view == v
                        && r.df_px == df_max
                })
                .map_or("–".to_string(), |r| format!("{:.4}", r.median))
        };
        let _ = writeln!(
            md,
            "| {scope} | {levels} | {} | {} |",
            dice("ap"),
            dice("lat")
        );
    }
    let _ = writeln!(md, "\n### Cases left out\n");
    if m.left_out.is_empty() {
        let _ = writeln!(md, "None: every case found was read and checked.\n");
    } else {
        let _ = writeln!(md, "| dataset | case | file | reason |");
        let _ = writeln!(md, "|---|---|---|---|");
        for l in &m.left_out {
            let reason = l.reason.replace('|', "\\|").replace('\n', " ");
            let _ = writeln!(
                md,
                "| {} | {} | `{}` | {reason} |",
                l.dataset,
                l.case,
                l.file.display()
            );
        }
        let _ = writeln!(
            md,
            "\nAlso in `tables/cohort_left_out.csv`; `strict = true` on a dataset makes such a case an error.\n"
        );
    }
}
