//! Registration figures: for every target and error quantity, one figure with a panel per method; in
//! each panel the mean error over the trials vs Δf, one line per piercing shift, ± one standard deviation
//! as whiskers.

use std::path::Path;

use super::{Panel, Series, distinct, panel_chart};
use crate::Result;
use crate::study::config::RegistrationMethod;
use crate::study::schema::RegistrationSummaryRow;

/// (mean, sd) of one error quantity of a summary row.
type Quantity = fn(&RegistrationSummaryRow) -> (f64, f64);

/// The error quantities: (mean and sd, axis label, file tag).
const QUANTITIES: [(Quantity, &str, &str); 3] = [
    (
        |r| (r.rot_err_deg_mean, r.rot_err_deg_sd),
        "rotation error (deg)",
        "rot",
    ),
    (
        |r| (r.trans_err_mm_mean, r.trans_err_mm_sd),
        "translation error (mm)",
        "trans",
    ),
    (
        |r| (r.residual_px_mean, r.residual_px_sd),
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
            let title = format!("{target}: {label} vs focal offset, mean ± sd over trials");
            panel_chart(&file, &title, "focal offset Δf (px)", label, &panels, 3)?;
        }
    }
    Ok(())
}

/// (Δf, mean, sd) of one summary cell.
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
            }
        })
        .collect();
    Panel {
        title: method.to_string(),
        series,
    }
}
