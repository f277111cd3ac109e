//! The paper-style figures of a study, each with its caption: per target the |ΔDRR| heatmap panel
//! (views × heatmap Δf, one colour scale), landmarks AP beside LAT on the reference DRR, registration
//! error of Kabsch beside direct AP+LAT against the paper's ranges; pooled over levels, Dice and IoU vs
//! the perturbation against the paper's values.

use std::path::Path;

use super::canvas::write_figure;
use super::charts::PanelChart;
use super::heatmap_panel::HeatmapPanel;
use super::manifest::{FigureEntry, Section};
use super::{distinct, overlap, overlay, registration};
use crate::Result;
use crate::io::units::LINE_INTEGRAL_DIFFERENCE;
use crate::study::config::{StudyConfig, is_segment};
use crate::study::paper::PaperResults;
use crate::study::schema::{Family, StudyTables};

/// `x` to `d` decimals.
fn round_to(x: f64, d: usize) -> String {
    format!("{x:.d$}")
}

/// `x` to `n` significant digits in plain notation (no exponent): 2.135, 0.01234.
pub(super) fn significant(x: f64, n: usize) -> String {
    if x == 0.0 || !x.is_finite() {
        return format!("{x}");
    }
    let digits = n as i32 - 1 - x.abs().log10().floor() as i32;
    format!("{x:.*}", digits.max(0) as usize)
}

/// The conditions every caption states.
pub struct Conditions {
    /// Views, detector binning, renderer backend, C-arm geometry.
    pub geometry: String,
    /// Monte-Carlo trials per registration cell.
    pub trials: String,
}

impl Conditions {
    pub fn of(cfg: &StudyConfig, _tables: &StudyTables) -> Conditions {
        let g = &cfg.geometry;
        let carm = g.file.as_ref().map_or_else(
            || "the built-in C-arm".to_string(),
            |f| format!("the C-arm of {}", f.display()),
        );
        let views: Vec<String> = g.views.iter().map(|v| v.to_uppercase()).collect();
        // Perturbation sizes in mm at this detector (as the Setup table gives them per step).
        let sizes = cfg.pixel_pitch_mm().map_or(String::new(), |s| {
            let mm = |px: f64| {
                let v = format!("{:.2}", px * s);
                v.trim_end_matches('0').trim_end_matches('.').to_string()
            };
            format!(
                "; at its {} mm pixels a focal offset Δf of 100 px is an SDD error of {} mm and a piercing \
                 shift of 10 px a move of {} mm along u and v on the detector",
                mm(1.0),
                mm(100.0),
                mm(10.0)
            )
        });
        Conditions {
            geometry: format!(
                "{carm}, views {}, detector binning {}, {} backend{sizes}",
                views.join(" and "),
                g.binning,
                g.backend_name()
            ),
            trials: format!(
                "{} trials per cell, landmarks observed with Gaussian noise σ = {} px",
                cfg.registration.trials, cfg.registration.noise_px
            ),
        }
    }

    /// A manifest entry captioned "`title`: `what`. Geometry: … ."
    pub fn entry(
        &self,
        section: Section,
        file: &str,
        title: &str,
        what: &str,
        primary: bool,
    ) -> FigureEntry {
        FigureEntry {
            section,
            file: file.to_string(),
            title: title.to_string(),
            caption: format!("{title}: {what}. Geometry: {}.", self.geometry),
            primary,
        }
    }
}

