//! Calibration figures: reconstruction-domain error (reprojection RMS, held-out 3-D error) against the
//! vertebral landmark error with their correlation; the distribution of each intrinsic error per σ and
//! phantom; and the ambiguity — two calibrations with equal phantom RMS and very different landmark
//! error, highlighted in their cell's scatter.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::canvas::{Figure, Raster, write_figure};
use super::chart::{Panel, Series, plot_err};
use super::composed::Conditions;
use super::{FigureEntry, Section, distinct, panel_chart};
use crate::Result;
use crate::analysis::percentile;
use crate::study::config::Protocol;
use crate::study::schema::{CalibrationAmbiguityRow, CalibrationRow, StudyTables};

/// Pearson correlation of finite pairs (NaN with fewer than 3).
pub fn correlation(pairs: &[(f64, f64)]) -> f64 {
    let p: Vec<(f64, f64)> = pairs
        .iter()
        .copied()
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .collect();
    if p.len() < 3 {
        return f64::NAN;
    }
    let n = p.len() as f64;
    let (ma, mb) = (
        p.iter().map(|x| x.0).sum::<f64>() / n,
        p.iter().map(|x| x.1).sum::<f64>() / n,
    );
    let cov: f64 = p.iter().map(|(a, b)| (a - ma) * (b - mb)).sum();
    let va: f64 = p.iter().map(|(a, _)| (a - ma).powi(2)).sum();
    let vb: f64 = p.iter().map(|(_, b)| (b - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

/// One scatter panel: groups of points (a colour each), optional highlighted points.
struct ScatterPanel {
    title: String,
    x_label: String,
    y_label: String,
    groups: Vec<(String, Vec<(f64, f64)>)>,
    highlight: Vec<(String, (f64, f64))>,
    log: bool,
}

struct Scatter {
    title: String,
    panels: Vec<ScatterPanel>,
    cols: usize,
}

const PANEL: (u32, u32) = (620, 480);

impl Figure for Scatter {
    fn size(&self) -> (u32, u32) {
        let rows = self.panels.len().div_ceil(self.cols) as u32;
        (PANEL.0 * self.cols as u32, PANEL.1 * rows + 50)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<Vec<Raster>> {
        let (top, body) = root.split_vertically(50);
        top.margin(super::charts::TITLE_MARGIN_PX, 0, 0, 0)
            .titled(&self.title, ("sans-serif", 26))
            .map_err(plot_err)?;
        let rows = self.panels.len().div_ceil(self.cols);
        let areas = body.split_evenly((rows, self.cols));
        let font = super::legible(self.size().0, 14);
        for (p, area) in self.panels.iter().zip(areas) {
            draw_scatter(&area, p, font)?;
        }
        Ok(Vec::new())
    }
}

fn range(v: impl Iterator<Item = f64>, log: bool) -> std::ops::Range<f64> {
    let v: Vec<f64> = v.filter(|x| x.is_finite() && (!log || *x > 0.0)).collect();
    let (lo, hi) = v
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    if lo > hi {
        return if log { 1e-3..1.0 } else { 0.0..1.0 };
    }
    if log {
        (lo / 1.3)..(hi * 1.3)
    } else {
        let pad = ((hi - lo) * 0.05).max(1e-9);
        (lo - pad)..(hi + pad)
    }
}

/// One scatter panel; `font`: tick labels and legend (px).
fn draw_scatter<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    p: &ScatterPanel,
    font: u32,
) -> Result<()> {
    let all = || p.groups.iter().flat_map(|g| g.1.iter().copied());
    let xr = range(all().map(|q| q.0), p.log);
    let yr = range(all().map(|q| q.1), p.log);
    let mut b = ChartBuilder::on(area);
    b.caption(&p.title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70);
    let tick = |v: &f64| {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    };
    macro_rules! body {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(p.x_label.as_str())
                .y_desc(p.y_label.as_str())
                .x_labels(6)
                .y_labels(6)
                .x_label_formatter(&tick)
                .y_label_formatter(&tick)
                .label_style(("sans-serif", font))
                .draw()
                .map_err(plot_err)?;
            for (i, (label, pts)) in p.groups.iter().enumerate() {
                let c = Palette99::pick(i).to_rgba();
                chart
                    .draw_series(
                        pts.iter()
                            .filter(|q| q.0.is_finite() && q.1.is_finite())
                            .map(|&q| Circle::new(q, 3, c.mix(0.6).filled())),
                    )
                    .map_err(plot_err)?
                    .label(label.clone())
                    .legend(move |(x, y)| Circle::new((x + 8, y), 4, c.filled()));
            }
            for (label, q) in &p.highlight {
                chart
                    .draw_series(std::iter::once(Circle::new(*q, 9, BLACK.stroke_width(2))))
                    .map_err(plot_err)?;
                chart
                    .draw_series(std::iter::once(Text::new(
                        label.clone(),
                        (q.0, q.1),
                        ("sans-serif", 16).into_font(),
                    )))
                    .map_err(plot_err)?;
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperLeft)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", font))
                .draw()
                .map_err(plot_err)?;
        }};
    }
    if p.log {
        body!(
            b.build_cartesian_2d(xr.log_scale(), yr.log_scale())
                .map_err(plot_err)?
        );
    } else {
        body!(b.build_cartesian_2d(xr, yr).map_err(plot_err)?);
    }
    Ok(())
}

/// The rows of one protocol and view.
fn of<'a>(rows: &'a [CalibrationRow], protocol: Protocol, view: &str) -> Vec<&'a CalibrationRow> {
    rows.iter()
        .filter(|r| r.protocol == protocol && r.view == view)
        .collect()
}

