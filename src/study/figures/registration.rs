//! Registration figures: for every target and error quantity, one figure with a panel per method; in
//! each panel the mean error over the trials vs Δf, one line per piercing shift, its 95 % confidence
//! interval as whiskers where the trials vary (none for a deterministic cell or a single trial). And per target the paper's comparison: rotation and translation error of Kabsch beside
//! direct AP+LAT, the paper's reported ranges as shaded bands.

use std::path::Path;

use super::canvas::write_figure;
use super::chart::Mark;
use super::charts::PanelChart;
use super::{Panel, Series, distinct, panel_chart};
use crate::Result;
use crate::study::config::RegistrationMethod;
use crate::study::paper::PaperResults;
use crate::study::schema::RegistrationSummaryRow;

/// (mean, 95 % CI half-width) of one error quantity of a summary row.
type Quantity = fn(&RegistrationSummaryRow) -> (f64, f64);

/// The whisker of a cell: its CI half-width where the trials vary, else none.
fn whisker(r: &RegistrationSummaryRow, ci95: f64) -> f64 {
    if r.deterministic || !ci95.is_finite() {
        0.0
    } else {
        ci95
    }
}

/// The error quantities: (mean and CI, axis label, file tag).
const QUANTITIES: [(Quantity, &str, &str); 3] = [
    (
        |r| (r.rot_err_deg_mean, whisker(r, r.rot_err_deg_ci95)),
        "rotation error (deg)",
        "rot",
    ),
    (
        |r| (r.trans_err_mm_mean, whisker(r, r.trans_err_mm_ci95)),
        "translation error (mm)",
        "trans",
    ),
    (
        |r| (r.residual_px_mean, whisker(r, r.residual_px_ci95)),
        "reprojection residual (px)",
        "residual",
    ),
];

/// Writes `registration_<target>_<rot|trans|residual>.png` for every target of the summary table.
pub fn registration_figures(rows: &[RegistrationSummaryRow], figs: &Path) -> Result<()> {
    let methods = distinct(rows.iter().map(|r| r.method));
    for target in distinct(rows.iter().map(|r| r.target.as_str())) {
        for (quantity, label, tag) in QUANTITIES {
            let panels: Vec<Panel> = methods
                .iter()
                .map(|&m| panel(rows, target, m, quantity))
                .collect();
            let file = figs.join(format!("registration_{target}_{tag}.png"));
            let title = format!("{target}: {label} vs focal offset, mean and 95 % CI over trials");
            panel_chart(&file, &title, "focal offset Δf (px)", label, panels, 3)?;
        }
    }
    Ok(())
}

/// (Δf, mean, CI half-width) of one summary cell.
type CellMean = (f64, f64, f64);

/// One method's panel: a line per piercing shift.
fn panel(
    rows: &[RegistrationSummaryRow],
    target: &str,
    method: RegistrationMethod,
    quantity: Quantity,
) -> Panel {
    let mut by_piercing: Vec<(f64, Vec<CellMean>)> = Vec::new();
    for r in rows
        .iter()
        .filter(|r| r.target == target && r.method == method)
    {
        let (mean, sd) = quantity(r);
        let point = (r.df_px, mean, sd);
        match by_piercing.iter_mut().find(|(q, _)| *q == r.piercing_px) {
            Some((_, pts)) => pts.push(point),
            None => by_piercing.push((r.piercing_px, vec![point])),
        }
    }
    by_piercing.sort_by(|a, b| a.0.total_cmp(&b.0));
    let series = by_piercing
        .into_iter()
        .map(|(p, mut pts)| {
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            Series {
                label: format!("piercing ({p}, {p}) px"),
                points: pts.iter().map(|x| (x.0, x.1)).collect(),
                spread: pts.iter().map(|x| x.2).collect(),
                // Errors and residuals are ≥ 0: a confidence interval reaching below 0 stops there.
                floor: 0.0,
                band: Vec::new(),
                colour: None,
                dashed: false,
            }
        })
        .collect();
    Panel {
        title: method.to_string(),
        series,
        marks: Vec::new(),
    }
}

/// The paper's two methods, in its order.
const PAPER_METHODS: [RegistrationMethod; 2] =
    [RegistrationMethod::Kabsch, RegistrationMethod::DirectApLat];

/// Writes `registration_paper_<target>.png` (and SVG) for every target with Kabsch or direct AP+LAT
/// rows: rotation (top) and translation (bottom) error, Kabsch (left) beside direct AP+LAT (right), the
/// paper's range of each as a band. Returns the targets drawn.
pub fn paper_figures(
    rows: &[RegistrationSummaryRow],
    paper: &PaperResults,
    figs: &Path,
) -> Result<Vec<String>> {
    let r = &paper.registration;
    let ranges = [
        [r.kabsch_rotation_deg, r.direct_rotation_deg],
        [r.kabsch_translation_mm, r.direct_translation_mm],
    ];
    let mut drawn = Vec::new();
    for target in distinct(rows.iter().map(|r| r.target.as_str())) {
        let has = |m| rows.iter().any(|r| r.target == target && r.method == m);
        if !PAPER_METHODS.iter().any(|&m| has(m)) {
            continue;
        }
        let mut panels = Vec::new();
        for (q, (quantity, label, _)) in QUANTITIES[..2].iter().enumerate() {
            for (k, &m) in PAPER_METHODS.iter().enumerate() {
                let mut p = panel(rows, target, m, *quantity);
                p.title = format!("{m}: {label}");
                let [lo, hi] = ranges[q][k];
                p.marks.push(Mark::Band { lo, hi });
                panels.push(p);
            }
        }
        // Kabsch beside direct AP+LAT is the comparison: each row (quantity) at one y scale.
        for row in [[0, 1], [2, 3]] {
            super::charts::share_y(&mut panels, &row);
        }
        let title =
            format!("{target}: registration error vs focal offset, mean and 95 % CI over trials");
        let fig = PanelChart {
            title: &title,
            x_label: "focal offset Δf (px)",
            y_labels: vec![QUANTITIES[0].1.into(), QUANTITIES[1].1.into()],
            panels,
            cols: 2,
            legend_extra: vec![("grey band: the paper's range".into(), None)],
        };
        write_figure(&figs.join(format!("registration_paper_{target}.png")), &fig)?;
        drawn.push(target.to_string());
    }
    Ok(drawn)
}
