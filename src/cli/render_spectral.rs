//! `spinedrr render --spectrum`: a polychromatic DRR of the phantom or of meshes with materials.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, bail};
use serde_json::json;
use spinedrr::anatomy::{
    Landmarks, PhantomOptions, TriMesh, build_phantom, parse_levels, read_landmarks,
};
use spinedrr::geometry::RigidTransform;
use spinedrr::io::{DrrProducts, write_drr_set};
use spinedrr::render::{
    Backend, SpectralInput, SpectralRenderer, SpectralScene, add_pedicle_screws,
    phantom_spectral_scene, planned_screw_implants,
};
use spinedrr::spectral::{Attenuation, Channel, SpectralModel, model_from_specs};

use super::render_checks::{
    RenderRun, check_finite, check_not_empty, check_not_negative, check_source_outside,
    mesh_corners, split_implant_spec, split_mesh_spec,
};
use super::render_timing::{median_min, peak_rss_mb};

/// The spectral model's flags.
#[derive(clap::Args)]
pub struct SpectralArgs {
    /// Render a polychromatic radiograph (meshes, phantom or CT). SPEC: a tube potential in kV for TASMIP's
    /// tungsten-anode spectrum (Boone & Seibert 1997, 30–140 kV, e.g. 80), `mono:E` for one energy (keV),
    /// or a spectrum file (energy keV and photon fluence per line). The image is −ln(I/I0) of an
    /// energy-integrating detector, with per-material path lengths from the exact mesh renders; with
    /// --intensity or --photons, the detected signal. Meshes take materials, --mesh FILE:MATERIAL[@DENSITY]
    /// (MATERIALS: air, water, adipose, soft_tissue, cortical_bone, cancellous_bone, titanium (Ti-6Al-4V),
    /// steel (316L), cobalt_chrome, peek, aluminium, copper, csi); a material mesh inside another displaces
    /// it. FILE:MU meshes keep their energy-independent μ. A --ct's voxels become soft tissue and cortical
    /// bone (HU ≤ 100 soft tissue at 1 + HU/1000 g/cm³, 100–1500 HU a mixture, ≥ 1500 HU bone; one Siddon
    /// render per material). The sidecar records the spectrum (bins, fluence, mean energy, Al HVL), the
    /// detector and the channels.
    #[arg(long, value_name = "SPEC", conflicts_with_all = ["masks", "depth"])]
    pub spectrum: Option<String>,
    /// With --spectrum: added filtration, comma-separated MATERIAL[@DENSITY]:MM, e.g. `al:2.5,cu:0.1`.
    /// TASMIP's spectra already carry their tube's inherent filtration.
    #[arg(long, value_name = "LIST", requires = "spectrum")]
    pub filter: Option<String>,
    /// With --spectrum: the detector, MATERIAL:MM of scintillator (η(E) = 1 − exp(−μ(E)·t)) or `ideal`
    /// (η = 1); each photon adds η(E)·E to the signal.
    #[arg(
        long,
        value_name = "SPEC",
        default_value = "csi:0.6",
        requires = "spectrum"
    )]
    pub detector: String,
    /// With --spectrum: an implant mesh, FILE:MATERIAL[@DENSITY][:POSE.json] (e.g. screw.stl:titanium or
    /// screw.stl:titanium:pose.json). A pose file places the mesh (model → world): {"R": [[3 × 3 rows]],
    /// "t": [mm]} — the layout of `spinedrr register`'s R.json — or {"matrix": [[4 × 4 rows]]}; without
    /// one the mesh is placed as its file gives it. Along every ray
    /// it displaces whatever it occupies (phantom tissue, --mesh surfaces, or a --ct's voxels: each CT
    /// material's Siddon integral over the implant's stretch of the ray is subtracted), so the tissue under
    /// it is not counted twice. With --ct it is in the CT file's world coordinates and moves with the CT's
    /// --placement. Repeat for several implants.
    #[arg(long, value_name = "FILE:MATERIAL", requires = "spectrum")]
    pub implant: Vec<String>,
    /// With --spectrum and --phantom: two titanium (Ti-6Al-4V) pedicle screws per level, along each
    /// pedicle's planned trajectory from its entry point to its tip (the `*_pedicle_entry` and `*_tip`
    /// targets of `spinedrr phantom`): 6.5 mm thread, 4.5 mm core, 2.75 mm pitch, 4 mm conical tip, and a
    /// 12 × 14 mm tulip head on the entry point. They displace the bone and tissue they occupy.
    #[arg(long, requires = "spectrum", requires = "phantom")]
    pub screws: bool,
    /// With --spectrum: a titanium pedicle screw (the --screws screw) along every planned trajectory of a
    /// landmark file (JSON, Slicer markups, CSV; world mm): each `PREFIXpedicle_entry` with the
    /// `PREFIXpedicle_tip` of the same prefix (e.g. `left_pedicle_entry` → `left_pedicle_tip`), the tip at
    /// the tip point. For --mesh scenes (a user's vertebra), a --ct (the plan in the CT file's world
    /// coordinates, moved with its --placement) or beside --screws.
    #[arg(long, value_name = "FILE", requires = "spectrum")]
    pub screws_at: Option<std::path::PathBuf>,
}

