//! `spinedrr render`: one DRR (plus preview, sidecar, masks, depth) of the phantom or of mesh files.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, bail};
use serde_json::json;
use spinedrr::anatomy::{PhantomOptions, build_phantom, parse_levels, read_mesh};
use spinedrr::geometry::{CArm, Perturbation};
use spinedrr::io::{DrrValues, write_depth, write_drr, write_masks};
use spinedrr::render::{
    Backend, RenderScene, SceneMesh, ThicknessDrr, ThicknessOptions, phantom_scene,
};

/// Render a DRR under the reference or a perturbed calibration.
///
/// Writes OUT.tiff (float32 line integral Σ μ·L; with μ = 1 mm⁻¹ it is the thickness in mm), OUT.json
/// (sidecar: width, height, K, world_to_camera, units, view, perturbation, version) and OUT.png (preview).
/// With --masks also OUT_mask.png (all objects), OUT_mask_<object>.png and OUT_mask_<structure>.png, each
/// with its sidecar; with --depth OUT_depth.tiff (camera z of the first surface, mm; 0 = no hit).
#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("anatomy").required(true).args(["phantom", "mesh", "ct"])))]
pub struct Args {
    /// Render the built-in phantom: levels such as L3, L1-L5 or L1,L3.
    #[arg(long, value_name = "LEVELS")]
    phantom: Option<String>,
    /// A closed mesh (STL, OBJ or PLY) with an optional attenuation in mm⁻¹: FILE or FILE:MU. Repeat for
    /// several meshes; nested surfaces take differential μ.
    #[arg(long, value_name = "FILE[:MU]")]
    mesh: Vec<String>,
    /// μ (mm⁻¹) of a --mesh given without one.
    #[arg(long, default_value_t = 1.0, value_name = "MU")]
    mu_default: f64,
    /// With --phantom: add the soft-tissue outline around the spine.
    #[arg(long)]
    soft_tissue: bool,
    /// View name from the geometry (the default geometry has `ap` and `lat`).
    #[arg(long, default_value = "ap")]
    view: String,
    /// Geometry TOML file (see `spinedrr geometry`); default: the built-in non-isocentric C-arm.
    #[arg(long, value_name = "FILE")]
    geometry: Option<PathBuf>,
    /// Intrinsic perturbation, comma-separated KEY=VALUE: df=300 (focal offset px), alpha=1.05 (focal
    /// scale), dcx=20, dcy=-10 (piercing shift px), skew=1.5, sx=1.01, sy=0.99 (per-axis focal scale).
    #[arg(long, default_value = "none", value_name = "SPEC")]
    perturb: String,
    /// How rays find the surfaces: `raster` (exact edge functions per pixel, the fastest; a view with a
    /// vertex at or behind the source plane is traced with Embree), `embree` (all hits in one Embree
    /// traversal) or `bvh` (the pure-Rust reference). All give the same path lengths (to ~1e-7 mm).
    #[arg(long, value_enum, default_value_t = Backend::Raster)]
    backend: Backend,
    /// Write silhouette masks per object and per structure.
    #[arg(long)]
    masks: bool,
    /// Write the first-hit depth map.
    #[arg(long)]
    depth: bool,
    /// Write I0·exp(−line integral) instead of the line integral (a radiograph look), for meshes and CT.
    #[arg(long, value_name = "I0")]
    intensity: Option<f64>,
    /// Render N times and print timing statistics as one JSON line on stderr.
    #[arg(long, default_value_t = 1, value_name = "N")]
    repeat: u32,
    #[command(flatten)]
    ct: super::render_ct::CtArgs,
    /// Output image (.tiff or .tif); the sidecar and preview are written beside it.
    #[arg(long, value_name = "OUT.tiff")]
    out: PathBuf,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    check_out_path(&a.out)?;
    let carm = match &a.geometry {
        Some(p) => {
            CArm::from_file(p).with_context(|| format!("loading geometry {}", p.display()))?
        }
        None => CArm::default_paper(),
    };
    let view = carm.view(&a.view)?.clone();
    let perturbation = Perturbation::parse(&a.perturb)?;
    let rendered = view
        .perturbed(&perturbation)
        .context("applying the perturbation")?;
    let values = DrrValues::new(a.intensity).context("--intensity")?;
    if a.repeat == 0 {
        bail!("invalid --repeat 0: render at least once");
    }
    if a.ct.ct.is_some() {
        return super::render_ct::run_ct(&a.ct, &view, &perturbation, values, &a.out);
    }

    let (scene, anatomy) = build_scene(&a)?;
    for name in &scene.open_meshes {
        eprintln!(
            "warning: mesh '{name}' is not closed; path lengths near its holes are unreliable"
        );
    }
    let renderer = a.backend.renderer(scene)?;
    let mut times = Vec::with_capacity(a.repeat as usize);
    let opts = ThicknessOptions {
        masks: a.masks,
        depth: a.depth,
        ..ThicknessOptions::default()
    };
    let mut drr = renderer.render(&rendered, &opts)?;
    times.push(drr.stats.render_ms);
    for _ in 1..a.repeat {
        drr = renderer.render(&rendered, &opts)?;
        times.push(drr.stats.render_ms);
    }
    if drr.stats.rays_unrepaired > 0 {
        eprintln!(
            "warning: {} rays did not pair their surface crossings even after retracing; their values are capped \
             by the longest chord (is a mesh open or self-intersecting?)",
            drr.stats.rays_unrepaired
        );
    }
    if a.repeat > 1 {
        eprintln!("{}", timing_json(&a, &renderer, &drr, &mut times));
    }

