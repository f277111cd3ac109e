//! `spinedrr register`: rigid pose of a vertebra from landmark observations (direct LM, two-view
//! Kabsch, or OpenCV solvePnP), written as `R.json`.

use std::path::PathBuf;

use anyhow::{Context, bail};
use serde_json::json;
use spinedrr::registration::{
    LoadedProblem, Method, RegistrationOptions, add_pixel_noise, model_centroid, perturb_pose,
    pose_errors, register,
};

#[derive(clap::Args)]
pub struct Args {
    /// Problem JSON: {"landmarks_3d": {...}, "views": [{"name", "K", "world_to_camera", "observed"}],
    /// "init"?: {"R", "t"}, "truth"?: {"R", "t"}} (R, t map model to world).
    #[arg(long)]
    problem: PathBuf,
    /// direct | kabsch | opencv (= opencv-iterative) | opencv-sqpnp.
    #[arg(long, default_value = "direct")]
    method: String,
    /// Use only these views (repeatable; default: all views in the file).
    #[arg(long = "view")]
    views: Vec<String>,
    /// Standard deviation (px) of Gaussian noise added to every observation.
    #[arg(long, default_value_t = 0.0)]
    noise_px: f64,
    /// Seed of the noise and of the initial-pose perturbation.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Start from the truth rotated by this angle (deg) about a random axis (needs "truth").
    #[arg(long)]
    init_rot_deg: Option<f64>,
    /// Start from the truth translated by this distance (mm) in a random direction (needs "truth").
    #[arg(long)]
    init_trans_mm: Option<f64>,
    /// Iteration cap of the direct solver.
    #[arg(long, default_value_t = 100)]
    max_iterations: usize,
    /// Output JSON: {"R", "t", "residual_px", "iterations", "converged"} (+ errors when truth is known).
    #[arg(long)]
    out: PathBuf,
    /// Accept a solve that did not converge: still warn on stderr, but exit 0. Without it a
    /// non-converged solve writes --out (with "converged": false) and exits non-zero.
    #[arg(long)]
    allow_unconverged: bool,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let method = Method::parse(&a.method)?;
    let loaded = LoadedProblem::read(&a.problem)
        .with_context(|| format!("reading problem {}", a.problem.display()))?;
    let mut problem = loaded.problem;
    if !a.views.is_empty() {
        problem = problem
            .select_views(&a.views)
            .with_context(|| format!("selecting views in {}", a.problem.display()))?;
    }
    if !(a.noise_px.is_finite() && a.noise_px >= 0.0) {
        bail!(
            "invalid --noise-px: must be a non-negative number, got {}",
            a.noise_px
        );
    }
    if a.noise_px > 0.0 {
        problem = add_pixel_noise(&problem, a.noise_px, a.seed);
    }
    let mut init = loaded.init;
    if a.init_rot_deg.is_some() || a.init_trans_mm.is_some() {
        let Some(truth) = loaded.truth else {
            bail!(
                "--init-rot-deg/--init-trans-mm perturb the truth, but {} has no \"truth\"",
                a.problem.display()
            );
        };
        let (deg, mm) = (
            a.init_rot_deg.unwrap_or(0.0),
            a.init_trans_mm.unwrap_or(0.0),
        );
        if !(deg.is_finite() && mm.is_finite()) {
            bail!("invalid --init-rot-deg/--init-trans-mm: must be finite");
        }
        let centre = truth.apply(model_centroid(&problem));
        init = Some(perturb_pose(&truth, deg, mm, centre, a.seed));
    }
    let opts = RegistrationOptions {
        init,
        max_iterations: a.max_iterations,
        ..Default::default()
    };
    let r = register(&problem, method, &opts)
        .with_context(|| format!("registering {} with {}", a.problem.display(), a.method))?;
    let mut out = json!({
        "R": r.pose.rotation_rows(),
        "t": r.pose.translation.to_array(),
        "residual_px": r.residual_px,
        "iterations": r.iterations,
        "converged": r.converged,
        "method": a.method,
        "views": problem.views.iter().map(|v| v.view.name.clone()).collect::<Vec<_>>(),
    });
    if let Some(truth) = loaded.truth {
        let e = pose_errors(&r.pose, &truth);
        out["rot_err_deg"] = json!(e.rot_err_deg);
        out["trans_err_mm"] = json!(e.trans_err_mm);
    }
    let text = serde_json::to_string_pretty(&out)?;
    spinedrr::io::write_atomic_bytes(&a.out, text.as_bytes())
        .with_context(|| format!("writing {}", a.out.display()))?;
    if !r.converged {
        let what = unconverged_summary(&a, &r, &out);
        if !a.allow_unconverged {
            bail!("{what}; pass --allow-unconverged to accept it");
        }
        eprintln!("warning: {what} (accepted: --allow-unconverged)");
    }
    Ok(())
}

/// One line saying the solve did not converge, with what it reached; `out` is the written result.
fn unconverged_summary(
    a: &Args,
    r: &spinedrr::registration::RegistrationResult,
    out: &serde_json::Value,
) -> String {
    let mut s = format!(
        "{} registration of {} did not converge after {} iteration(s) (--max-iterations {}): \
         residual {:.3} px",
        a.method,
        a.problem.display(),
        r.iterations,
        a.max_iterations,
        r.residual_px
    );
    if let Some(e) = out["rot_err_deg"].as_f64() {
        s += &format!(", rotation error {e:.3}°");
    }
    if let Some(e) = out["trans_err_mm"].as_f64() {
        s += &format!(", translation error {e:.3} mm");
    }
    s + &format!("; the pose was written to {}", a.out.display())
}
