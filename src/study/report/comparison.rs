//! The paper's comparison tables (silhouette overlap, landmark shift per structure, registration
//! ranges): the paper's figure beside ours, from the typed tables, as [`PaperTable`]s.

use super::grid::Pitch;
use super::latex::PaperTable;
use crate::study::config::RegistrationMethod;
use crate::study::paper::{self, PaperResults};
use crate::study::schema::{Family, LandmarkRow, ProjectionRow, RegistrationSummaryRow};

/// A number to 4 decimals, or `n/a`.
fn show(v: Option<f64>) -> String {
    v.map_or("n/a".into(), |x| format!("{x:.4}"))
}

/// A value of the paper as the paper prints it (no digits added), or `n/a`.
fn as_printed(v: Option<f64>) -> String {
    v.map_or("n/a".into(), |x| format!("{x}"))
}

/// The projection row of (target, view, family, Δf).
pub(super) fn projection_row<'a>(
    rows: &'a [ProjectionRow],
    target: &str,
    view: &str,
    family: Family,
    df: f64,
) -> Option<&'a ProjectionRow> {
    rows.iter()
        .find(|r| r.target == target && r.view == view && r.family == family && r.df_px == df)
}

/// The smallest AP Dice of `target` over the joint schedule.
pub(super) fn ap_joint_dice_min(rows: &[ProjectionRow], target: &str) -> Option<f64> {
    let m = rows
        .iter()
        .filter(|r| r.target == target && r.view == "ap" && r.family == Family::Joint)
        .map(|r| r.dice)
        .fold(f64::INFINITY, f64::min);
    m.is_finite().then_some(m)
}

/// Range (min, max) of the per-cell mean `value` for `method` on `target` (every target when `None`),
/// over Δf > 0.
pub(super) fn summary_range(
    rows: &[RegistrationSummaryRow],
    target: Option<&str>,
    method: RegistrationMethod,
    value: fn(&RegistrationSummaryRow) -> f64,
) -> Option<(f64, f64)> {
    rows.iter()
        .filter(|r| target.is_none_or(|t| r.target == t) && r.method == method && r.df_px > 0.0)
        .map(value)
        .filter(|v| v.is_finite())
        .fold(None, |acc, v| {
            Some(acc.map_or((v, v), |(a, b): (f64, f64)| (a.min(v), b.max(v))))
        })
}

/// The paper's registration ranges: (method, quantity column, paper range, value).
pub(super) type PaperRange = (
    RegistrationMethod,
    &'static str,
    [f64; 2],
    fn(&RegistrationSummaryRow) -> f64,
);

pub(super) fn paper_ranges(paper: &PaperResults) -> [PaperRange; 4] {
    let r = &paper.registration;
    [
        (
            RegistrationMethod::Kabsch,
            "rot_err_deg_mean",
            r.kabsch_rotation_deg,
            |s| s.rot_err_deg_mean,
        ),
        (
            RegistrationMethod::Kabsch,
            "trans_err_mm_mean",
            r.kabsch_translation_mm,
            |s| s.trans_err_mm_mean,
        ),
        (
            RegistrationMethod::DirectApLat,
            "rot_err_deg_mean",
            r.direct_rotation_deg,
            |s| s.rot_err_deg_mean,
        ),
        (
            RegistrationMethod::DirectApLat,
            "trans_err_mm_mean",
            r.direct_translation_mm,
            |s| s.trans_err_mm_mean,
        ),
    ]
}

/// Silhouette overlap of `first`, LAT Dice and IoU at Δf 100 and 500 px (joint and focal) and the AP
/// Dice minimum, paper vs ours.
pub fn silhouette_table(
    rows: &[ProjectionRow],
    paper: &PaperResults,
    first: &str,
    pitch: Pitch,
) -> PaperTable {
    let s = &paper.silhouette;
    type Metric = fn(&ProjectionRow) -> f64;
    let metrics: [(&str, &paper::AtDf, Metric); 2] = [
        ("dice", &s.lat_dice, |r| r.dice),
        ("iou", &s.lat_iou, |r| r.iou),
    ];
    let mut body = Vec::new();
    for (col, theirs, value) in metrics {
        for df in [100.0, 500.0] {
            for family in [Family::Joint, Family::Focal] {
                let ours = projection_row(rows, first, "lat", family, df).map(value);
                body.push(vec![
                    format!("lat {col} at {}, {family}", pitch.df_words(df)),
                    as_printed(theirs.at(df)),
                    show(ours),
                ]);
            }
        }
    }
    body.push(vec![
        "ap Dice, minimum over the schedule".into(),
        as_printed(Some(s.ap_dice_min)),
        show(ap_joint_dice_min(rows, first)),
    ]);
    PaperTable {
        name: "silhouette_overlap",
        caption: format!(
            "Silhouette overlap, paper vs ours ({first}; joint = Δf with piercing (p, p), focal = Δf alone)"
        ),
        header: ["quantity", "paper", "ours"].map(String::from).to_vec(),
        rows: body,
    }
}

/// Landmark shift (px) per landmark of `first`, AP and LAT: the paper's (whose Δf it does not state) beside
/// ours under focal Δf = 100 px (measured, with the H·x prediction in parentheses).
pub fn landmark_table(
    rows: &[LandmarkRow],
    paper: &PaperResults,
    first: &str,
    pitch: Pitch,
) -> PaperTable {
    let df = 100.0;
    let names = crate::study::figures::distinct(
        rows.iter()
            .filter(|r| r.target == first)
            .map(|r| r.landmark.as_str()),
    );
    let mut body = Vec::new();
    for n in names {
        let mut cells = vec![n.to_string()];
        for (i, view) in ["ap", "lat"].iter().enumerate() {
            let theirs = paper.landmark_shift_px.get(n).map(|s| s[i]);
            let row = rows.iter().find(|r| {
                r.target == first
                    && r.view == *view
                    && r.family == Family::Focal
                    && r.df_px == df
                    && r.landmark == n
            });
            cells.push(as_printed(theirs));
            cells.push(row.map_or("n/a".into(), |r| {
                format!("{:.2} ({:.2})", r.shift_px, r.pred_shift_px)
            }));
        }
        body.push(cells);
    }
    PaperTable {
        name: "landmark_shift",
        caption: format!(
            "Landmark shift (px), {first}: the paper's values (the paper does not state their Δf) beside ours at focal {} (measured from marker images; H·x predicted)",
            pitch.df_words(df)
        ),
        header: [
            "landmark",
            "paper AP",
            "ours AP (pred)",
            "paper LAT",
            "ours LAT (pred)",
        ]
        .map(String::from)
        .to_vec(),
        rows: body,
    }
}

/// The paper's registration ranges beside ours (min – max of the trial means of `first`, Δf > 0).
pub fn registration_table(
    rows: &[RegistrationSummaryRow],
    paper: &PaperResults,
    first: &str,
) -> PaperTable {
    let body = paper_ranges(paper)
        .into_iter()
        .map(|(method, col, theirs, value)| {
            let ours = summary_range(rows, Some(first), method, value)
                .map_or("n/a".into(), |(a, b)| format!("{a:.3} – {b:.3}"));
            vec![
                format!("{method} {col}"),
                format!("{} – {}", theirs[0], theirs[1]),
                ours,
            ]
        })
        .collect();
    PaperTable {
        name: "registration_ranges",
        caption: format!(
            "Registration error over Δf > 0 and all piercing shifts ({first}): paper vs ours"
        ),
        header: ["quantity", "paper range", "ours (min – max of trial means)"]
            .map(String::from)
            .to_vec(),
        rows: body,
    }
}
