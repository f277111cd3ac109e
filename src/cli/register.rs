//! `spinedrr register`: rigid pose of a vertebra from landmark observations (direct LM, two-view
//! Kabsch, or OpenCV solvePnP), or with `--intensity` from images (DRRs matched to fixed radiographs),
//! written as `R.json`.

use std::path::PathBuf;

use anyhow::{Context, bail};
use spinedrr::registration::{LoadedProblem, RegisterOutcome, RegisterRequest, run_request};

#[derive(clap::Args)]
pub struct Args {
    /// Intensity-based registration: --problem is an intensity problem ({"anatomy", "moving"?,
    /// "views": [{"name", "fixed": "ap.tiff", "K" (assumed), "world_to_camera"}], "init", "truth"?,
    /// "similarity"?: ncc | gc | gncc | lncc[:P], "levels"?: [16, 8, 4, 2], "global"?, "seed"?}; see the
    /// README). R.json then holds R, t, similarity, evaluations, seconds, converged (+ rot_err_deg,
    /// trans_err_mm, mtre_mm with a truth).
    /// The landmark solver's flags do not apply (--method, --view, --noise-px, --seed, --init-rot-deg,
    /// --init-trans-mm, --max-iterations): the problem file states its views and options.
    #[arg(long, conflicts_with_all = [
        "method", "views", "noise_px", "seed", "init_rot_deg", "init_trans_mm", "max_iterations",
    ])]
    intensity: bool,
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
    #[arg(long, default_value_t = 0, value_parser = super::values::whole::<u64>)]
    seed: u64,
    /// Start from the truth rotated by this angle (deg) about a random axis (needs "truth").
    #[arg(long)]
    init_rot_deg: Option<f64>,
    /// Start from the truth translated by this distance (mm) in a random direction (needs "truth").
    #[arg(long)]
    init_trans_mm: Option<f64>,
    /// Iteration cap of the direct solver.
    #[arg(long, default_value_t = 100, value_parser = super::values::whole::<usize>)]
    max_iterations: usize,
    /// Output JSON: {"R", "t", "residual_px", "iterations", "converged", "tool", "kind"} (+ errors when
    /// truth is known). An existing file there is replaced only if it is a registration result spinedrr
    /// wrote (its `tool` and `kind` say so); any other file is refused, and nothing is written.
    #[arg(long)]
    out: PathBuf,
    /// Accept a solve that did not converge: still warn on stderr, but exit 0. Without it a
    /// non-converged solve writes --out (with "converged": false) and exits non-zero.
    #[arg(long)]
    allow_unconverged: bool,
    /// With --intensity: what renders a mesh or phantom anatomy's DRRs in the loop: `raster` (the
    /// default), `embree`, `bvh` or `gpu` (signed-depth sums in compute shaders through wgpu, checked
    /// against the raster's paired render before the loop relies on them; R.json then names the
    /// adapter). A CT anatomy renders with the CPU's volume renderer (the default) or, with `gpu`, the
    /// same Siddon integral in the GPU's compute shader.
    #[arg(long, value_enum, value_name = "BACKEND", requires = "intensity")]
    backend: Option<spinedrr::render::Backend>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    spinedrr::io::check_spares_inputs(
        &[("--out".to_string(), a.out.clone())],
        &[("the --problem file".to_string(), a.problem.clone())],
    )?;
    spinedrr::io::check_ours(&a.out)?;
    spinedrr::io::check_kind(&a.out, spinedrr::io::kind::REGISTRATION)?;
    if a.intensity {
        return run_intensity(&a);
    }
    let loaded = LoadedProblem::read(&a.problem)
        .with_context(|| format!("reading problem {}", a.problem.display()))?;
    let req = RegisterRequest {
        method: a.method.clone(),
        views: a.views.clone(),
        noise_px: a.noise_px,
        seed: a.seed,
        init_rot_deg: a.init_rot_deg,
        init_trans_mm: a.init_trans_mm,
        max_iterations: a.max_iterations,
    };
    let RegisterOutcome {
        result: r,
        record: out,
    } = run_request(loaded, &req)
        .with_context(|| format!("registering {} with {}", a.problem.display(), a.method))?;
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
    // Three decimals, or scientific notation for a pose run off to 1e11 mm.
    let three = |x: f64| {
        if x.abs() < 1e6 {
            format!("{x:.3}")
        } else {
            spinedrr::error::shown(x)
        }
    };
    let mut s = match out["implausible"].as_str() {
        Some(why) => format!(
            "{} registration of {} stopped after {} iteration(s) at a pose that cannot be the observed \
             anatomy ({why}; start nearer the truth, or add a view): residual {} px",
            a.method,
            a.problem.display(),
            r.iterations,
            three(r.residual_px)
        ),
        None => format!(
            "{} registration of {} did not converge after {} iteration(s) (--max-iterations {}): \
             residual {} px",
            a.method,
            a.problem.display(),
            r.iterations,
            a.max_iterations,
            three(r.residual_px)
        ),
    };
    if let Some(e) = out["rot_err_deg"].as_f64() {
        s += &format!(", rotation error {e:.3}°");
    }
    if let Some(e) = out["trans_err_mm"].as_f64() {
        s += &format!(", translation error {} mm", three(e));
    }
    s + &format!("; the pose was written to {}", a.out.display())
}

/// `--intensity`: reads and builds the problem (every input checked before anything is written),
/// registers, writes R.json.
fn run_intensity(a: &Args) -> anyhow::Result<()> {
    use spinedrr::registration::intensity::{LoadedIntensityProblem, run_intensity_problem};
    let backend = a.backend.unwrap_or(spinedrr::render::Backend::Raster);
    let loaded = LoadedIntensityProblem::read(&a.problem, backend)
        .with_context(|| format!("reading intensity problem {}", a.problem.display()))?;
    eprintln!(
        "registering {} view(s) by {} over levels {:?}…",
        loaded.problem.views.len(),
        loaded.options.similarity.name(),
        loaded.options.levels
    );
    let mut out = run_intensity_problem(&loaded)
        .with_context(|| format!("registering {}", a.problem.display()))?;
    if let Some(b) = loaded.problem.moving.backend() {
        out["backend"] = b.name().into();
    }
    if let Some(adapter) = loaded.problem.moving.gpu_adapter() {
        out["gpu_adapter"] = adapter.into();
    }
    let text = serde_json::to_string_pretty(&out)?;
    spinedrr::io::write_atomic_bytes(&a.out, text.as_bytes())
        .with_context(|| format!("writing {}", a.out.display()))?;
    let mut summary = format!(
        "{}: similarity {:.6}, {} evaluations, {:.2} s",
        a.out.display(),
        out["similarity"].as_f64().unwrap_or(f64::NAN),
        out["evaluations"],
        out["seconds"].as_f64().unwrap_or(f64::NAN)
    );
    if let Some(m) = out["mtre_mm"].as_f64() {
        summary += &format!(", mTRE {m:.3} mm");
    }
    eprintln!("{summary}");
    if out["converged"] != serde_json::Value::Bool(true) {
        let what =
            "the intensity registration did not converge (the finest level hit its iteration cap)";
        if !a.allow_unconverged {
            bail!(
                "{what}; the pose was written to {}; pass --allow-unconverged to accept it",
                a.out.display()
            );
        }
        eprintln!("warning: {what} (accepted: --allow-unconverged)");
    }
    Ok(())
}