impl SpectralArgs {
    /// The filtered spectrum on the detector, when --spectrum is given.
    pub fn model(&self) -> anyhow::Result<Option<SpectralModel>> {
        let Some(spec) = &self.spectrum else {
            return Ok(None);
        };
        let filters = self.filter.as_deref().unwrap_or("");
        let model = model_from_specs(spec, filters, &self.detector).with_context(|| {
            format!(
                "--spectrum {spec} --filter '{filters}' --detector {}",
                self.detector
            )
        })?;
        Ok(Some(model))
    }
}

/// What the spectral render needs of `spinedrr render`'s flags.
pub struct SceneSpec<'a> {
    pub phantom: Option<&'a str>,
    pub soft_tissue: bool,
    pub meshes: &'a [String],
    pub mu_default: f64,
    pub implants: &'a [String],
    pub screws: bool,
    pub screws_at: Option<&'a Path>,
}

/// The spectral scene and its description for the sidecar.
fn build_scene(s: &SceneSpec) -> anyhow::Result<(SpectralScene, serde_json::Value)> {
    if s.screws && s.phantom.is_none() {
        bail!(
            "--screws places screws along the phantom's pedicles and needs --phantom; give a mesh's screws \
             as --implant FILE:titanium"
        );
    }
    let (mut scene, mut anatomy) = if let Some(levels) = s.phantom {
        let opts = PhantomOptions {
            levels: parse_levels(levels)?,
            soft_tissue: s.soft_tissue,
            ..PhantomOptions::default()
        };
        let phantom = build_phantom(&opts).context("building the phantom")?;
        let mut scene = phantom_spectral_scene(&phantom)?;
        if s.screws {
            add_pedicle_screws(&mut scene, &phantom)?;
        }
        (
            scene,
            json!({"phantom": levels, "soft_tissue": s.soft_tissue, "pedicle_screws": s.screws}),
        )
    } else {
        let mut items = Vec::new();
        for spec in s.meshes {
            let (path, attenuation) = split_mesh_spec(spec, s.mu_default)?;
            items.push(SpectralInput {
                mesh: Arc::new(load_mesh(&path)?),
                object: stem(&path),
                attenuation,
                implant: false,
            });
        }
        let (scene, warnings) = SpectralScene::from_meshes(items)?;
        for w in warnings {
            eprintln!("warning: {w}");
        }
        (scene, json!({"files": s.meshes}))
    };
    let (implants, placed) = implant_meshes(s.implants, s.screws_at)?;
    for (object, mesh, material) in implants {
        scene.add_implant(mesh, object, material);
    }
    merge_placed(&mut anatomy, placed);
    anatomy["implants"] = json!(s.implants);
    anatomy["meshes"] = describe(&scene);
    Ok((scene, anatomy))
}

