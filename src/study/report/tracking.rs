//! *Relative (tracking) error*: `tracking.csv` in the report — per method and perturbation, the first
//! target's absolute error at pose 1 beside the error of the relative pose, and the single levels'
//! range. Every number is a cell of `tracking.csv`.

use std::fmt::Write as _;

use super::grid::{Pitch, short};
use super::shift_ratio::is_segment;
use crate::study::config::StudyConfig;
use crate::study::schema::TrackingRow;

pub const HEADING: &str = "Relative (tracking) error: two poses, one wrong geometry";

/// Writes the section (nothing without rows).
pub fn section(md: &mut String, cfg: &StudyConfig, rows: &[TrackingRow], first: &str) {
    if rows.is_empty() {
        return;
    }
    let tr = &cfg.tracking;
    let pitch = Pitch::of(cfg);
    let _ = writeln!(md, "## {HEADING}\n");
    let _ = writeln!(
        md,
        "Each target is registered from its landmarks (noise-free, by the row's method) at two true poses with the same \
assumed geometry: at its place, and moved by a rotation of ({})° (axis-angle, world axes) about its \
landmarks' centroid followed by a translation of ({}) mm (`[tracking]`). The absolute error is the pose 1 \
estimate's mean target registration error over the landmarks (TRE); the relative error is that of the \
estimated relative pose T₁⁻¹T₂ against the true one — what a navigation system tracking the vertebra \
between two acquisitions, or relative to an instrument in the same images, would get wrong. An error of \
the assumed geometry that is a rigid motion of the whole C-arm cancels from the relative pose exactly \
(Jain et al., MICCAI 2005); the rows show how much of each error here does (`tables/tracking.csv`).\n",
        triple(tr.rotation_deg),
        triple(tr.translation_mm)
    );
    let _ = writeln!(
        md,
        "| method | assumed geometry | {first}: absolute TRE (mm) | {first}: relative TRE (mm) | {first}: \
relative rotation error (°) | {first}: pedicle error, largest, absolute / relative (mm) | single levels: \
relative TRE, range (mm) |\n|---|---|---|---|---|---|---|"
    );
    let mut cells: Vec<(String, String)> = Vec::new();
    for r in rows {
        let c = (r.method.name().to_string(), r.perturbation.clone());
        if !cells.contains(&c) {
            cells.push(c);
        }
    }
    for (method, pert) in cells {
        let here: Vec<&TrackingRow> = rows
            .iter()
            .filter(|r| r.method.name() == method && r.perturbation == pert)
            .collect();
        let num = |x: f64, d: usize| {
            if x.is_finite() {
                short(x, d)
            } else {
                "n/a".to_string()
            }
        };
        let of_first = here.iter().find(|r| r.target == first);
        let na = || "n/a".to_string();
        let (abs, rel, rot, pedicle) = of_first.map_or((na(), na(), na(), na()), |r| {
            let failed = if r.converged { "" } else { " (not converged)" };
            (
                format!("{}{failed}", num(r.abs_tre_mm, 3)),
                num(r.rel_tre_mm, 3),
                num(r.rel_rot_err_deg, 3),
                format!(
                    "{} / {}",
                    num(r.pedicle_abs_err_max_mm, 3),
                    num(r.pedicle_rel_err_max_mm, 3)
                ),
            )
        });
        let levels: Vec<f64> = here
            .iter()
            .filter(|r| !is_segment(&r.target) && r.converged && r.rel_tre_mm.is_finite())
            .map(|r| r.rel_tre_mm)
            .collect();
        let range = super::grid::level_range(&levels, 3);
        // A focal cell with its SDD error beside it.
        let geometry = match pert.strip_prefix("df=").and_then(|d| d.parse::<f64>().ok()) {
            Some(df) if !pert.contains(',') => match pitch.mm(df) {
                Some(mm) => format!("{pert} (an SDD error of {mm} mm)"),
                None => pert.clone(),
            },
            _ => pert.clone(),
        };
        let _ = writeln!(
            md,
            "| {method} | {geometry} | {abs} | {rel} | {rot} | {pedicle} | {range} |"
        );
    }
    let _ = writeln!(md);
    pedicle_margins(md, rows);
}

/// How many single-level cells put a planned pedicle screw's entry, isthmus or tip more than 1 and 2 mm
/// off (a lumbar screw's margin in the pedicle), absolute and relative.
fn pedicle_margins(md: &mut String, rows: &[TrackingRow]) {
    let cells: Vec<&TrackingRow> = rows
        .iter()
        .filter(|r| !is_segment(&r.target) && r.converged)
        .filter(|r| r.pedicle_abs_err_max_mm.is_finite() && r.pedicle_rel_err_max_mm.is_finite())
        .collect();
    if cells.is_empty() {
        return;
    }
    let over = |f: fn(&TrackingRow) -> f64, mm: f64| cells.iter().filter(|r| f(r) > mm).count();
    let abs = |r: &TrackingRow| r.pedicle_abs_err_max_mm;
    let rel = |r: &TrackingRow| r.pedicle_rel_err_max_mm;
    let _ = writeln!(
        md,
        "Pedicle targets (each side's planned screw entry, isthmus centre and tip in the anterior third of \
the body, from the phantom's pedicle axes, or a user target's landmarks named `pedicle`): of the {} \
converged single-level cells above (targets × methods × assumed geometries), {} put a pedicle target \
more than 1 mm off and {} more than 2 mm in the absolute pose; in the relative pose, {} and {}. A lumbar \
pedicle screw has about 1–2 mm of margin.\n",
        cells.len(),
        over(abs, 1.0),
        over(abs, 2.0),
        over(rel, 1.0),
        over(rel, 2.0)
    );
}

/// `(x, y, z)` with at most 3 decimals each.
fn triple(v: [f64; 3]) -> String {
    v.map(|x| short(x, 3)).join(", ")
}
