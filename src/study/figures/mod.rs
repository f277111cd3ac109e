//! Figures drawn from the study's typed tables, each as PNG and SVG: the paper-style composed figures
//! ([`composed`]: |ΔDRR| heatmap panels, AP-beside-LAT landmark overlays, pooled Dice/IoU, registration
//! error beside the paper's ranges), and the detail charts (metric-vs-perturbation lines, per-structure
//! Dice, per-view overlays, per-method registration panels). `figures/index.json` lists them with
//! their captions.

use std::collections::BTreeMap;
use std::path::Path;

mod calibration;
mod canvas;
mod chart;
mod charts;
pub mod cohort;
mod composed;
pub mod heatmap_panel;
mod intensity;
mod labels;
pub mod manifest;
mod overlap;
mod overlay;
mod overlay_draw;
mod overlay_key;
mod overlay_points;
mod registration;
mod scale_bar;
mod screws;
mod setup;

pub use canvas::{Figure, Raster, svg_path, write_figure};
pub use chart::{Mark, Panel, Series};
pub use charts::{PanelChart, line_chart, panel_chart};
pub use manifest::{FigureEntry, Section};

use super::config::StudyConfig;
use super::schema::{Family, LandmarkRow, ProjectionRow, StructureRow, StudyTables};
use crate::{Error, Result};

/// Width (px) at which the report shows a figure (its HTML preview; wider figures are scaled down to
/// it).
pub const PAGE_WIDTH_PX: u32 = 1000;
/// The least text height (px, the font size plotters draws) a figure may show at [`PAGE_WIDTH_PX`].
pub const MIN_TEXT_PX: f64 = 12.0;

/// A font size (px) at least `at_least` that stays [`MIN_TEXT_PX`] high when a figure `width_px` wide
/// is scaled to [`PAGE_WIDTH_PX`].
fn legible(width_px: u32, at_least: u32) -> u32 {
    let scaled = MIN_TEXT_PX * f64::from(width_px) / f64::from(PAGE_WIDTH_PX);
    at_least.max(scaled.ceil() as u32)
}

/// The detector's u pixel spacing (mm, binned) where the geometry states it (not for an explicit K):
/// the scale bars' unit.
fn mm_per_px(cfg: &StudyConfig) -> Option<f64> {
    let (g, _) = cfg.geometry_config().ok()?;
    g.detector.stated_pixel_spacing_mm().map(|s| s[0])
}

/// Groups the rows passing `keep` by `group` and collects their (x, y) points, x-sorted.
fn grouped<R>(
    rows: &[R],
    keep: impl Fn(&R) -> bool,
    group: impl Fn(&R) -> String,
    xy: impl Fn(&R) -> (f64, f64),
) -> Vec<Series> {
    let mut m: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
    for r in rows.iter().filter(|r| keep(r)) {
        m.entry(group(r)).or_default().push(xy(r));
    }
    m.into_iter()
        .map(|(label, mut points)| {
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            Series::line(label, points)
        })
        .collect()
}

/// Series labelled "<target> <view>" styled one colour per target (in the order of `targets`), AP solid
/// and LAT dashed.
fn by_target_and_view(series: Vec<Series>, targets: &[&str]) -> Vec<Series> {
    series
        .into_iter()
        .map(|s| {
            let (target, view) = s.label.rsplit_once(' ').unwrap_or((&s.label, ""));
            let colour = targets.iter().position(|t| *t == target).unwrap_or(0);
            let dashed = view == "lat";
            s.styled(colour, dashed)
        })
        .collect()
}

/// Averages the y of points sharing an x (landmarks → mean shift per Δf).
fn mean_per_x(s: Series) -> Series {
    let mut m: BTreeMap<u64, (f64, f64, usize)> = BTreeMap::new();
    for (x, y) in s.points {
        let e = m.entry(x.to_bits()).or_insert((x, 0.0, 0));
        e.1 += y;
        e.2 += 1;
    }
    let mut points: Vec<(f64, f64)> = m.into_values().map(|(x, y, n)| (x, y / n as f64)).collect();
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    Series::line(s.label, points)
}

