//! The registration cells of one target as the report shows them: a mean with its 95 % confidence
//! interval and n where the trials vary, one value where they all agree (no "± over identical trials").

use std::fmt::Write as _;

use crate::geometry::View;
use crate::study::config::RegistrationMethod;
use crate::study::schema::{
    RegistrationPhysicalRow, RegistrationSummaryRow, SOLVER_SPREAD, ci95_half_width, mean_sd,
};

use super::latex::PaperTable;
use super::layout::mean_text;

/// One error quantity of a cell as text ([`mean_text`]: the deterministic flag says whether the
/// trials agree), `failed` when no trial gave a finite error.
pub fn cell_text(r: &RegistrationSummaryRow, mean: f64, ci95: f64) -> String {
    if r.n == 0 || !mean.is_finite() {
        return "failed".into();
    }
    mean_text(mean, ci95, r.n, r.deterministic)
}

/// The focal–depth ambiguity of the single-view methods the study ran, checked on `target`: at the
/// largest Δf with piercing 0, each one's mean translation error beside `z·Δf/f` of its view (z the
/// source–aim distance, f its fx, [`View::aim`]). `None` when no single-view method ran there.
pub fn single_view_note(
    rows: &[RegistrationSummaryRow],
    target: &str,
    views: &[&View],
) -> Option<String> {
    let mine: Vec<&RegistrationSummaryRow> = rows
        .iter()
        .filter(|r| r.target == target && r.piercing_px == 0.0 && r.method.single_view())
        .collect();
    let df = mine.iter().map(|r| r.df_px).fold(0.0, f64::max);
    let parts: Vec<String> = mine
        .iter()
        .filter(|r| r.df_px == df && df > 0.0 && r.n > 0)
        .filter_map(|r| {
            let view = views.iter().find(|v| v.name == r.method.views()[0])?;
            let (z, f) = (view.aim().1, view.intrinsics.fx);
            Some(format!(
                "{} {:.3} mm against {} {z:.0} × {df:.0} / {f:.0} = {:.1} mm",
                r.method,
                r.trans_err_mm_mean,
                view.name.to_uppercase(),
                z * df / f
            ))
        })
        .collect();
    if parts.is_empty() {
        return None;
    }
    Some(format!(
        "Single-view methods cannot separate a focal error from depth: the pose they find slides along \
the central ray by about z·Δf/f (z the view's source–aim distance, f its focal length). For {target} at \
Δf = {df:.0} px, piercing 0, the mean translation error (registration_summary.csv) is {}.",
        parts.join("; ")
    ))
}

/// The cells of `target` at piercing 0, Δf 0 (noise only) and the largest Δf, every method.
pub fn cells_table(
    rows: &[RegistrationSummaryRow],
    target: &str,
    noise_px: f64,
    pitch: super::grid::Pitch,
) -> PaperTable {
    let mine: Vec<&RegistrationSummaryRow> = rows
        .iter()
        .filter(|r| r.target == target && r.piercing_px == 0.0)
        .collect();
    let df_max = mine.iter().map(|r| r.df_px).fold(0.0, f64::max);
    let body = mine
        .iter()
        .filter(|r| r.df_px == 0.0 || r.df_px == df_max)
        .map(|r| {
            vec![
                r.method.to_string(),
                pitch.df_cell(r.df_px),
                cell_text(r, r.rot_err_deg_mean, r.rot_err_deg_ci95),
                cell_text(r, r.trans_err_mm_mean, r.trans_err_mm_ci95),
                cell_text(r, r.residual_px_mean, r.residual_px_ci95),
                format!("{} of {}", r.n, r.trials),
            ]
        })
        .collect();
    PaperTable {
        name: "registration_cells",
        caption: format!(
            "Registration error of {target} at piercing 0: mean over trials and its 95 % confidence \
             interval (Student t; a bound below 0 is shown as 0, the errors being magnitudes), landmarks \
             observed with Gaussian noise σ = {noise_px} px; a cell whose trials all agree (σ = 0) is one \
             value"
        ),
        header: [
            "method".to_string(),
            format!("Δf, {}", pitch.unit("SDD error")),
            "rotation error (°)".into(),
            "translation error (mm)".into(),
            "residual (px)".into(),
            "n (finite of trials)".into(),
        ]
        .to_vec(),
        rows: body,
    }
}

/// One physical registration cell's statistics over its converged trials.
struct PhysicalCell<'a> {
    /// The converged trials (finite errors).
    rows: Vec<&'a RegistrationPhysicalRow>,
    n: usize,
    trials: usize,
    agree: bool,
}

type CellKey = (String, RegistrationMethod, String, u64);

impl<'a> PhysicalCell<'a> {
    /// The trials of cell `c` in `all`.
    fn of(all: &'a [RegistrationPhysicalRow], c: &CellKey) -> Self {
        let rows: Vec<&RegistrationPhysicalRow> = all
            .iter()
            .filter(|r| {
                r.target == c.0 && r.method == c.1 && r.key == c.2 && r.value.to_bits() == c.3
            })
            .collect();
        let ok: Vec<&RegistrationPhysicalRow> = rows
            .iter()
            .copied()
            .filter(|r| r.converged && r.rot_err_deg.is_finite())
            .collect();
        let columns: [fn(&RegistrationPhysicalRow) -> f64; 4] = [
            |r| r.rot_err_deg,
            |r| r.trans_err_mm,
            |r| r.tre_mm,
            |r| r.residual_px,
        ];
        let agree = !ok.is_empty()
            && columns
                .iter()
                .all(|f| mean_sd(&ok.iter().map(|r| f(r)).collect::<Vec<_>>()).1 <= SOLVER_SPREAD);
        PhysicalCell {
            n: ok.len(),
            trials: rows.len(),
            rows: ok,
            agree,
        }
    }