/// Writes the composed figures under `out/figures`; returns their manifest entries, in report order.
pub fn write(
    out: &Path,
    cfg: &StudyConfig,
    tables: &StudyTables,
    c: &Conditions,
) -> Result<Vec<FigureEntry>> {
    let figs = out.join("figures");
    let paper = PaperResults::embedded()?;
    let mut entries = Vec::new();
    let p = &tables.projection;
    if !p.is_empty() {
        let pooled = overlap::pooled_targets(p);
        let targets = &pooled.targets;
        let mut panels = overlap::overlap_panels(p, targets, Family::Focal, &paper);
        panels.extend(overlap::overlap_panels(p, targets, Family::Joint, &paper));
        for (i, panel) in panels.iter_mut().enumerate() {
            let family = if i < 2 {
                "focal: Δf alone"
            } else {
                "joint: Δf with piercing (p, p)"
            };
            panel.title = format!("{}, {family}", panel.title);
        }
        let title = "Silhouette overlap vs perturbation magnitude, AP vs LAT";
        let fig = PanelChart {
            title,
            x_label: "focal offset Δf (px)",
            y_labels: vec!["overlap".into()],
            panels,
            cols: 2,
            legend_extra: vec![
                ("▲ paper LAT value".into(), Some(1)),
                ("dashed: paper AP Dice minimum".into(), Some(0)),
            ],
        };
        let file = "silhouette_overlap.png";
        write_figure(&figs.join(file), &fig)?;
        let what = format!(
            "Dice (left) and IoU (right) of the whole-object silhouette against Δf, under a focal offset \
alone (top, focal family) and with the piercing shift (p, p) paired in order (bottom, joint family); the \
line is the mean over {} ({}{}), the band their min–max{}; triangles are the paper's LAT values at Δf 100 \
and 500 px, the dashed line its AP Dice minimum",
            match (targets.len(), targets.iter().all(|t| is_segment(t))) {
                (1, _) => "one target",
                (_, true) => "the segments",
                _ => "the levels",
            },
            targets.join(", "),
            if pooled.all_cut {
                if targets.len() == 1 {
                    ", cut by the detector edge in some cell"
                } else {
                    ", each cut by the detector edge in some cell"
                }
            } else {
                ""
            },
            match pooled.left_out.as_slice() {
                [] => String::new(),
                [one] => format!(" ({one}, cut by the detector edge in some cell, is left out)"),
                more => format!(
                    " ({}, cut by the detector edge in some cell, are left out)",
                    more.join(", ")
                ),
            }
        );
        entries.push(c.entry(Section::Projection, file, title, &what, true));
    }
    let views = cfg.geometry.views.clone();
    let mut dfs = cfg.heatmaps_df_px.clone();
    dfs.sort_by(f64::total_cmp);
    for target in distinct(p.iter().map(|r| r.target.as_str())) {
        let Some(panel) = HeatmapPanel::load(
            out,
            target,
            &views,
            &dfs,
            LINE_INTEGRAL_DIFFERENCE,
            super::mm_per_px(cfg),
        )?
        else {
            continue;
        };
        let file = format!("heatmap_panel_{target}.png");
        write_figure(&figs.join(&file), &panel)?;
        let dfs: Vec<String> = dfs.iter().map(|d| format!("{d}")).collect();
        let what = format!(
            "|A − B| of the reference DRR A and the DRR B under a focal offset alone (focal family), a \
row per view, a column per Δf ({} px), each view cropped around where its differences are non-zero to \
a window of one size for every view ({} px square{}), so the views are drawn at one scale (scale bar in \
each pane); one viridis scale from 0 to {} for every pane, so colours compare across views and Δf",
            dfs.join(", "),
            panel.crops.first().map_or(0, |c| c.side),
            super::mm_per_px(cfg).map_or(String::new(), |s| format!(
                ", {} mm at the detector",
                round_to(f64::from(panel.crops.first().map_or(0, |c| c.side)) * s, 1)
            )),
            significant(panel.scale.max, 4)
        );
        let title = format!("{target}: |ΔDRR| heatmaps");
        entries.push(c.entry(Section::Projection, &file, &title, &what, true));
    }
    if !tables.landmarks.is_empty() {
        for o in overlay::landmark_overlays(out, &tables.landmarks, &figs, super::mm_per_px(cfg))? {
            let views: Vec<String> = o.views.iter().map(|v| v.to_uppercase()).collect();
            let title = format!(
                "{}: landmark displacement, {}",
                o.target,
                views.join(" beside ")
            );
            let what = format!(
                "the {} landmarks on the reference DRR, reference position (green circle), position \
measured from the marker render under a focal offset Δf = {} px (red dot), the shift magnified ×{} (red \
arrow) and the homography prediction H·x at the same magnification (blue cross), each landmark numbered \
(the key under the panes); focal family. The views are drawn at one scale (the same detector window \
size; scale bar in {})",
                o.landmarks,
                o.df_px,
                o.gain,
                if o.scale_in_mm {
                    "mm at the detector"
                } else {
                    "detector px"
                }
            );
            entries.push(c.entry(Section::Landmarks, &o.file, &title, &what, true));
            for (v, upper) in o.views.iter().zip(&views) {
                let file = format!("landmark_overlay_{}_{v}.png", o.target);
                let title = format!("{}: landmarks, {upper} alone", o.target);
                let what = "as the composed figure, one view at its own arrow magnification";
                entries.push(c.entry(Section::Landmarks, &file, &title, what, false));
            }
        }
    }
    let reg = &tables.registration_summary;
    for target in registration::paper_figures(reg, &paper, &figs)? {
        let title = format!("{target}: registration error, Kabsch beside direct AP+LAT");
        let what = format!(
            "rotation (top) and translation (bottom) error of the recovered pose vs the focal offset Δf, \
Kabsch and direct AP+LAT at one y scale in each row, a line per piercing shift (p, p), mean over {}, \
whiskers the 95 % confidence interval of the mean where trials vary; grey bands are the paper's reported \
ranges",
            c.trials
        );
        let file = format!("registration_paper_{target}.png");
        entries.push(c.entry(Section::Registration, &file, &title, &what, true));
    }
    Ok(entries)
}

#[cfg(test)]
mod tests {
    use super::significant;

    #[test]
    fn captions_print_significant_digits_without_an_exponent() {
        assert_eq!(significant(2.13456, 4), "2.135");
        assert_eq!(significant(0.0123456, 3), "0.0123");
        assert_eq!(significant(1234.5, 3), "1234");
        assert_eq!(significant(0.0, 3), "0");
    }
}