/// The projection metrics drawn against the joint perturbation: (value, axis label, file).
type ProjectionMetric = (fn(&ProjectionRow) -> f64, &'static str, &'static str);

const PROJECTION_FIGURES: [ProjectionMetric; 5] = [
    (|r| r.dice, "Dice", "dice_vs_perturbation.png"),
    (|r| r.iou, "IoU", "iou_vs_perturbation.png"),
    (
        |r| r.chamfer_mean_px,
        "mean Chamfer distance (px)",
        "chamfer_vs_perturbation.png",
    ),
    (
        |r| r.ssim,
        "SSIM (anatomy region)",
        "ssim_vs_perturbation.png",
    ),
    (|r| r.ncc, "NCC (anatomy region)", "ncc_vs_perturbation.png"),
];

/// Writes every figure of the non-empty `tables` to `out/figures` (PNG and SVG) and their manifest;
/// returns how many PNGs `figures/` holds (with the heatmaps the units wrote). Overlays read the
/// reference DRRs under `out`, the heatmap panels the difference images.
pub fn write_all(out: &Path, cfg: &StudyConfig, tables: &StudyTables) -> Result<usize> {
    let figs = out.join("figures");
    let conditions = composed::Conditions::of(cfg, tables);
    let mut entries = Vec::new();
    if setup::write(out, cfg, &super::units::targets(cfg), &figs)? {
        entries.push(conditions.entry(
            Section::Setup,
            setup::FILE,
            "Each view drawn to scale",
            "every view seen from beside the beam at one scale in mm: the source (red dot), the \
central ray (dashed) to the piercing point, the detector (black bar, its extent along v at the SDD), the \
beam's fan to the detector's edges, the aim (cross) and each target's outline where the study placed it \
(the convex hull of its surface in the view's camera frame; one colour per target as in the other \
figures; the single levels all sit at the world origin, so their outlines overlap); horizontal is depth from the source along the central ray, vertical the offset along the \
detector's v axis, up = the top row",
            true,
        ));
    }
    entries.extend(composed::write(out, cfg, tables, &conditions)?);
    let joint: Vec<&ProjectionRow> = tables
        .projection
        .iter()
        .filter(|r| r.family == Family::Joint)
        .collect();
    if !tables.projection.is_empty() {
        for (value, label, file) in PROJECTION_FIGURES {
            let targets = distinct(joint.iter().map(|r| r.target.as_str()));
            // One colour per target, one line style per view (AP solid, LAT dashed).
            let s = by_target_and_view(
                grouped(
                    &joint,
                    |_| true,
                    |r| format!("{} {}", r.target, r.view),
                    |r| (r.df_px, value(r)),
                ),
                &targets,
            );
            let title = format!("{label} vs joint perturbation (Δf with piercing (p, p))");
            line_chart(
                &figs.join(file),
                &title,
                "focal offset Δf (px), with the piercing shift (p, p) paired in order",
                label,
                s,
            )?;
            entries.push(conditions.entry(
                Section::Projection,
                file,
                &title,
                "one colour per target, AP solid and LAT dashed; along x, Δf and the piercing shift \
                 change together (the joint family)",
                false,
            ));
        }
    }
    let lm = &tables.landmarks;
    if !lm.is_empty() {
        let focal: Vec<&LandmarkRow> = lm.iter().filter(|r| r.family == Family::Focal).collect();
        // Per target and view, the landmarks measured at every focal Δf (a landmark leaving the
        // detector at a large Δf would change the set, and the mean, along the line).
        let dfs = distinct(focal.iter().map(|r| r.df_px));
        let fixed = |r: &LandmarkRow| {
            dfs.iter().all(|&d| {
                focal.iter().any(|q| {
                    q.target == r.target
                        && q.view == r.view
                        && q.landmark == r.landmark
                        && q.df_px == d
                        && q.shift_px.is_finite()
                })
            })
        };
        let kept: Vec<&LandmarkRow> = focal.iter().copied().filter(|r| fixed(r)).collect();
        let targets = distinct(kept.iter().map(|r| r.target.as_str()));
        let mean_of = |value: fn(&LandmarkRow) -> f64| {
            grouped(
                &kept,
                |_| true,
                |r| format!("{} {}", r.target, r.view),
                move |r| (r.df_px, value(r)),
            )
            .into_iter()
            .map(mean_per_x)
            .collect::<Vec<Series>>()
        };
        let (measured, predicted) = (mean_of(|r| r.shift_px), mean_of(|r| r.pred_shift_px));
        // How far the H·x prediction's mean is from the measured one, over every point drawn.
        let gap = measured
            .iter()
            .zip(&predicted)
            .flat_map(|(m, p)| {
                m.points
                    .iter()
                    .zip(&p.points)
                    .map(|(a, b)| (a.1 - b.1).abs())
            })
            .fold(0.0, f64::max);
        let s = by_target_and_view(measured, &targets);
        let title = "Mean landmark shift vs focal offset";
        let file = "landmark_shift_vs_df.png";
        line_chart(
            &figs.join(file),
            title,
            "focal offset Δf (px)",
            "mean landmark shift (px)",
            s,
        )?;
        entries.push(conditions.entry(
            Section::Landmarks,
            file,
            title,
            &format!(
                "measured mean over each target's landmarks that are on the detector at every Δf, \
                 one colour per target, AP solid and LAT dashed, focal family; the H·x prediction's \
                 mean differs from the measured one by at most {gap:.3} px at any point"
            ),
            false,
        ));
    }
    entries.extend(structure_figures(&tables.structures, &figs, &conditions)?);
    registration::registration_figures(&tables.registration_summary, &figs)?;
    for target in distinct(
        tables
            .registration_summary
            .iter()
            .map(|r| r.target.as_str()),
    ) {
        for (tag, what) in [
            ("rot", "rotation"),
            ("trans", "translation"),
            ("residual", "reprojection residual"),
        ] {
            let file = format!("registration_{target}_{tag}.png");
            let title = format!("{target}: {what} error vs focal offset, every method");
            entries.push(conditions.entry(
                Section::Registration,
                &file,
                &title,
                &format!(
                    "a panel per method, a line per piercing shift, mean over {}, whiskers the 95 % \
confidence interval of the mean where trials vary; each panel has its own y scale, except that a method's \
AP and LAT panels (direct-ap and direct-lat, opencv-ap and opencv-lat) share one",
                    conditions.trials
                ),
                false,
            ));
        }
    }
    if let Some((m, rows)) = super::cohort::cohort_of(out, cfg, tables) {
        entries.extend(cohort::write(&figs, &rows, m.cases.len())?);
    }
    entries.extend(calibration::figures(&figs, tables, &conditions)?);
    entries.extend(intensity::figures(&figs, tables, &conditions)?);
    entries.extend(screws::figures(out, cfg, tables, &figs, &conditions)?);
    manifest::write(&figs, &entries)?;
    let n = std::fs::read_dir(&figs)
        .map_err(|e| Error::io(&figs, e))?
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".png"))
        .count();
    Ok(n)
}

