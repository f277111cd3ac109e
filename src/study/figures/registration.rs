//! Registration figures: for every target and error quantity, one figure with a panel per method; in
//! each panel the mean error over the trials vs Δf, one line per piercing shift, ± one standard deviation
//! as whiskers.

use std::path::Path;

use super::{Panel, Series, panel_chart};
use crate::Result;
use crate::study::tables::Table;

/// The error quantities: (column stem, axis label, file tag).
const QUANTITIES: [(&str, &str, &str); 3] = [
    ("rot_err_deg", "rotation error (deg)", "rot"),
    ("trans_err_mm", "translation error (mm)", "trans"),
    ("residual_px", "reprojection residual (px)", "residual"),
];

/// Values of `col` in order of first appearance.
fn distinct(t: &Table, col: &str) -> Result<Vec<String>> {
    let mut v: Vec<String> = Vec::new();
    for r in &t.rows {
        let s = t.str(r, col)?;
        if !v.iter().any(|x| x == s) {
            v.push(s.to_string());
        }
    }
    Ok(v)
}

/// Writes `registration_<target>_<rot|trans|residual>.png` for every target of the summary table.
pub fn registration_figures(t: &Table, figs: &Path) -> Result<()> {
    let methods = distinct(t, "method")?;
    for target in distinct(t, "target")? {
        for (stem, label, tag) in QUANTITIES {
            let panels = methods
                .iter()
                .map(|m| panel(t, &target, m, stem))
                .collect::<Result<Vec<_>>>()?;
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
fn panel(t: &Table, target: &str, method: &str, stem: &str) -> Result<Panel> {
    let (mean, sd) = (format!("{stem}_mean"), format!("{stem}_sd"));
    let mut by_piercing: Vec<(f64, Vec<CellMean>)> = Vec::new();
    for r in &t.rows {
        if t.str(r, "target")? != target || t.str(r, "method")? != method {
            continue;
        }
        let p = t.num(r, "piercing_px")?;
        let point = (t.num(r, "df_px")?, t.num(r, &mean)?, t.num(r, &sd)?);
        match by_piercing.iter_mut().find(|(q, _)| *q == p) {
            Some((_, pts)) => pts.push(point),
            None => by_piercing.push((p, vec![point])),
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
    Ok(Panel {
        title: method.to_string(),
        series,
    })
}
