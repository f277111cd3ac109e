//! The registration cells of one target as the report shows them: a mean with its 95 % confidence
//! interval and n where the trials vary, one value where they all agree (no "± over identical trials").

use crate::study::schema::RegistrationSummaryRow;

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

/// The cells of `target` at piercing 0, Δf 0 (noise only) and the largest Δf, every method.
pub fn cells_table(rows: &[RegistrationSummaryRow], target: &str, noise_px: f64) -> PaperTable {
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
                format!("{}", r.df_px),
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
            "method",
            "Δf (px)",
            "rotation error (°)",
            "translation error (mm)",
            "residual (px)",
            "n (finite of trials)",
        ]
        .map(String::from)
        .to_vec(),
        rows: body,
    }
}
