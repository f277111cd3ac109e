//! `report.md`: what the study produced and the paper's reported figures
//! (`reference/paper-results.toml`, embedded) beside ours.

use std::fmt::Write as _;
use std::path::Path;

use super::config::StudyConfig;
use super::runner::RunFacts;
use super::tables::Table;
use super::timings::{TimingRow, to_markdown};
use crate::io::write_atomic_bytes;
use crate::{Error, Result};

/// The paper's reported figures.
pub const PAPER_RESULTS_TOML: &str = include_str!("../../reference/paper-results.toml");

fn fmt_err(e: std::fmt::Error) -> Error {
    Error::Numerical(format!("formatting the report: {e}"))
}

/// Our value of `col` for (target, view, family, Δf) in `projection.csv`.
fn projection_value(
    t: &Table,
    target: &str,
    view: &str,
    family: &str,
    df: f64,
    col: &str,
) -> Result<Option<f64>> {
    for r in &t.rows {
        if t.str(r, "target")? == target
            && t.str(r, "view")? == view
            && t.str(r, "family")? == family
            && t.num(r, "df_px")? == df
        {
            return Ok(Some(t.num(r, col)?));
        }
    }
    Ok(None)
}

fn show(v: Option<f64>) -> String {
    v.map_or("n/a".into(), |x| format!("{x:.4}"))
}

/// Writes `out/report.md`; everything above the timing section depends only on the config and the
/// tables, the timing section (`rows`, `run`) on this invocation.
pub fn write(out: &Path, cfg: &StudyConfig, rows: &[TimingRow], run: &RunFacts) -> Result<()> {
    let paper: toml::Value = toml::from_str(PAPER_RESULTS_TOML)
        .map_err(|e| Error::format("reference/paper-results.toml", e.to_string()))?;
    let mut md = String::new();
    writeln!(md, "# spinedrr sensitivity study\n").map_err(fmt_err)?;
    writeln!(
        md,
        "spinedrr {}. Targets: {}; views: {}; seed {}; detector binning {}. The full configuration is \
`study.toml`.\n",
        env!("CARGO_PKG_VERSION"),
        super::units::targets(cfg).join(", "),
        cfg.geometry.views.join(", "),
        cfg.seed,
        cfg.geometry.binning
    )
    .map_err(fmt_err)?;
    renderers_section(&mut md, cfg)?;
    list_dir(&mut md, out, "tables", "Tables")?;
    list_dir(&mut md, out, "figures", "Figures")?;
    let first = super::units::targets(cfg)
        .first()
        .cloned()
        .unwrap_or_default();
    let p = out.join("tables/projection.csv");
    if p.exists() {
        let t = Table::read(&p)?;
        writeln!(
            md,
            "## Silhouette overlap, paper vs ours ({first}; joint = Δf with piercing (p, p), focal = Δf alone)\n"
        )
        .map_err(fmt_err)?;
        writeln!(md, "| quantity | paper | ours |\n|---|---|---|").map_err(fmt_err)?;
        let s = &paper["silhouette"];
        for (view, key, col) in [("lat", "lat_dice", "dice"), ("lat", "lat_iou", "iou")] {
            for df in [100.0, 500.0] {
                let pv = s
                    .get(key)
                    .and_then(|v| v.get(format!("at_df_{df}")))
                    .and_then(|v| v.as_float());
                for family in ["joint", "focal"] {
                    let ours = projection_value(&t, &first, view, family, df, col)?;
                    writeln!(
                        md,
                        "| {view} {col} at Δf {df} px ({family}) | {} | {} |",
                        show(pv),
                        show(ours)
                    )
                    .map_err(fmt_err)?;
                }
            }
        }
        let ap_min = t
            .rows
            .iter()
            .filter(|r| r[0] == first && r[1] == "ap" && r[2] == "joint")
            .filter_map(|r| t.num(r, "dice").ok())
            .fold(f64::INFINITY, f64::min);
        let pv = s.get("ap_dice_min").and_then(|v| v.as_float());
        writeln!(
            md,
            "| ap Dice, minimum over the schedule | {} | {} |\n",
            show(pv),
            show(ap_min.is_finite().then_some(ap_min))
        )
        .map_err(fmt_err)?;
        writeln!(md, "A pure focal change scales the silhouette about the piercing point by α_f = (f + Δf)/f, so Dice \
falls even for a vertebra on the central ray; the paper's AP Dice > 0.997 cannot come from this model. We report \
what the model gives rather than tuning to the paper.\n").map_err(fmt_err)?;
    }
    let p = out.join("tables/landmarks.csv");
    if p.exists() {
        landmark_section(&mut md, &Table::read(&p)?, &paper, &first)?;
    }
    let p = out.join("tables/registration_summary.csv");
    if p.exists() {
        registration_section(&mut md, &Table::read(&p)?, &paper, &first)?;
    }
    timings_section(&mut md, rows, run)?;
    write_atomic_bytes(&out.join("report.md"), md.as_bytes())
}