/// Mean over (phantom, σ) cells of the within-cell correlation (what the RMS tells about the landmark
/// error once the noise level is known).
fn within_cell_correlation(rows: &[&CalibrationRow], x: fn(&CalibrationRow) -> f64) -> f64 {
    let cells = distinct(
        rows.iter()
            .map(|r| (r.phantom.clone(), r.noise_px.to_bits())),
    );
    let cs: Vec<f64> = cells
        .iter()
        .map(|(p, s)| {
            let pairs: Vec<(f64, f64)> = rows
                .iter()
                .filter(|r| &r.phantom == p && r.noise_px.to_bits() == *s)
                .map(|r| (x(r), r.landmark_shift_max_px))
                .collect();
            correlation(&pairs)
        })
        .filter(|c| c.is_finite())
        .collect();
    cs.iter().sum::<f64>() / cs.len().max(1) as f64
}

/// Writes every calibration figure; returns their manifest entries.
pub fn figures(figs: &Path, tables: &StudyTables, c: &Conditions) -> Result<Vec<FigureEntry>> {
    let rows = &tables.calibration;
    let mut entries = Vec::new();
    if rows.is_empty() {
        return Ok(entries);
    }
    let views = distinct(rows.iter().map(|r| r.view.clone()));
    let protocols = distinct(rows.iter().map(|r| r.protocol));
    let phantoms = distinct(rows.iter().map(|r| r.phantom.clone()));
    type Axis = (fn(&CalibrationRow) -> f64, &'static str, &'static str);
    let axes: [Axis; 2] = [
        (
            |r| r.reprojection_rms_px,
            "phantom reprojection RMS (px)",
            "RMS",
        ),
        (
            |r| r.heldout_err_mm,
            "held-out BB 3-D error (mm)",
            "held-out",
        ),
    ];
    for view in &views {
        let mut panels = Vec::new();
        for &protocol in &protocols {
            let rs = of(rows, protocol, view);
            for (x, label, short) in axes {
                let groups = phantoms
                    .iter()
                    .map(|p| {
                        let pts = rs
                            .iter()
                            .filter(|r| &r.phantom == p)
                            .map(|r| (x(r), r.landmark_shift_max_px))
                            .collect();
                        (p.clone(), pts)
                    })
                    .collect();
                let pairs: Vec<(f64, f64)> =
                    rs.iter().map(|r| (x(r), r.landmark_shift_max_px)).collect();
                panels.push(ScatterPanel {
                    title: format!(
                        "{protocol}: {short} vs landmark error, r = {:.2} (within σ: {:.2})",
                        correlation(&pairs),
                        within_cell_correlation(&rs, x)
                    ),
                    x_label: label.into(),
                    y_label: format!("largest landmark shift, {view} (px)"),
                    groups,
                    highlight: Vec::new(),
                    log: true,
                });
            }
        }
        let file = format!("calibration_scatter_{view}.png");
        let title = format!(
            "Reconstruction-domain error vs vertebral landmark error ({view}), every trial and σ"
        );
        write_figure(
            &figs.join(&file),
            &Scatter {
                title: title.clone(),
                panels,
                cols: 2,
            },
        )?;
        entries.push(c.entry(
            Section::Calibration,
            &file,
            &title,
            "one point per calibration trial, a colour per phantom, log axes; r is the Pearson \
             correlation over all trials, 'within σ' its mean within each (phantom, σ) cell",
            true,
        ));
    }
    entries.push(intrinsics_figure(figs, rows, c)?);
    if let Some(e) = ambiguity_figure(figs, rows, &tables.calibration_ambiguity, c)? {
        entries.push(e);
    }
    Ok(entries)
}

