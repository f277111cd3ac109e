//! The report's cohort section: how many cases, the population-level findings (the LAT/AP ratio of
//! landmark shift with its inter-patient range, Dice and registration error at the largest Δf, as
//! median and 5th–95th percentile across the cases' levels), the cohort figures, per-case rows and
//! the cases left out.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use crate::study::cohort::{self, Manifest};
use crate::study::config::StudyConfig;
use crate::study::figures::cohort as figs;
use crate::study::schema::cohort::{CaseOf, CohortRow, Stats, stats};
use crate::study::schema::{Family, LandmarkRow, StudyTables, mean_sd};

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

/// Per level target, the ratio LAT/AP of its mean landmark shift at focal Δf `df`.
fn lat_ap_ratios(rows: &[LandmarkRow], case_of: &CaseOf, df: f64) -> Vec<(String, f64)> {
    let mut shifts: BTreeMap<(&str, &str), Vec<f64>> = BTreeMap::new();
    for r in rows {
        if r.family == Family::Focal && r.df_px == df && case_of.contains_key(&r.target) {
            shifts
                .entry((r.target.as_str(), r.view.as_str()))
                .or_default()
                .push(r.shift_px);
        }
    }
    let mut out = Vec::new();
    for (target, case) in case_of {
        let mean = |v: &str| shifts.get(&(target.as_str(), v)).map(|s| mean_sd(s).0);
        if let (Some(ap), Some(lat)) = (mean("ap"), mean("lat"))
            && ap.is_finite()
            && lat.is_finite()
            && ap > 0.0
        {
            out.push((case.clone(), lat / ap));
        }
    }
    out
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
    t: &StudyTables,
    rows: &[CohortRow],
    case_of: &CaseOf,
    pitch: super::grid::Pitch,
) -> Vec<String> {
    let mut items = Vec::new();
    let df_max = t
        .landmarks
        .iter()
        .filter(|r| r.family == Family::Focal)
        .map(|r| r.df_px)
        .fold(f64::NAN, f64::max);
    if df_max.is_finite() {
        let ratios = lat_ap_ratios(&t.landmarks, case_of, df_max);
        if !ratios.is_empty() {
            let s = stats(&ratios.iter().map(|r| r.1).collect::<Vec<_>>());
            let mut per_case: BTreeMap<&str, Vec<f64>> = BTreeMap::new();
            for (c, r) in &ratios {
                per_case.entry(c).or_default().push(*r);
            }
            let case_means: Vec<f64> = per_case.values().map(|v| mean_sd(v).0).collect();
            let lo = case_means.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = case_means.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            items.push(format!(
                "At {} the LAT/AP ratio of the mean landmark shift is {} across the \
                 cases' levels; per patient (mean over its levels) it ranges from {lo:.2} to {hi:.2} \
                 over {} patients.",
                pitch.df_words(df_max),
                range(&s, 2),
                per_case.len()
            ));
        }
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
            "Registration translation error at {} (no piercing shift), per target the \
             mean over its trials: {}.",
            pitch.df_words(reg_df),
            parts.join("; ")
        ));
    }
    items
}

/// Writes the cohort section into `md` when the study has datasets (else nothing).
pub fn section(md: &mut String, out: &Path, cfg: &StudyConfig, t: &StudyTables) {
    let Some((m, rows)) = cohort::cohort_of(out, cfg, t) else {
        return;
    };
    let case_of = cohort::case_of(cfg, &m);
    let pitch = super::grid::Pitch::of(cfg);
    write_section(md, &out.join("figures"), &m, &rows, t, (&case_of, pitch));
}

fn write_section(
    md: &mut String,
    figures: &Path,
    m: &Manifest,
    rows: &[CohortRow],
    t: &StudyTables,
    (case_of, pitch): (&CaseOf, super::grid::Pitch),
) {
    let _ = writeln!(md, "## {HEADING}\n");
    let datasets = crate::study::figures::distinct(m.cases.iter().map(|c| c.dataset.clone()));
    let _ = writeln!(
        md,
        "{} cases from {} ({} level targets), {} left out. Every statistic is over the cases' level \
targets (the segment targets are not samples): median and 5th–95th percentile, per perturbation cell, in \
`tables/cohort.csv` (scope `pooled`, and one scope per case).\n",
        m.cases.len(),
        datasets.join(", "),
        case_of.len(),
        m.left_out.len()
    );
    for f in findings(t, rows, case_of, pitch) {
        let _ = writeln!(md, "- {f}");
    }
    let _ = writeln!(md);
    for (file, title) in [
        (figs::DICE, "Dice vs focal offset across patients"),
        (figs::AP_LAT, "Landmark shift, AP vs LAT, across patients"),
        (
            figs::LANDMARKS,
            "Landmark shift per landmark across patients",
        ),
        (
            figs::REGISTRATION,
            "Registration error vs focal offset across patients",
        ),
    ] {
        if figures.join(file).is_file() {
            let svg = file.replace(".png", ".svg");
            let _ = writeln!(md, "![{title}](figures/{file})");
            let _ = writeln!(
                md,
                "_{title}: median line, 5th–95th percentile band ([PNG](figures/{file}), [SVG](figures/{svg}))_\n"
            );
        }
    }
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