    let details = renderer.details(drr.stats, anatomy);
    write_drr(
        &a.out,
        &drr.line_integral,
        values,
        &view,
        &perturbation,
        &details,
    )?;
    if a.masks {
        write_masks(&a.out, &drr.silhouettes()?, &view, &perturbation)?;
    }
    if a.depth {
        write_depth(&a.out, drr.depth()?, &view, &perturbation)?;
    }
    eprintln!(
        "{}: {} × {} {} DRR, view {}, perturbation {}, {:.1} ms ({} rays traced, {} culled)",
        a.out.display(),
        drr.line_integral.width,
        drr.line_integral.height,
        renderer.backend_name(),
        view.name,
        perturbation,
        drr.stats.render_ms,
        drr.stats.rays_traced,
        drr.stats.rays_culled
    );
    Ok(())
}

fn check_out_path(out: &Path) -> anyhow::Result<()> {
    match out.extension().and_then(|e| e.to_str()) {
        Some("tiff" | "tif") => {}
        _ => bail!(
            "--out {}: the output must be a .tiff or .tif file",
            out.display()
        ),
    }
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("creating output folder {}", dir.display()))?;
    }
    Ok(())
}

/// The scene and a JSON description of it for the sidecar (`details.anatomy`).
fn build_scene(a: &Args) -> anyhow::Result<(RenderScene, serde_json::Value)> {
    if let Some(spec) = &a.phantom {
        let opts = PhantomOptions {
            levels: parse_levels(spec)?,
            soft_tissue: a.soft_tissue,
            ..PhantomOptions::default()
        };
        let phantom = build_phantom(&opts).context("building the phantom")?;
        let scene = phantom_scene(&phantom)?;
        let mu: Vec<_> = scene
            .meshes
            .iter()
            .map(|m| json!({"mesh": m.mesh.name, "mu_per_mm": m.mu_per_mm}))
            .collect();
        return Ok((
            scene,
            json!({"phantom": spec, "soft_tissue": a.soft_tissue, "meshes": mu}),
        ));
    }
    if !(a.mu_default.is_finite()) {
        bail!("invalid --mu-default {}: must be finite", a.mu_default);
    }
    let mut meshes = Vec::new();
    for spec in &a.mesh {
        let (path, mu) = split_mesh_spec(spec, a.mu_default)?;
        let mesh = read_mesh(&path).with_context(|| format!("reading mesh {}", path.display()))?;
        let object = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        meshes.push(SceneMesh {
            mesh: Arc::new(mesh),
            mu_per_mm: mu,
            object,
        });
    }
    let desc: Vec<_> = meshes
        .iter()
        .zip(&a.mesh)
        .map(|(m, spec)| json!({"file": spec, "triangles": m.mesh.triangles.len(), "mu_per_mm": m.mu_per_mm}))
        .collect();
    Ok((RenderScene::new(meshes)?, json!({"meshes": desc})))
}

/// `FILE[:MU]`: a trailing `:number` is the attenuation; anything else is part of the path.
fn split_mesh_spec(spec: &str, default_mu: f64) -> anyhow::Result<(PathBuf, f64)> {
    if let Some((path, mu)) = spec.rsplit_once(':')
        && let Ok(mu) = mu.parse::<f64>()
    {
        if !mu.is_finite() {
            bail!("--mesh {spec}: μ must be finite");
        }
        return Ok((PathBuf::from(path), mu));
    }
    Ok((PathBuf::from(spec), default_mu))
}

fn timing_json(
    a: &Args,
    r: &spinedrr::render::ThicknessRenderer,
    drr: &ThicknessDrr,
    times: &mut [f64],
) -> serde_json::Value {
    times.sort_by(f64::total_cmp);
    let median = times[times.len() / 2];
    let min = times[0];
    json!({
        "backend": r.backend_name(),
        "view": a.view,
        "repeat": a.repeat,
        "median_ms": median,
        "min_ms": min,
        "rays_traced": drr.stats.rays_traced,
        "rays_per_s": drr.stats.rays_traced as f64 / (median / 1e3),
        "hits_per_s": drr.stats.hits as f64 / (median / 1e3),
        "bvh_build_ms": r.build_ms(),
        "rays_repaired": drr.stats.rays_repaired,
        "rays_unrepaired": drr.stats.rays_unrepaired,
        "triangles": r.scene().triangle_count(),
        "peak_rss_mb": peak_rss_mb(),
    })
}

/// Peak resident memory of this process so far (MiB), from /proc/self/status (Linux; null elsewhere).
fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}