/// Which renderer feeds which measurement, per kind of target.
fn renderers_section(md: &mut String, cfg: &StudyConfig) -> Result<()> {
    writeln!(md, "## How each measurement is made\n").map_err(fmt_err)?;
    writeln!(
        md,
        "- Landmark shifts: a small marker sphere at each 3-D landmark is rendered alone and its blob \
centroid measured, in the reference and the perturbed view; the homography prediction H·x is beside it."
    )
    .map_err(fmt_err)?;
    writeln!(
        md,
        "- Phantom levels and mesh targets: silhouettes, contours and image metrics (NCC, SSIM, MI, GC, \
heatmaps) all come from the thickness DRR (Σ μ·L through the closed surfaces, Embree or BVH)."
    )
    .map_err(fmt_err)?;
    if !cfg.anatomy.ct.is_empty() {
        writeln!(
            md,
            "- CT targets ({}): image metrics and heatmaps come from the CT volume DRR (Siddon's exact \
line integral of μ(HU) through the CT, masked to the level's label), as the paper renders DRRs; \
silhouettes and contours from a thickness render of the label's closed surface (its ray-hit mask); \
landmarks are automatic landmarks of that surface unless a landmarks file is given. Each CT target is \
translated so its body centre sits where the views aim. The label surface carries no structure labels, so \
structures.csv has no rows for CT targets.",
            cfg.anatomy
                .ct
                .iter()
                .map(|c| c.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )
        .map_err(fmt_err)?;
    }
    writeln!(md).map_err(fmt_err)
}

/// Where this invocation's time went.
fn timings_section(md: &mut String, rows: &[TimingRow], run: &RunFacts) -> Result<()> {
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    writeln!(md, "## Where the time goes (this invocation)\n").map_err(fmt_err)?;
    writeln!(
        md,
        "{} of {} work units ran in this invocation ({} reused from an earlier one), on {} worker \
threads ({cores} cores available). Wall-clock phases are elapsed time; the indented unit phases are summed \
over worker threads, so together they are about threads × the units' wall time. Report writing itself is \
in timings.csv.\n",
        run.ran_units,
        run.total_units,
        run.total_units - run.ran_units,
        run.threads
    )
    .map_err(fmt_err)?;
    // The report's own writing time is not known yet: it is in timings.csv.
    let rows: Vec<TimingRow> = rows
        .iter()
        .filter(|r| !r.phase.starts_with("report"))
        .cloned()
        .collect();
    writeln!(md, "{}", to_markdown(&rows)?).map_err(fmt_err)
}

fn list_dir(md: &mut String, out: &Path, dir: &str, title: &str) -> Result<()> {
    let path = out.join(dir);
    let mut names: Vec<String> = std::fs::read_dir(&path)
        .map_err(|e| Error::io(&path, e))?
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| !n.starts_with('.'))
        .collect();
    names.sort();
    writeln!(md, "## {title}\n").map_err(fmt_err)?;
    for n in names {
        if n.ends_with(".png") {
            writeln!(md, "- ![{n}]({dir}/{n})").map_err(fmt_err)?;
        } else {
            writeln!(md, "- [{n}]({dir}/{n})").map_err(fmt_err)?;
        }
    }
    writeln!(md).map_err(fmt_err)
}

