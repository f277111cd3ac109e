//! Intensity-registration figures, per target: the final mTRE vs Δf (a panel per view set, a line per
//! piercing shift, the landmark registration's mTRE and its distance to the intensity optimum beside
//! it), and the van de Kraats plot — success rate vs initial mTRE (a panel per view set, a line per
//! assumed K: true and each perturbation).

use std::path::Path;

use super::composed::Conditions;
use super::{FigureEntry, Mark, Panel, Section, Series, distinct, panel_chart};
use crate::Result;
use crate::study::config::FixedImage;
use crate::study::schema::{IntensityBinRow, IntensitySummaryRow, StudyTables};

/// `Δf 300, p 30`, `K true` or the physical error (`det_roll_deg=2`).
fn k_label(df: f64, p: f64, physical: &str) -> String {
    if !physical.is_empty() {
        physical.replace('=', " = ")
    } else if df == 0.0 && p == 0.0 {
        "K true".into()
    } else {
        format!("Δf {df} px, piercing ({p}, {p}) px")
    }
}

fn mtre_panel(rows: &[&IntensitySummaryRow], views: &str) -> Panel {
    // The focal axis has the Δf × piercing cells only.
    let rows: Vec<&&IntensitySummaryRow> = rows
        .iter()
        .filter(|r| r.views == views && r.physical.is_empty())
        .collect();
    let mut series = Vec::new();
    let piercings = {
        let mut p = distinct(rows.iter().map(|r| r.piercing_px));
        p.sort_by(f64::total_cmp);
        p
    };
    type Value = fn(&IntensitySummaryRow) -> f64;
    let values: [(&str, Value); 4] = [
        ("intensity optimum", |r| r.optimum_mtre_mm),
        ("intensity, median of starts", |r| r.final_mtre_median_mm),
        ("landmark", |r| r.landmark_mtre_mm),
        ("intensity optimum to landmark optimum", |r| {
            r.optimum_to_landmark_mm
        }),
    ];
    for (what, value) in values {
        for &p in &piercings {
            let mut points: Vec<(f64, f64)> = rows
                .iter()
                .filter(|r| r.piercing_px == p)
                .map(|r| (r.df_px, value(r)))
                .collect();
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            series.push(Series::line(
                format!("{what}, piercing ({p}, {p}) px"),
                points,
            ));
        }
    }
    Panel {
        title: views.to_uppercase(),
        series,
        marks: Vec::new(),
    }
}

fn success_panel(rows: &[&IntensityBinRow], views: &str, reached: bool) -> Panel {
    let rows: Vec<&&IntensityBinRow> = rows.iter().filter(|r| r.views == views).collect();
    let cells = distinct(rows.iter().map(|r| {
        (
            r.df_px.to_bits(),
            r.piercing_px.to_bits(),
            r.physical.clone(),
        )
    }));
    let series = cells
        .into_iter()
        .map(|(df, p, physical)| {
            let (df, p) = (f64::from_bits(df), f64::from_bits(p));
            let points = rows
                .iter()
                .filter(|r| r.df_px == df && r.piercing_px == p && r.physical == physical)
                .map(|r| {
                    let rate = if reached {
                        r.reached_optimum_rate
                    } else {
                        r.success_rate
                    };
                    (0.5 * (r.bin_lo_mm + r.bin_hi_mm), 100.0 * rate)
                })
                .collect();
            Series::line(k_label(df, p, &physical), points)
        })
        .collect();
    Panel {
        title: if reached {
            format!("{}: reached the optimum under its K", views.to_uppercase())
        } else {
            format!("{}: final mTRE < 2 mm", views.to_uppercase())
        },
        series,
        // Rates on their whole scale: all-100 % panels otherwise span 95–105 %.
        marks: vec![Mark::Extent { lo: 0.0, hi: 100.0 }],
    }
}