/// Median and 5–95% band of each intrinsic error vs σ, a line per phantom.
fn intrinsics_figure(figs: &Path, rows: &[CalibrationRow], c: &Conditions) -> Result<FigureEntry> {
    let first_view = rows[0].view.clone();
    let first_protocol = rows[0].protocol;
    // One row per trial (the intrinsics do not depend on protocol or view).
    let trials: Vec<&CalibrationRow> = rows
        .iter()
        .filter(|r| r.view == first_view && r.protocol == first_protocol)
        .collect();
    let phantoms = distinct(trials.iter().map(|r| r.phantom.clone()));
    type Param = (fn(&CalibrationRow) -> f64, &'static str);
    let params: [Param; 5] = [
        (|r| r.dfx_px, "fx"),
        (|r| r.dfy_px, "fy"),
        (|r| r.dcx_px, "cx"),
        (|r| r.dcy_px, "cy"),
        (|r| r.dskew_px, "skew"),
    ];
    let panels = params
        .iter()
        .map(|(f, name)| {
            let series = phantoms
                .iter()
                .map(|p| {
                    let mut sig = distinct(
                        trials
                            .iter()
                            .filter(|r| &r.phantom == p)
                            .map(|r| r.noise_px),
                    );
                    sig.sort_by(f64::total_cmp);
                    let stats: Vec<(f64, f64, f64, f64)> = sig
                        .iter()
                        .map(|&s| {
                            let v: Vec<f64> = trials
                                .iter()
                                .filter(|r| &r.phantom == p && r.noise_px == s)
                                .map(|r| f(r))
                                .collect();
                            (
                                s,
                                percentile(&v, 50.0),
                                percentile(&v, 5.0),
                                percentile(&v, 95.0),
                            )
                        })
                        .collect();
                    Series {
                        label: p.clone(),
                        points: stats.iter().map(|x| (x.0, x.1)).collect(),
                        spread: Vec::new(),
                        band: stats.iter().map(|x| (x.2, x.3)).collect(),
                        colour: None,
                        dashed: false,
                        floor: f64::NEG_INFINITY,
                    }
                })
                .collect();
            Panel {
                title: format!("{name}: estimated − true"),
                series,
                marks: Vec::new(),
            }
        })
        .collect();
    let file = "calibration_intrinsics.png";
    let title = "Intrinsic errors of the calibrations vs detection noise";
    panel_chart(
        &figs.join(file),
        title,
        "detection noise σ (px)",
        "error (px)",
        panels,
        3,
    )?;
    Ok(c.entry(
        Section::Calibration,
        file,
        title,
        "median (line) and 5–95th percentile band (shaded) over the trials, a line per phantom; a \
         plate's skew is fixed at 0 by Zhang's method (OpenCV)",
        true,
    ))
}

/// The cell of the largest ambiguity ratio (protocol full when present), its trials in a scatter, the
/// pair highlighted.
fn ambiguity_figure(
    figs: &Path,
    rows: &[CalibrationRow],
    amb: &[CalibrationAmbiguityRow],
    c: &Conditions,
) -> Result<Option<FigureEntry>> {
    let largest = |p: Option<Protocol>| {
        amb.iter()
            .filter(|a| p.is_none_or(|p| a.protocol == p))
            .max_by(|a, b| a.ratio.total_cmp(&b.ratio))
    };
    let best = largest(Some(Protocol::Full)).or_else(|| largest(None));
    let Some(a) = best else {
        return Ok(None);
    };
    let cell: Vec<&CalibrationRow> = rows
        .iter()
        .filter(|r| {
            r.phantom == a.phantom
                && r.noise_px == a.noise_px
                && r.protocol == a.protocol
                && r.view == a.view
        })
        .collect();
    let panels = vec![
        ScatterPanel {
            title: format!(
                "RMS {:.3} vs {:.3} px, landmark error {:.2} vs {:.2} px (×{:.1})",
                a.rms_a_px, a.rms_b_px, a.shift_a_px, a.shift_b_px, a.ratio
            ),
            x_label: "phantom reprojection RMS (px)".into(),
            y_label: format!("largest landmark shift, {} (px)", a.view),
            groups: vec![(
                format!("{} trials", cell.len()),
                cell.iter()
                    .map(|r| (r.reprojection_rms_px, r.landmark_shift_max_px))
                    .collect(),
            )],
            highlight: vec![
                (
                    format!(" A (trial {})", a.trial_a),
                    (a.rms_a_px, a.shift_a_px),
                ),
                (
                    format!(" B (trial {})", a.trial_b),
                    (a.rms_b_px, a.shift_b_px),
                ),
            ],
            log: false,
        },
        ScatterPanel {
            title: "the same trials: focal error vs landmark error".into(),
            x_label: "fx error (px)".into(),
            y_label: format!("largest landmark shift, {} (px)", a.view),
            groups: vec![(
                format!("{} trials", cell.len()),
                cell.iter()
                    .map(|r| (r.dfx_px, r.landmark_shift_max_px))
                    .collect(),
            )],
            highlight: vec![
                (" A".into(), (a.dfx_a_px, a.shift_a_px)),
                (" B".into(), (a.dfx_b_px, a.shift_b_px)),
            ],
            log: false,
        },
    ];
    let file = "calibration_ambiguity.png";
    let title = format!(
        "Equal phantom RMS, different anatomy: {} at σ = {} px, protocol {}",
        a.phantom, a.noise_px, a.protocol
    );
    write_figure(
        &figs.join(file),
        &Scatter {
            title: title.clone(),
            panels,
            cols: 2,
        },
    )?;
    Ok(Some(c.entry(
        Section::Calibration,
        file,
        &title,
        "every trial of the cell with the largest ratio in calibration_ambiguity.csv; A and B report \
         the same reprojection RMS (within 5%) on the phantom",
        true,
    )))
}