fn landmark_section(md: &mut String, t: &Table, paper: &toml::Value, first: &str) -> Result<()> {
    let df = 100.0;
    writeln!(md, "## Landmark shift (px), focal Δf = {df} px, {first}: paper vs ours (measured from marker images; H·x predicted)\n").map_err(fmt_err)?;
    writeln!(md, "| landmark | paper AP | ours AP (pred) | paper LAT | ours LAT (pred) |\n|---|---|---|---|---|").map_err(fmt_err)?;
    let mut names: Vec<String> = Vec::new();
    for r in &t.rows {
        let n = t.str(r, "landmark")?.to_string();
        if t.str(r, "target")? == first && !names.contains(&n) {
            names.push(n);
        }
    }
    let lp = paper.get("landmark_shift_px");
    for n in names {
        let mut cells = Vec::new();
        for (i, view) in ["ap", "lat"].iter().enumerate() {
            let p = lp
                .and_then(|v| v.get(n.as_str()))
                .and_then(|v| v.get(i))
                .and_then(|v| v.as_float());
            let row = t.rows.iter().find(|r| {
                r[0] == first
                    && r[1] == *view
                    && r[2] == "focal"
                    && t.num(r, "df_px").ok() == Some(df)
                    && r[6] == n
            });
            let ours = match row {
                Some(r) => format!(
                    "{:.2} ({:.2})",
                    t.num(r, "shift_px")?,
                    t.num(r, "pred_shift_px")?
                ),
                None => "n/a".into(),
            };
            cells.push((show(p), ours));
        }
        writeln!(
            md,
            "| {n} | {} | {} | {} | {} |",
            cells[0].0, cells[0].1, cells[1].0, cells[1].1
        )
        .map_err(fmt_err)?;
    }
    writeln!(md).map_err(fmt_err)
}

/// Range (min, max) of the per-cell mean of `col` for `method` on `target`, over Δf > 0.
fn summary_range(t: &Table, target: &str, method: &str, col: &str) -> Result<Option<(f64, f64)>> {
    let mut r: Option<(f64, f64)> = None;
    for row in &t.rows {
        if t.str(row, "target")? == target
            && t.str(row, "method")? == method
            && t.num(row, "df_px")? > 0.0
        {
            let v = t.num(row, col)?;
            if v.is_finite() {
                r = Some(r.map_or((v, v), |(a, b)| (a.min(v), b.max(v))));
            }
        }
    }
    Ok(r)
}

fn registration_section(
    md: &mut String,
    t: &Table,
    paper: &toml::Value,
    first: &str,
) -> Result<()> {
    writeln!(
        md,
        "## Registration error over Δf > 0 and all piercing shifts ({first}): paper vs ours\n"
    )
    .map_err(fmt_err)?;
    writeln!(
        md,
        "| quantity | paper range | ours (min – max of trial means) |\n|---|---|---|"
    )
    .map_err(fmt_err)?;
    let reg = paper.get("registration");
    for (key, method, col) in [
        ("kabsch_rotation_deg", "kabsch", "rot_err_deg_mean"),
        ("kabsch_translation_mm", "kabsch", "trans_err_mm_mean"),
        ("direct_rotation_deg", "direct-ap+lat", "rot_err_deg_mean"),
        (
            "direct_translation_mm",
            "direct-ap+lat",
            "trans_err_mm_mean",
        ),
    ] {
        let p = reg
            .and_then(|r| r.get(key))
            .and_then(|v| v.as_array())
            .map(|a| {
                a.iter()
                    .filter_map(|x| x.as_float())
                    .map(|x| format!("{x}"))
                    .collect::<Vec<_>>()
                    .join(" – ")
            })
            .unwrap_or_else(|| "n/a".into());
        let ours = summary_range(t, first, method, col)?
            .map_or("n/a".into(), |(a, b)| format!("{a:.3} – {b:.3}"));
        writeln!(md, "| {method} {col} | {p} | {ours} |").map_err(fmt_err)?;
    }
    writeln!(md, "\nSingle-view methods (direct-ap, direct-lat, opencv-*) cannot separate a focal error from depth: \
their translation error is about z·Δf/f along the central ray (see registration_summary.csv). \
Landmarks whose marker falls off the detector (far levels of the segment in LAT) have NaN measurements in landmarks.csv.\n").map_err(fmt_err)
}
