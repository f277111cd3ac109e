//! `spinedrr render`: one DRR (plus preview, sidecar, masks, depth) of the phantom or of mesh files.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, bail};
use serde_json::json;
use spinedrr::anatomy::{PhantomOptions, build_phantom, parse_levels, read_mesh};
use spinedrr::geometry::{CArm, Perturbation};
use spinedrr::io::{
    DrrProducts, DrrValues, XrayModel, check_output_set, check_spares_inputs, drr_set_kind,
    drr_set_paths, write_drr_set,
};
use spinedrr::render::{
    Backend, RenderScene, SceneMesh, ThicknessDrr, ThicknessOptions, orient_outward_warning,
    phantom_scene,
};
use spinedrr::spectral::Attenuation;

use super::render_checks::{
    RenderRun, check_finite, check_not_empty, check_not_negative, check_source_outside,
    mesh_corners, mesh_mu_cause, mesh_zero_cause, split_implant_spec, split_mesh_spec,
};
use super::render_timing::{median_min, peak_rss_mb};

/// Render a DRR under the reference or a perturbed calibration.
///
/// Writes OUT.tiff (float32 line integral Σ μ·L; with μ = 1 mm⁻¹ it is the thickness in mm), OUT.json
/// (sidecar: width, height, K, world_to_camera, units, view, perturbation, version) and OUT.png (preview).
/// With --masks also OUT_mask.png (all objects), OUT_mask_<object>.png and OUT_mask_<structure>.png, each
/// with its sidecar; with --depth OUT_depth.tiff (camera z of the first surface, mm; 0 = no hit).
///
/// Every output path is checked before the first is written; OUT.json is written last and lists the
/// other files of the set (`companions`), so a folder without OUT.json holds an unfinished set. A render
/// with nothing on the detector is refused (see --allow-empty), as are flags that do not apply to the
/// input (e.g. --masks with --ct, --bone-hu with --mesh).
#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("anatomy").required(true).args(["phantom", "mesh", "ct"])))]
pub struct Args {
    /// Render the built-in phantom: levels such as L3, L1-L5 or L1,L3.
    #[arg(long, value_name = "LEVELS")]
    phantom: Option<String>,
    /// A closed mesh (STL, OBJ or PLY) with an optional attenuation in mm⁻¹: FILE or FILE:MU (with
    /// --spectrum also FILE:MATERIAL[@DENSITY], see there). Repeat for
    /// several meshes; nested surfaces take differential μ: a core inside a shell of μ₁ gets μ₂ − μ₁, which
    /// is negative for a core less dense than its shell. A negative μ is therefore accepted, but a render
    /// whose line integral comes out negative anywhere (a negative μ not nested in a denser surface) is
    /// refused. A closed mesh wound inside out is flipped to face outward, with a warning.
    #[arg(long, value_name = "FILE[:MU]")]
    mesh: Vec<String>,
    /// μ (mm⁻¹) of a --mesh given without one.
    #[arg(long, default_value_t = 1.0, value_name = "MU", conflicts_with_all = ["phantom", "ct"])]
    mu_default: f64,
    /// With --phantom: add the soft-tissue outline around the spine.
    #[arg(long, conflicts_with_all = ["mesh", "ct"])]
    soft_tissue: bool,
    /// View name from the geometry (the default geometry has `ap` and `lat`).
    #[arg(long, default_value = "ap")]
    view: String,
    /// Geometry TOML file (see `spinedrr geometry`); default: the built-in non-isocentric C-arm.
    #[arg(long, value_name = "FILE")]
    geometry: Option<PathBuf>,
    /// How the assumed calibration differs from the true one, comma-separated KEY=VALUE. Intrinsic
    /// (K only, pose fixed): df=300 (focal offset px), alpha=1.05 (focal scale), dcx=20, dcy=-10
    /// (piercing shift px), skew=1.5, sx=1.01, sy=0.99 (per-axis focal scale). Physical (mm and degrees,
    /// in the view's camera axes: x along detector rows, y down the detector, z along the central ray;
    /// these change K and the pose together and need a geometry with sdd_mm, not an explicit K):
    /// src_dx_mm, src_dy_mm, src_dz_mm (focal spot moved), det_dx_mm, det_dy_mm, det_dz_mm (detector
    /// moved), det_roll_deg (detector rotated about the central ray), det_tilt_u_deg, det_tilt_v_deg
    /// (about its row and column axes through the piercing point). The sidecar records the rendered K,
    /// world_to_camera and P = K [R | t] beside the reference's.
    #[arg(long, default_value = "none", value_name = "SPEC")]
    perturb: String,
    /// What renders. Meshes and phantoms: `raster` (the default; exact edge functions per pixel, the
    /// fastest on a CPU; a view with a vertex at or behind the source plane is traced with Embree),
    /// `embree` (all hits in one Embree traversal) or `bvh` (the pure-Rust reference); all give the same
    /// path lengths (to ~1e-7 mm). `gpu`: compute shaders through wgpu on the machine's GPU (Vulkan, Metal
    /// or DX12; Mesa's software Vulkan, lavapipe, where there is none); the sidecar names the adapter.
    /// Meshes on the GPU are the raster's signed-depth sums (exit − entry depths per pixel; closed meshes
    /// only, and a mesh that intersects itself counts twice where it overlaps), within ~1e-4 mm of the
    /// raster, with the same masks; a spectral mesh DRR (--spectrum; implants and screws are refused)
    /// renders its per-material channels on the GPU and sums the energies there. A CT (`--ct`) renders on
    /// the CPU unless `gpu` is given, the same Siddon or trilinear integral to ~1e-5; a spectral CT DRR
    /// renders its channels and sums the energies on the GPU.
    #[arg(long, value_enum, value_name = "BACKEND")]
    backend: Option<Backend>,
    /// Write silhouette masks per object and per structure (meshes and phantom only).
    #[arg(long, conflicts_with = "ct")]
    masks: bool,
    /// Write the first-hit depth map (meshes and phantom only).
    #[arg(long, conflicts_with = "ct")]
    depth: bool,
    /// Write I0·exp(−line integral) instead of the line integral (a radiograph look), for meshes and CT.
    #[arg(long, value_name = "I0")]
    intensity: Option<f64>,
    /// Write a radiograph of the X-ray image model instead: expected counts I0·exp(−L) with I0 photons
    /// per pixel in air, Poisson quantum noise (seeded by --seed), Gaussian blur --blur-px, and with --log
    /// −ln(N/I0). The sidecar records the model (details.xray_model).
    #[arg(long, value_name = "I0", conflicts_with = "intensity")]
    photons: Option<f64>,
    /// With --photons: Gaussian detector blur σ (px), applied to the detected counts.
    #[arg(
        long,
        default_value_t = 0.0,
        value_name = "SIGMA",
        requires = "photons"
    )]
    blur_px: f64,
    /// With --photons: seed of the Poisson noise (the same seed gives the same image).
    #[arg(long, default_value_t = 0, value_name = "S", requires = "photons", value_parser = super::values::whole::<u64>)]
    seed: u64,
    /// With --photons: write the log-converted image −ln(N/I0) (a noisy line integral).
    #[arg(long, requires = "photons")]
    log: bool,
    /// Render N times and print timing statistics as one JSON line on stderr (meshes, phantom and CT).
    #[arg(long, default_value_t = 1, value_name = "N", value_parser = super::values::whole::<u32>)]
    repeat: u32,
    /// Write the image even when every pixel is 0 (nothing of the anatomy on the detector), which is
    /// otherwise an error.
    #[arg(long)]
    allow_empty: bool,
    #[command(flatten)]
    ct: super::render_ct::CtArgs,
    #[command(flatten)]
    spectral: super::render_spectral::SpectralArgs,
    /// Output image (.tiff or .tif); the sidecar and preview are written beside it. A file already at any
    /// of these names is replaced only if spinedrr wrote it (a sidecar of spinedrr's, or an image beside
    /// one); any other (your own `OUT.png`, a TIFF without a sidecar) is refused before anything is written.
    #[arg(long, value_name = "OUT.tiff")]
    out: PathBuf,
}