/// Values in order of first appearance.
pub(crate) fn distinct<T: PartialEq + Clone>(values: impl IntoIterator<Item = T>) -> Vec<T> {
    let mut v: Vec<T> = Vec::new();
    for x in values {
        if !v.contains(&x) {
            v.push(x);
        }
    }
    v
}

/// Per-structure Dice vs Δf (focal family), one figure per target with a panel per view (the views at
/// one y scale, a structure in one colour in every panel).
fn structure_figures(
    rows: &[StructureRow],
    figs: &Path,
    conditions: &composed::Conditions,
) -> Result<Vec<FigureEntry>> {
    let mut entries = Vec::new();
    let targets = distinct(rows.iter().map(|r| r.target.as_str()));
    let views = distinct(rows.iter().map(|r| r.view.as_str()));
    for target in &targets {
        let mine = |r: &StructureRow| r.target == *target && r.family == Family::Focal;
        let mut names = distinct(rows.iter().filter(|r| mine(r)).map(|r| r.structure.clone()));
        names.sort();
        let panels: Vec<Panel> = views
            .iter()
            .map(|v| Panel {
                title: v.to_uppercase(),
                series: grouped(
                    rows,
                    |r| mine(r) && r.view == *v,
                    |r| r.structure.clone(),
                    |r| (r.df_px, r.dice),
                )
                .into_iter()
                .map(|s| {
                    let colour = names.iter().position(|n| *n == s.label).unwrap_or(0);
                    s.styled(colour, false)
                })
                .collect(),
                marks: Vec::new(),
            })
            .filter(|p| !p.series.is_empty())
            .collect();
        if panels.is_empty() {
            continue;
        }
        let file = format!("structures_dice_{target}.png");
        let title = format!("Per-structure Dice vs focal offset ({target})");
        let cols = panels.len();
        panel_chart(
            &figs.join(&file),
            &title,
            "focal offset Δf (px)",
            "Dice",
            panels,
            cols,
        )?;
        entries.push(conditions.entry(
            Section::Projection,
            &file,
            &title,
            "a panel per view, the views at one y scale, a line per anatomical structure, focal family",
            false,
        ));
    }
    Ok(entries)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Landmark and structure rows of `targets` × {ap, lat} × Δf {100, 500} (focal).
    pub(crate) fn rows(targets: &[&str]) -> (Vec<LandmarkRow>, Vec<StructureRow>) {
        let (mut lm, mut st) = (Vec::new(), Vec::new());
        for target in targets {
            for view in ["ap", "lat"] {
                for df in [100.0, 500.0] {
                    for (i, name) in ["center", "spinous_tip"].iter().enumerate() {
                        let (u, v) = (300.0 + 50.0 * i as f64, 400.0);
                        let s = df * 1e-3;
                        lm.push(LandmarkRow {
                            target: target.to_string(),
                            view: view.into(),
                            family: Family::Focal,
                            df_px: df,
                            dcx_px: 0.0,
                            dcy_px: 0.0,
                            landmark: name.to_string(),
                            ref_u_px: u,
                            ref_v_px: v,
                            meas_u_px: u + s,
                            meas_v_px: v,
                            shift_px: s,
                            pred_u_px: u + s,
                            pred_v_px: v,
                            pred_shift_px: s,
                            pred_error_px: 0.0,
                        });
                    }
                    for s in ["body", "pedicle_left"] {
                        st.push(StructureRow {
                            target: target.to_string(),
                            view: view.into(),
                            family: Family::Focal,
                            df_px: df,
                            dcx_px: 0.0,
                            dcy_px: 0.0,
                            structure: s.into(),
                            dice: 1.0 - df * 1e-4,
                            iou: 0.9,
                        });
                    }
                }
            }
        }
        (lm, st)
    }

    /// Every target gets its own landmark overlays (one per view) and per-structure figure.
    #[test]
    fn overlays_and_structure_figures_for_every_target() {
        let dir = tempfile::tempdir().expect("temp dir");
        let (lm, st) = rows(&["L1", "segment"]);
        overlay::landmark_overlays(dir.path(), &lm, dir.path(), Some(0.3)).expect("overlays");
        let tables = StudyTables::default();
        let conditions = composed::Conditions::of(&StudyConfig::default(), &tables);
        structure_figures(&st, dir.path(), &conditions).expect("structure figures");
        for target in ["L1", "segment"] {
            let mut files = vec![format!("structures_dice_{target}.png")];
            for view in ["ap", "lat"] {
                files.push(format!("landmark_overlay_{target}_{view}.png"));
            }
            for f in files {
                let img = image::open(dir.path().join(&f)).unwrap_or_else(|e| panic!("{f}: {e}"));
                assert!(img.width() > 100, "{f}");
            }
        }
    }
}
