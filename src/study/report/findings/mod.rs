//! The report's *Findings*: sentences rendered from claims ([`claim`]) that this run computed from its
//! tables, each linking to the table and figure it rests on. The claims and the facts they decide are
//! written to `tables/findings.json` beside the prose they print, so every number and categorical word
//! can be re-derived from the CSV tables alone.
//!
//! Rules: a segment is never pooled with single levels; each perturbation family is stated apart, both
//! views, with the direction of an AP-vs-LAT difference; landmark statistics are over a fixed set; ties
//! are called ties; the paper is compared by interval logic and trends as trends.

mod calibration;
pub mod claim;
mod derive;
mod landmarks;
mod projection;
mod registration;

use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::path::Path;

use serde::Serialize;

use crate::Result;
use crate::io::write_atomic_bytes;
use crate::study::paper::PaperResults;
use crate::study::schema::{StudyTables, TableRow};
use claim::{Finding, Table};

use super::shift_ratio::{TargetRatio, is_segment};

/// The file the findings' data is written to, under `tables/`.
pub const FILE: &str = "findings.json";

/// A Markdown link to the table of rows `R`.
fn table<R: TableRow>() -> String {
    let name = R::TABLE;
    format!("[{name}.csv](tables/{name}.csv)")
}

/// A Markdown link to `figures/<file>`.
fn figure(file: &str) -> String {
    format!("[{file}](figures/{file})")
}

/// What the findings are computed from.
struct Inputs<'a> {
    projection: Table,
    structures: Table,
    landmarks: Table,
    registration: Table,
    calibration: Table,
    /// `calibration.trials` of the config.
    calibration_trials: usize,
    paper: &'a PaperResults,
    /// The first target (the paper's comparisons are made on it).
    first: &'a str,
    /// (target, view) cut by the detector edge: the reference silhouette, or the perturbed one of any cell.
    cut: BTreeSet<(String, String)>,
    ratios: &'a [TargetRatio],
    /// The piercing point (cx, cy) of AP and LAT.
    piercing: [[f64; 2]; 2],
    /// The registration trials' landmark noise σ (px).
    noise_px: f64,
    /// A reference sidecar (path under the study folder) and the detector's pixel pitch along u (mm):
    /// what sizes the px of a perturbation in mm.
    pitch: Option<(String, f64)>,
}

impl Inputs<'_> {
    /// Whether `target` is pooled with others: a single level (not a segment) whose silhouette is whole
    /// on the detector in every view and cell.
    fn pooled(&self, target: &str) -> bool {
        !is_segment(target) && !self.cut.iter().any(|(t, _)| t == target)
    }

    /// The pooled targets and the others (segments and cut targets, each reported apart), in order.
    fn split_targets(&self, targets: Vec<String>) -> (Vec<String>, Vec<String>) {
        targets.into_iter().partition(|t| self.pooled(t))
    }

    /// The single levels and the segments: for tables the detector's edge does not touch (registration
    /// observes its landmarks analytically, wherever they fall), a cut level is pooled like any other.
    fn split_segments(&self, targets: Vec<String>) -> (Vec<String>, Vec<String>) {
        targets.into_iter().partition(|t| !is_segment(t))
    }

    /// Why `target` is reported apart when the detector cuts it: the views cut in the rows `here` (the
    /// cell being reported: not comparable), else the views cut in other cells; nothing when whole.
    fn cut_note(&self, target: &str, here: &[usize]) -> String {
        let views = |cut: &dyn Fn(&str) -> bool| -> Vec<String> {
            ["ap", "lat"]
                .iter()
                .filter(|v| cut(v))
                .map(|v| v.to_uppercase())
                .collect()
        };
        let t = &self.projection;
        let now = views(&|v: &str| {
            here.iter().any(|&i| {
                t.rows[i].get("view").is_some_and(|x| x == v)
                    && t.rows[i].get("cut_by_edge").is_some_and(|x| x == "true")
            })
        });
        if !now.is_empty() {
            return format!(
                " (cut by the detector edge in {} here: not comparable)",
                now.join(" and ")
            );
        }
        let ever = views(&|v: &str| self.cut.contains(&(target.to_string(), v.to_string())));
        if ever.is_empty() {
            String::new()
        } else {
            format!(
                " (cut by the detector edge in {} in other cells)",
                ever.join(" and ")
            )
        }
    }
}

