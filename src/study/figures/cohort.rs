//! Cohort figures: the spread across patients (`tables/cohort.csv`, scope `pooled`) as a median line
//! with a shaded 5th–95th percentile band — Dice vs Δf per view, landmark shift vs Δf per landmark,
//! registration error vs Δf per method, and AP beside LAT landmark shift.

use std::path::Path;

use super::chart::{Panel, Series};
use super::charts::panel_chart;
use super::distinct;
use super::manifest::{FigureEntry, Section};
use crate::Result;
use crate::study::schema::cohort::CohortRow;

/// The file names, in report order.
pub const DICE: &str = "cohort_dice_vs_df.png";
pub const LANDMARKS: &str = "cohort_landmark_shift_per_landmark.png";
pub const REGISTRATION: &str = "cohort_registration_vs_df.png";
pub const AP_LAT: &str = "cohort_ap_vs_lat.png";

/// The median-and-band series of the pooled rows passing `keep`, x = Δf, labelled `label`.
fn band(rows: &[CohortRow], label: &str, keep: impl Fn(&CohortRow) -> bool) -> Option<Series> {
    let mut r: Vec<&CohortRow> = rows
        .iter()
        .filter(|r| r.scope == "pooled" && r.n > 0 && keep(r))
        .collect();
    if r.is_empty() {
        return None;
    }
    r.sort_by(|a, b| a.df_px.total_cmp(&b.df_px));
    Some(Series {
        label: label.to_string(),
        points: r.iter().map(|r| (r.df_px, r.median)).collect(),
        spread: Vec::new(),
        band: r.iter().map(|r| (r.p5, r.p95)).collect(),
        colour: None,
        dashed: false,
        floor: f64::NEG_INFINITY,
    })
}

/// A figure of the report's cohort section.
fn entry(file: &str, title: &str, what: &str, cases: usize) -> FigureEntry {
    FigureEntry {
        section: Section::Cohort,
        file: file.to_string(),
        title: title.to_string(),
        caption: format!(
            "{title}: {what}; line: median across the {cases} cases' levels, band: 5th–95th \
             percentile"
        ),
        primary: true,
    }
}

/// Draws the cohort figures of `rows` (from [`crate::study::schema::cohort::cohort_rows`]) into
/// `figs`; returns their manifest entries (only the figures that have data).
pub fn write(figs: &Path, rows: &[CohortRow], cases: usize) -> Result<Vec<FigureEntry>> {
    let mut entries = Vec::new();
    let focal = |r: &CohortRow| r.family == "focal";
    let views = distinct(
        rows.iter()
            .filter(|r| !r.view.is_empty())
            .map(|r| r.view.clone()),
    );

    let series: Vec<Series> = views
        .iter()
        .filter_map(|v| {
            band(rows, &v.to_uppercase(), |r| {
                r.table == "landmarks"
                    && r.metric == "shift_px"
                    && r.landmark == "*"
                    && focal(r)
                    && r.view == *v
            })
        })
        .collect();
    if !series.is_empty() {
        let title = "Cohort: mean landmark shift, AP vs LAT";
        let panel = Panel {
            title: "mean over each target's landmarks".into(),
            series,
            marks: Vec::new(),
        };
        panel_chart(
            &figs.join(AP_LAT),
            title,
            "focal offset Δf (px)",
            "mean landmark shift (px)",
            vec![panel],
            1,
        )?;
        entries.push(entry(
            AP_LAT,
            title,
            "a line per view, focal family, each target's mean shift over its landmarks (the LAT/AP \
             ratio in the text is of RMS shifts on each level's fixed landmark set, as in the Findings' \
             table)",
            cases,
        ));
    }
    let panels: Vec<Panel> = views
        .iter()
        .filter_map(|v| {
            band(rows, "Dice", |r| {
                r.table == "projection" && r.metric == "dice" && focal(r) && r.view == *v
            })
            .map(|s| Panel {
                title: v.to_uppercase(),
                series: vec![s],
                marks: Vec::new(),
            })
        })
        .collect();
    if !panels.is_empty() {
        let title = "Cohort: silhouette Dice vs focal offset";
        let n = panels.len();
        panel_chart(
            &figs.join(DICE),
            title,
            "focal offset Δf (px)",
            "Dice",
            panels,
            n,
        )?;
        entries.push(entry(
            DICE,
            title,
            "a panel per view, the views at one y scale, focal family",
            cases,
        ));
    }

    let landmarks = distinct(
        rows.iter()
            .filter(|r| r.table == "landmarks" && r.landmark != "*" && !r.landmark.is_empty())
            .map(|r| r.landmark.clone()),
    );
    let panels: Vec<Panel> = views
        .iter()
        .map(|v| Panel {
            title: v.to_uppercase(),
            series: landmarks
                .iter()
                .filter_map(|l| {
                    band(rows, l, |r| {
                        r.table == "landmarks"
                            && r.metric == "shift_px"
                            && focal(r)
                            && r.view == *v
                            && r.landmark == *l
                    })
                })
                .collect(),
            marks: Vec::new(),
        })
        .filter(|p| !p.series.is_empty())
        .collect();
    if !panels.is_empty() {
        let title = "Cohort: landmark shift vs focal offset, per landmark";
        let n = panels.len();
        panel_chart(
            &figs.join(LANDMARKS),
            title,
            "focal offset Δf (px)",
            "landmark shift (px)",
            panels,
            n,
        )?;
        entries.push(entry(
            LANDMARKS,
            title,
            "a panel per view, the views at one y scale, a line per landmark, focal family",
            cases,
        ));
    }

    let methods = distinct(
        rows.iter()
            .filter(|r| r.table == "registration")
            .map(|r| r.method.clone()),
    );
    let panels: Vec<Panel> = methods
        .iter()
        .filter_map(|m| {
            band(rows, "translation error", |r| {
                r.table == "registration"
                    && r.metric == "trans_err_mm"
                    && r.method == *m
                    && r.dcx_px == 0.0
            })
            .map(|s| Panel {
                title: m.clone(),
                series: vec![s],
                marks: Vec::new(),
            })
        })
        .collect();
    if !panels.is_empty() {
        let title = "Cohort: registration translation error vs focal offset";
        panel_chart(
            &figs.join(REGISTRATION),
            title,
            "focal offset Δf (px)",
            "translation error (mm)",
            panels,
            3,
        )?;
        entries.push(entry(
            REGISTRATION,
            title,
            "a panel per method, piercing shift 0, per target the mean over its trials; each panel \
             has its own y scale, except that a method's AP and LAT panels share one",
            cases,
        ));
    }

    Ok(entries)
}