/// Implants as (object, mesh, material).
pub type Implants = spinedrr::render::ImplantMeshes;

/// The implants of `--implant FILE:MATERIAL[:POSE]` and `--screws-at PLAN`, and what placed them for the
/// sidecar: `implant_poses` (each posed implant's spec and the 4 × 4 matrix applied, so the record holds
/// the pose even if its file changes) and `screws_at` (the plan's file and screws).
pub fn implant_meshes(
    implants: &[String],
    screws_at: Option<&Path>,
) -> anyhow::Result<(Implants, serde_json::Value)> {
    let mut out = Vec::new();
    let mut placed = json!({});
    let mut poses = Vec::new();
    for spec in implants {
        let (path, value, pose) = split_implant_spec(spec)?;
        let Attenuation::Material(material) = value else {
            bail!(
                "--implant {spec}: give the implant's material, FILE:MATERIAL[@DENSITY][:POSE.json] (e.g. \
                 :titanium)"
            );
        };
        let mut mesh = load_mesh(&path)?;
        if let Some(pose_path) = pose {
            let pose = read_pose(&pose_path).with_context(|| format!("--implant {spec}"))?;
            mesh.transform(&pose);
            poses.push(json!({"implant": spec, "matrix": pose.to_rows()}));
        }
        out.push((stem(&path), Arc::new(mesh), material));
    }
    if !poses.is_empty() {
        placed["implant_poses"] = json!(poses);
    }
    let Some(path) = screws_at else {
        return Ok((out, placed));
    };
    let sets = read_landmarks(path).with_context(|| format!("--screws-at {}", path.display()))?;
    let several = sets.len() > 1;
    let (screws, meshes) = planned_screw_implants(&Landmarks::named_points(sets, several), "plan")
        .with_context(|| format!("--screws-at {}", path.display()))?;
    out.extend(meshes);
    placed["screws_at"] = json!({
        "file": path.display().to_string(),
        "screws": screws
            .iter()
            .map(|s| json!({"name": s.name, "entry": s.entry.to_array(), "tip": s.tip.to_array()}))
            .collect::<Vec<_>>(),
    });
    Ok((out, placed))
}

/// Adds the keys of [`implant_meshes`]' record to a sidecar object.
pub fn merge_placed(into: &mut serde_json::Value, placed: serde_json::Value) {
    if let (Some(into), serde_json::Value::Object(p)) = (into.as_object_mut(), placed) {
        into.extend(p);
    }
}

/// The pose of an `--implant …:POSE.json` file (model → world).
fn read_pose(path: &Path) -> anyhow::Result<RigidTransform> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("reading the pose file {}", path.display()))?;
    Ok(RigidTransform::from_json_str(
        &text,
        &path.display().to_string(),
    )?)
}

fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

fn load_mesh(path: &Path) -> anyhow::Result<TriMesh> {
    let mut mesh = spinedrr::anatomy::read_mesh(path)
        .with_context(|| format!("reading mesh {}", path.display()))?;
    if let Some(w) =
        spinedrr::render::orient_outward_warning(&mut mesh, &path.display().to_string())
    {
        eprintln!("warning: {w}");
    }
    Ok(mesh)
}

/// Per mesh: its name, object and terms (channel name, coefficient).
fn describe(scene: &SpectralScene) -> serde_json::Value {
    json!(scene.meshes.iter().map(|m| json!({
        "mesh": m.mesh.name,
        "object": m.object,
        "implant": m.implant,
        "terms": m.terms.iter().map(|&(c, k)| json!({
            "channel": scene.channels[c].name(),
            "coefficient": k,
            "unit": match scene.channels[c] { Channel::FixedMu => "mm^-1", Channel::Material(_) => "g/cm^3" },
        })).collect::<Vec<_>>(),
    })).collect::<Vec<_>>())
}