/// The most renders `--repeat` asks for.
const MAX_REPEAT: u32 = 10_000;

/// Every file a render reads: mesh and implant files, a spectrum file, the geometry, the CT and its label
/// map.
fn render_inputs(a: &Args) -> anyhow::Result<Vec<(String, PathBuf)>> {
    let mut v = Vec::new();
    for spec in &a.mesh {
        let (path, _) = split_mesh_spec(spec, a.mu_default)?;
        v.push((format!("the --mesh file {}", path.display()), path));
    }
    for spec in &a.spectral.implant {
        let (path, _, pose) = split_implant_spec(spec)?;
        v.push((format!("the --implant file {}", path.display()), path));
        if let Some(pose) = pose {
            v.push((format!("the --implant pose {}", pose.display()), pose));
        }
    }
    if let Some(path) = &a.spectral.screws_at {
        v.push((
            format!("the --screws-at file {}", path.display()),
            path.clone(),
        ));
    }
    if let Some(spec) = &a.spectral.spectrum {
        let path = PathBuf::from(spec);
        if path.is_file() {
            v.push((format!("the --spectrum file {spec}"), path));
        }
    }
    for (what, p) in [
        ("the --geometry file", &a.geometry),
        ("the --ct volume", &a.ct.ct),
        ("the --seg label map", &a.ct.seg),
    ] {
        if let Some(p) = p {
            v.push((what.to_string(), p.clone()));
        }
    }
    Ok(v)
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
    let values = match a.photons {
        Some(i0) => DrrValues::Xray(
            XrayModel::new(i0, a.blur_px, a.seed, a.log).context("--photons/--blur-px")?,
        ),
        None => DrrValues::new(a.intensity).context("--intensity")?,
    };
    if a.repeat == 0 {
        bail!("invalid --repeat 0: render at least once");
    }
    if a.repeat > MAX_REPEAT {
        bail!(
            "invalid --repeat {}: at most {MAX_REPEAT} renders (timing statistics settle within tens; \
             {} renders of even a 10 ms image would take {:.1} hours)",
            a.repeat,
            a.repeat,
            f64::from(a.repeat) * 0.01 / 3600.0
        );
    }
    // The files every render writes, checked before the (possibly long) render: none may be one of the
    // render's inputs, and a file already there must be one spinedrr wrote (spinedrr::io::check_ours).
    let set = drr_set_paths(&a.out, &[], a.depth);
    let outputs: Vec<(String, PathBuf)> = set
        .iter()
        .map(|p| ("--out".to_string(), p.clone()))
        .collect();
    check_spares_inputs(&outputs, &render_inputs(&a)?)?;
    check_output_set(&set, |p| drr_set_kind(&a.out, p))?;
    let run = RenderRun {
        view: &view,
        rendered: &rendered,
        perturbation: &perturbation,
        values,
        repeat: a.repeat,
        allow_empty: a.allow_empty,
        out: &a.out,
    };
    let model = a.spectral.model()?;
    if a.ct.ct.is_some() {
        let (implants, placed) = super::render_spectral::implant_meshes(
            &a.spectral.implant,
            a.spectral.screws_at.as_deref(),
        )?;
        let gpu = match a.backend {
            None => false,
            Some(Backend::Gpu) => true,
            Some(b) => bail!(
                "--backend {} renders meshes; a CT (--ct) renders on the CPU (leave --backend out) or \
                 with --backend gpu",
                Backend::name(b)
            ),
        };
        // On the gpu backend the implants' meshes render there too.
        let implants = super::render_ct::CtImplants {
            meshes: implants
                .into_iter()
                .map(|(_, m, material)| (m, material))
                .collect(),
            placed,
            backend: if gpu { Backend::Gpu } else { Backend::Raster },
        };
        return super::render_ct::run_ct(&a.ct, &run, model, implants, gpu);
    }
    let mesh_backend = a.backend.unwrap_or(Backend::Raster);
    if let Some(model) = model {
        let scene = super::render_spectral::SceneSpec {
            phantom: a.phantom.as_deref(),
            soft_tissue: a.soft_tissue,
            meshes: &a.mesh,
            mu_default: a.mu_default,
            implants: &a.spectral.implant,
            screws: a.spectral.screws,
            screws_at: a.spectral.screws_at.as_deref(),
        };
        return super::render_spectral::run_spectral(&scene, model, mesh_backend, &run);
    }

    let (scene, anatomy) = build_scene(&a)?;
    for w in scene.open_mesh_warnings() {
        eprintln!("warning: {w}");
    }
    let named: Vec<_> = scene
        .meshes
        .iter()
        .map(|m| (m.object.as_str(), m.mesh.as_ref()))
        .collect();
    check_source_outside(&rendered, &named)?;
    let corners = mesh_corners(scene.meshes.iter().map(|m| m.mesh.as_ref()));
    let mu_cause = mesh_mu_cause(&scene);
    let renderer = mesh_backend.renderer(scene)?;
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
    check_finite(&drr.line_integral, || mu_cause)?;
    check_not_empty(
        &drr.line_integral,
        &rendered,
        &perturbation.to_string(),
        &corners,
        a.allow_empty,
        || mesh_zero_cause(renderer.scene()),
    )?;
    check_not_negative(&drr.line_integral)?;

    let details = renderer.details(drr.stats, anatomy);
    let silhouettes = if a.masks {
        drr.silhouettes()?
    } else {
        Vec::new()
    };
    let products = DrrProducts {
        line_integral: &drr.line_integral,
        values,
        silhouettes: &silhouettes,
        depth: if a.depth { Some(drr.depth()?) } else { None },
    };
    write_drr_set(&a.out, &products, &view, &perturbation, &details)
        .with_context(|| format!("writing {}", a.out.display()))?;
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
        let (path, value) = split_mesh_spec(spec, a.mu_default)?;
        let mu = match value {
            Attenuation::Mu(mu) => mu,
            Attenuation::Material(m) => bail!(
                "--mesh {spec}: '{}' is a material, and materials need --spectrum (a monochromatic render \
                 takes μ in mm⁻¹, FILE:MU)",
                m.material.name
            ),
        };
        let mut mesh =
            read_mesh(&path).with_context(|| format!("reading mesh {}", path.display()))?;
        if let Some(w) = orient_outward_warning(&mut mesh, &path.display().to_string()) {
            eprintln!("warning: {w}");
        }
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

fn timing_json(
    a: &Args,
    r: &spinedrr::render::ThicknessRenderer,
    drr: &ThicknessDrr,
    times: &mut [f64],
) -> serde_json::Value {
    let (median, min) = median_min(times);
    json!({
        "backend": r.backend_name(),
        "adapter": r.gpu_adapter(),
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
