//! Silhouette overlap as the paper shows it: Dice and IoU against the perturbation magnitude, AP vs LAT,
//! the mean over the vertebral levels as a line with the min–max over levels as a band, the paper's
//! reported values as reference marks.

use std::collections::BTreeMap;

use super::chart::{Mark, Panel, Series};
use crate::study::config::is_segment;
use crate::study::paper::PaperResults;
use crate::study::schema::{Family, ProjectionRow};

/// The targets a figure pools, by the Findings' rule.
#[derive(Debug, Clone, PartialEq)]
pub struct Pooled {
    /// The single levels whose silhouettes are whole on the detector in every view and cell; when no
    /// level is, every level ([`Pooled::all_cut`]); with no level at all, the segments.
    pub targets: Vec<String>,
    /// The levels cut by the detector's edge in some cell, left out of `targets`.
    pub left_out: Vec<String>,
    /// Every level is cut in some cell, so `targets` are cut ones.
    pub all_cut: bool,
}

/// The targets pooled: the single levels (never a segment: `segment`, `<name>-segment`) whose
/// silhouette no cell's row marks cut by the detector's edge; the cut ones are left out and named.
pub fn pooled_targets(rows: &[ProjectionRow]) -> Pooled {
    let all = super::distinct(rows.iter().map(|r| r.target.clone()));
    let cut = |t: &String| rows.iter().any(|r| r.target == *t && r.cut_by_edge);
    let (levels, segments): (Vec<String>, Vec<String>) =
        all.into_iter().partition(|t| !is_segment(t));
    let (whole, left_out): (Vec<String>, Vec<String>) =
        levels.iter().cloned().partition(|t| !cut(t));
    match (whole.is_empty(), levels.is_empty()) {
        (false, _) => Pooled {
            targets: whole,
            left_out,
            all_cut: false,
        },
        (true, false) => Pooled {
            targets: levels,
            left_out: Vec::new(),
            all_cut: true,
        },
        (true, true) => Pooled {
            all_cut: segments.iter().any(cut),
            targets: segments,
            left_out: Vec::new(),
        },
    }
}

/// Per view: (x, mean, min, max) of `value` over `targets` at each Δf of `family`.
fn pooled(
    rows: &[ProjectionRow],
    targets: &[String],
    family: Family,
    view: &str,
    value: fn(&ProjectionRow) -> f64,
) -> Series {
    let mut by_df: BTreeMap<u64, (f64, Vec<f64>)> = BTreeMap::new();
    for r in rows.iter().filter(|r| {
        r.family == family && r.view == view && targets.contains(&r.target) && value(r).is_finite()
    }) {
        by_df
            .entry(r.df_px.to_bits())
            .or_insert((r.df_px, Vec::new()))
            .1
            .push(value(r));
    }
    let mut cells: Vec<(f64, Vec<f64>)> = by_df.into_values().collect();
    cells.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut s = Series::line(
        format!("{} mean over levels", view.to_uppercase()),
        Vec::new(),
    );
    for (df, v) in cells {
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        s.points.push((df, mean));
        s.band.push((lo, hi));
    }
    s
}