/// Renders, checks and writes the spectral DRR.
pub fn run_spectral(
    s: &SceneSpec,
    model: SpectralModel,
    backend: Backend,
    run: &RenderRun,
) -> anyhow::Result<()> {
    let (scene, anatomy) = build_scene(s)?;
    let named: Vec<(&str, &TriMesh)> = scene
        .meshes
        .iter()
        .map(|m| (m.mesh.name.as_str(), m.mesh.as_ref()))
        .collect();
    check_source_outside(run.rendered, &named)?;
    let corners = mesh_corners(scene.meshes.iter().map(|m| m.mesh.as_ref()));
    let renderer = SpectralRenderer::new(&scene, model, backend)?;
    let mut drr = renderer.render(run.rendered)?;
    let mut times = vec![(drr.channels_ms, drr.energy_sum_ms)];
    for _ in 1..run.repeat {
        drr = renderer.render(run.rendered)?;
        times.push((drr.channels_ms, drr.energy_sum_ms));
    }
    if drr.rays_unrepaired > 0 {
        eprintln!(
            "warning: {} rays did not pair their surface crossings even after retracing (is a mesh open or \
             self-intersecting?)",
            drr.rays_unrepaired
        );
    }
    if run.repeat > 1 {
        let mut total: Vec<f64> = times.iter().map(|(a, b)| a + b).collect();
        let mut ch: Vec<f64> = times.iter().map(|t| t.0).collect();
        let mut es: Vec<f64> = times.iter().map(|t| t.1).collect();
        let (median, min) = median_min(&mut total);
        eprintln!(
            "{}",
            json!({
                "renderer": "spectral",
                "backend": backend,
                "adapter": renderer.gpu_adapter(),
                "repeat": run.repeat,
                "bins": renderer.model.bins(),
                "channels": renderer.channels.len(),
                "median_ms": median,
                "min_ms": min,
                "channels_median_ms": median_min(&mut ch).0,
                "energy_sum_median_ms": median_min(&mut es).0,
                "peak_rss_mb": peak_rss_mb(),
            })
        );
    }
    check_finite(&drr.line_integral, || {
        "a mesh's density or μ is not finite".to_string()
    })?;
    check_not_empty(
        &drr.line_integral,
        run.rendered,
        &run.perturbation.to_string(),
        &corners,
        run.allow_empty,
        || Some("every mesh's density or μ is 0".to_string()),
    )?;
    check_not_negative(&drr.line_integral)?;
    let mut details = json!({
        "renderer": "spectral",
        "backend": backend,
        "gpu_adapter": renderer.gpu_adapter(),
        "anatomy": anatomy,
        "spectral": renderer.summary(),
        "stats": {"channels_ms": drr.channels_ms, "energy_sum_ms": drr.energy_sum_ms},
    });
    if let Some(n) = drr.gpu_rays_on_cpu {
        details["stats"]["gpu_rays_on_cpu"] = n.into();
    }
    let products = DrrProducts {
        line_integral: &drr.line_integral,
        values: run.values,
        silhouettes: &[],
        depth: None,
    };
    write_drr_set(run.out, &products, run.view, run.perturbation, &details)
        .with_context(|| format!("writing {}", run.out.display()))?;
    eprintln!(
        "{}: {} × {} spectral DRR ({}, {} bins, mean {:.1} keV, {} channels), view {}, perturbation {}, \
         {:.1} ms + {:.1} ms energy sum",
        run.out.display(),
        drr.line_integral.width,
        drr.line_integral.height,
        renderer.model.spectrum.source,
        renderer.model.bins(),
        renderer.model.spectrum.mean_energy_kev(),
        renderer.channels.len(),
        run.view.name,
        run.perturbation,
        drr.channels_ms,
        drr.energy_sum_ms
    );
    Ok(())
}