/// How the panels of the view sets `sets` are laid out and scaled (panels that differ only by their one
/// view share a y scale: [`super::charts::panel_chart`]).
fn panels_clause(sets: &[String]) -> String {
    let upper: Vec<String> = sets.iter().map(|v| v.to_uppercase()).collect();
    let (single, several): (Vec<&String>, Vec<&String>) =
        upper.iter().partition(|v| !v.contains('+'));
    let join = |v: &[&String]| {
        v.iter()
            .map(|s| s.as_str())
            .collect::<Vec<_>>()
            .join(" and ")
    };
    match (single.len(), several.len()) {
        (0, 1) | (1, 0) => format!("one panel, {}", upper.join("")),
        (0, _) => format!(
            "a panel per view set ({}, each at its own y scale)",
            join(&several)
        ),
        (_, 0) => format!("a panel per view ({} at one y scale)", join(&single)),
        _ => format!(
            "a panel per view set ({} at one y scale, {} at {})",
            join(&single),
            join(&several),
            if several.len() == 1 {
                "its own"
            } else {
                "their own"
            }
        ),
    }
}

/// Writes `intensity_mtre_<target>.png` and `intensity_success_<target>.png` for every target of the
/// intensity tables; returns their manifest entries.
pub fn figures(figs: &Path, tables: &StudyTables, c: &Conditions) -> Result<Vec<FigureEntry>> {
    let mut entries = Vec::new();
    // The monochromatic cells (the spectral ones are compared in the report's table).
    let mono = FixedImage::Mono.name();
    for target in distinct(tables.intensity_summary.iter().map(|r| r.target.clone())) {
        let summary: Vec<&IntensitySummaryRow> = tables
            .intensity_summary
            .iter()
            .filter(|r| r.target == target && r.fixed_image == mono)
            .collect();
        if summary.is_empty() {
            continue;
        }
        let sets = distinct(summary.iter().map(|r| r.views.clone()));
        let cols = sets.len().clamp(1, 3);
        let file = format!("intensity_mtre_{target}.png");
        let title = format!("{target}: final mTRE vs focal offset, intensity beside landmark");
        let panels = sets.iter().map(|v| mtre_panel(&summary, v)).collect();
        panel_chart(
            &figs.join(&file),
            &title,
            "focal offset Δf (px)",
            "final mTRE (mm)",
            panels,
            cols,
        )?;
        let trials = summary.first().map_or(0, |r| r.trials);
        entries.push(c.entry(
            Section::Intensity,
            &file,
            &title,
            &format!(
                "monochromatic fixed images; {}; per piercing shift the mTRE of the intensity optimum (registration \
                 started at the truth), the median final mTRE over {trials} starts, the mTRE of the \
                 landmark registration under the same assumed K, and the mTRE between the two optima \
                 (equal biases can be different poses); the physical errors are in the table, not on \
                 this focal axis",
                panels_clause(&sets)
            ),
            true,
        ));
        let bins: Vec<&IntensityBinRow> = tables
            .intensity_bins
            .iter()
            .filter(|r| r.target == target && r.fixed_image == mono)
            .collect();
        let file = format!("intensity_success_{target}.png");
        let title = format!("{target}: success rate vs initial mTRE (van de Kraats)");
        let panels = [false, true]
            .into_iter()
            .flat_map(|reached| sets.iter().map(move |v| (v, reached)))
            .map(|(v, reached)| success_panel(&bins, v, reached))
            .collect();
        panel_chart(
            &figs.join(&file),
            &title,
            "initial mTRE, bin centre (mm)",
            "success rate (%)",
            panels,
            cols,
        )?;
        entries.push(c.entry(
            Section::Intensity,
            &file,
            &title,
            "monochromatic fixed images; a column per view set, a line per assumed geometry (true, each Δf and piercing shift, each \
             physical error); top: \
             success (final mTRE to the truth < 2 mm; the capture range is the last bin edge of the \
             leading run at ≥ 95 %, stated only with ≥ 10 starts per bin), bottom: the start ended within 2 mm of the intensity optimum \
             under its K (the registration started at the truth), capture without the bias",
            true,
        ));
    }
    Ok(entries)
}

#[cfg(test)]
mod tests {
    use super::panels_clause;

    #[test]
    fn the_caption_names_the_panels_there_are() {
        let sets = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(panels_clause(&sets(&["ap+lat"])), "one panel, AP+LAT");
        assert_eq!(
            panels_clause(&sets(&["ap", "lat"])),
            "a panel per view (AP and LAT at one y scale)"
        );
        assert_eq!(
            panels_clause(&sets(&["ap", "ap+lat", "lat"])),
            "a panel per view set (AP and LAT at one y scale, AP+LAT at its own)"
        );
    }
}