/// The Dice and IoU panels of `family` (x: Δf) with the paper's values: LAT at Δf 100 and 500 as
/// points in the LAT colour, the AP Dice minimum as a dashed level in the AP colour.
pub fn overlap_panels(
    rows: &[ProjectionRow],
    targets: &[String],
    family: Family,
    paper: &PaperResults,
) -> Vec<Panel> {
    let views = ["ap", "lat"];
    let s = &paper.silhouette;
    type Metric = (&'static str, fn(&ProjectionRow) -> f64);
    let metrics: [Metric; 2] = [("Dice", |r| r.dice), ("IoU", |r| r.iou)];
    metrics
        .iter()
        .map(|&(name, value)| {
            let series: Vec<Series> = views
                .iter()
                .map(|v| pooled(rows, targets, family, v, value))
                .collect();
            let lat = if name == "Dice" {
                s.lat_dice
            } else {
                s.lat_iou
            };
            let mut marks: Vec<Mark> = [100.0, 500.0]
                .into_iter()
                .filter_map(|df| {
                    lat.at(df).map(|y| Mark::Point {
                        x: df,
                        y,
                        colour: 1,
                    })
                })
                .collect();
            if name == "Dice" {
                marks.push(Mark::Level {
                    y: s.ap_dice_min,
                    colour: 0,
                });
            }
            Panel {
                title: name.to_string(),
                series,
                marks,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(target: &str, view: &str, df: f64, dice: f64) -> ProjectionRow {
        ProjectionRow {
            target: target.into(),
            view: view.into(),
            family: Family::Joint,
            df_px: df,
            dcx_px: 0.0,
            dcy_px: 0.0,
            skew_px: 0.0,
            sy: 1.0,
            cut_by_edge: false,
            dice,
            iou: dice,
            chamfer_mean_px: 0.0,
            hausdorff_px: 0.0,
            hd95_px: 0.0,
            edge_distance_mean_px: 0.0,
            ncc: 1.0,
            ssim: 1.0,
            mutual_information_nats: 1.0,
            gradient_correlation: 1.0,
            region_margin_px: 10,
            region_px: 100,
            ncc_detector: 1.0,
            ssim_detector: 1.0,
            mutual_information_nats_detector: 1.0,
            gradient_correlation_detector: 1.0,
            mean_abs_diff: 0.0,
        }
    }

    /// The line is the mean over levels, the band their min and max; no segment is pooled (a CT's
    /// `<name>-segment` no more than the phantom's `segment`), nor a level cut by the detector's edge.
    #[test]
    fn mean_and_band_over_levels() {
        let mut cut = row("L4", "ap", 100.0, 0.50);
        cut.cut_by_edge = true;
        let rows = vec![
            row("L1", "lat", 100.0, 0.90),
            row("L2", "lat", 100.0, 0.96),
            row("L3", "lat", 100.0, 0.93),
            row("L4", "lat", 100.0, 0.99),
            cut,
            row("segment", "lat", 100.0, 0.10),
            row("ct-segment", "lat", 100.0, 0.20),
        ];
        let pooled_ = pooled_targets(&rows);
        assert_eq!(pooled_.left_out, ["L4"]);
        assert!(!pooled_.all_cut);
        let targets = pooled_.targets;
        assert_eq!(targets, ["L1", "L2", "L3"]);
        let s = pooled(&rows, &targets, Family::Joint, "lat", |r| r.dice);
        assert_eq!(s.points.len(), 1);
        assert!((s.points[0].1 - 0.93).abs() < 1e-12);
        assert_eq!(s.band, [(0.90, 0.96)]);
        let paper = PaperResults::embedded().expect("paper");
        let panels = overlap_panels(&rows, &targets, Family::Joint, &paper);
        assert_eq!(panels.len(), 2);
        assert!(panels[0].marks.contains(&Mark::Point {
            x: 500.0,
            y: paper.silhouette.lat_dice.at_df_500,
            colour: 1
        }));
    }

    /// With every level cut in some cell, the figure pools them all and says so; with only segments,
    /// the segments.
    #[test]
    fn all_cut_levels_or_only_segments_are_pooled_and_flagged() {
        let mut a = row("L1", "ap", 100.0, 0.5);
        a.cut_by_edge = true;
        let p = pooled_targets(&[a, row("segment", "ap", 100.0, 0.4)]);
        assert_eq!((p.targets, p.all_cut), (vec!["L1".to_string()], true));
        let p = pooled_targets(&[row("ct-segment", "ap", 100.0, 0.4)]);
        assert_eq!(
            (p.targets, p.all_cut),
            (vec!["ct-segment".to_string()], false)
        );
    }
}