    /// The mean of `f` over the converged trials ([`mean_text`]), `failed` without one.
    fn text(&self, f: fn(&RegistrationPhysicalRow) -> f64) -> String {
        let v: Vec<f64> = self.rows.iter().map(|r| f(r)).collect();
        let (mean, sd) = mean_sd(&v);
        if self.n == 0 || !mean.is_finite() {
            return "failed".into();
        }
        mean_text(mean, ci95_half_width(sd, self.n), self.n, self.agree)
    }

    fn mean(&self, f: fn(&RegistrationPhysicalRow) -> f64) -> f64 {
        mean_sd(&self.rows.iter().map(|r| f(r)).collect::<Vec<_>>()).0
    }
}

/// The cells of `rows` in the order they first appear: (target, method, key, value bits).
fn physical_cells(rows: &[RegistrationPhysicalRow]) -> Vec<CellKey> {
    let mut cells = Vec::new();
    for r in rows {
        let c = (r.target.clone(), r.method, r.key.clone(), r.value.to_bits());
        if !cells.contains(&c) {
            cells.push(c);
        }
    }
    cells
}

/// Landmark registration of `target` under each physical cell, every method: the mean of each error
/// over the converged trials (`registration_physical.csv`).
pub fn physical_table(rows: &[RegistrationPhysicalRow], target: &str, noise_px: f64) -> PaperTable {
    // Grouped by error (in the order the errors first appear), the methods within each.
    let mine: Vec<CellKey> = physical_cells(rows)
        .into_iter()
        .filter(|c| c.0 == target)
        .collect();
    let mut errors: Vec<(&str, u64)> = Vec::new();
    for c in &mine {
        if !errors.contains(&(c.2.as_str(), c.3)) {
            errors.push((c.2.as_str(), c.3));
        }
    }
    let order = |c: &CellKey| errors.iter().position(|e| *e == (c.2.as_str(), c.3));
    let mut sorted = mine.clone();
    sorted.sort_by_key(order);
    let body = sorted
        .into_iter()
        .map(|c| {
            let cell = PhysicalCell::of(rows, &c);
            vec![
                format!("{} = {}", c.2, f64::from_bits(c.3)),
                c.1.to_string(),
                cell.text(|r| r.rot_err_deg),
                cell.text(|r| r.trans_err_mm),
                cell.text(|r| r.tre_mm),
                cell.text(|r| r.pedicle_err_max_mm),
                format!("{} of {}", cell.n, cell.trials),
            ]
        })
        .collect();
    PaperTable {
        name: "registration_physical",
        caption: format!(
            "Landmark registration of {target} under the physical errors: mean over trials and its 95 % \
             confidence interval (as above), landmarks observed through the true cameras with Gaussian \
             noise σ = {noise_px} px, solved with the cameras the assumed geometry amounts to (K', R', t')"
        ),
        header: [
            "error",
            "method",
            "rotation error (°)",
            "translation error (mm)",
            "mTRE over the landmarks (mm)",
            "largest pedicle error (mm)",
            "n (converged of trials)",
        ]
        .map(String::from)
        .to_vec(),
        rows: body,
    }
}

/// Per method, over every target and physical cell with a pedicle error: how many cells' mean largest
/// pedicle error exceeds 1 mm and 2 mm (a pedicle screw's margin), as `(method, cells, > 1, > 2)`.
pub fn pedicle_margins(
    rows: &[RegistrationPhysicalRow],
) -> Vec<(RegistrationMethod, usize, usize, usize)> {
    let mut out: Vec<(RegistrationMethod, usize, usize, usize)> = Vec::new();
    for c in physical_cells(rows) {
        let (cell, method) = (PhysicalCell::of(rows, &c), c.1);
        let e = cell.mean(|r| r.pedicle_err_max_mm);
        if !e.is_finite() {
            continue;
        }
        let i = match out.iter().position(|o| o.0 == method) {
            Some(i) => i,
            None => {
                out.push((method, 0, 0, 0));
                out.len() - 1
            }
        };
        out[i].1 += 1;
        out[i].2 += usize::from(e > 1.0);
        out[i].3 += usize::from(e > 2.0);
    }
    out
}

/// The subsection of the physical cells (nothing without rows): the first target's table and, per
/// method, how many cells over every target leave a pedicle error beyond 1 and 2 mm.
pub fn physical_section(
    md: &mut String,
    rows: &[RegistrationPhysicalRow],
    first: &str,
    noise_px: f64,
) {
    if rows.is_empty() {
        return;
    }
    let t = physical_table(rows, first, noise_px);
    let _ = writeln!(md, "### {}\n", t.caption);
    let _ = write!(md, "{}", t.to_markdown());
    let _ = writeln!(
        md,
        "\nEach error is one key of `[perturbations.physical]` alone, in the view's camera axes (see *{}*); \
the rows of every trial, every target and the clinical points' errors are in `tables/registration_physical.csv`. \
The largest pedicle error is the largest distance, at the planned screw entry, isthmus and tip of both \
pedicles, between where the registered pose puts them and where they are. The noise alone gives the \
errors of the Δf = 0, piercing 0 rows above (where the grid has them); a physical error adds to them.",
        super::physical::HEADING
    );
    let margins = pedicle_margins(rows);
    if !margins.is_empty() {
        let parts: Vec<String> = margins
            .iter()
            .map(|(m, n, one, two)| format!("{m} {one} and {two} of {n}"))
            .collect();
        let _ = writeln!(
            md,
            "\nCells (target × error) whose mean largest pedicle error exceeds 1 mm and 2 mm, a pedicle \
screw's margin: {}.",
            parts.join("; ")
        );
    }
    let _ = writeln!(md);
}