/// `tables/findings.json`.
#[derive(Serialize)]
struct FindingsFile<'a> {
    /// How to read it.
    about: &'static str,
    findings: &'a [Finding],
}

const ABOUT: &str = "Each finding is one bullet of report.md's Findings: its Markdown text, the claims \
(numbers) it prints (text) or builds on (text null), and its categorical facts. A claim's source says how \
to recompute it from the CSV tables under tables/ (rows: 0-based data rows matching `where`, whose cells \
are compared as text) or their points (points), from other claims (formula, count_greater) or facts \
(count_word), from a list (count), from reference/paper-results.toml (paper) or study.toml (config), from a size \
in px and a reference sidecar's pixel pitch (detector: px × sdd_mm / K[0][0], in mm), or names a rule \
constant (rule). A fact's word follows from its rule applied to the claims it lists.";

/// Everything the section needs beyond the tables.
pub struct Context<'a> {
    pub out: &'a Path,
    pub paper: &'a PaperResults,
    pub first: &'a str,
    pub ratios: &'a [TargetRatio],
    pub piercing: [[f64; 2]; 2],
    pub noise_px: f64,
    pub calibration_trials: usize,
    /// The detector's pixel pitch along u (mm), where the geometry states it.
    pub pitch: Option<f64>,
}

/// Computes the findings, writes `tables/findings.json` and the *Findings* section (nothing when no
/// table has rows).
pub fn section(md: &mut String, t: &StudyTables, cx: &Context) -> Result<()> {
    let projection = Table::of(&t.projection);
    // Cut where the reference silhouette touches the detector's edge, or the perturbed one of any cell.
    let mut cut: BTreeSet<(String, String)> = projection
        .distinct(&claim::Where::new(), "target")
        .into_iter()
        .flat_map(|tg| ["ap", "lat"].map(|v| (tg.clone(), v.to_string())))
        .filter(|(tg, v)| super::setup::cut_by_edge(cx.out, tg, v))
        .collect();
    cut.extend(
        t.projection
            .iter()
            .filter(|r| r.cut_by_edge)
            .map(|r| (r.target.clone(), r.view.clone())),
    );
    let inputs = Inputs {
        projection,
        structures: Table::of(&t.structures),
        landmarks: Table::of(&t.landmarks),
        registration: Table::of(&t.registration_summary),
        calibration: Table::of(&t.calibration),
        calibration_trials: cx.calibration_trials,
        paper: cx.paper,
        first: cx.first,
        cut,
        ratios: cx.ratios,
        piercing: cx.piercing,
        noise_px: cx.noise_px,
        pitch: pitch_reference(cx),
    };
    let findings: Vec<Finding> = [
        landmarks::ratio(&inputs),
        projection::dice_by_family(&inputs),
        projection::structures(&inputs),
        registration::by_family(&inputs),
        projection::versus_paper(&inputs),
        landmarks::versus_paper(&inputs),
        registration::versus_paper(&inputs),
        calibration::headline(&inputs),
    ]
    .into_iter()
    .flatten()
    .collect();
    let json = serde_json::to_vec_pretty(&FindingsFile {
        about: ABOUT,
        findings: &findings,
    })
    .map_err(|e| crate::Error::format(FILE, e.to_string()))?;
    let dir = cx.out.join("tables");
    std::fs::create_dir_all(&dir).map_err(|e| crate::Error::io(&dir, e))?;
    write_atomic_bytes(&dir.join(FILE), &json)?;
    if findings.is_empty() {
        return Ok(());
    }
    let _ = writeln!(md, "## Findings\n");
    let _ = writeln!(
        md,
        "Every number below is in [{FILE}](tables/{FILE}) with the table rows it is computed from.\n"
    );
    for f in &findings {
        let _ = writeln!(md, "- {}", f.text);
    }
    let _ = writeln!(md);
    Ok(())
}

/// The first target's first reference sidecar (`references/<first>_<view>.json`) beside the pitch,
/// where both exist.
fn pitch_reference(cx: &Context) -> Option<(String, f64)> {
    let pitch = cx.pitch?;
    ["ap", "lat"]
        .iter()
        .map(|v| format!("references/{}_{v}.json", cx.first))
        .find(|r| cx.out.join(r).is_file())
        .map(|r| (r, pitch))
}

/// Links to the table of rows `R` and a figure, for the end of a finding.
fn sources<R: TableRow>(fig: &str) -> String {
    format!("({}, {})", table::<R>(), figure(fig))
}
