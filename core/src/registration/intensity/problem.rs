//! The intensity problem file of `spinedrr register --intensity --problem P.json` and its `R.json`
//! record.
//!
//! `P.json`: `{"anatomy": A, "moving"?: "level" | "anatomy", "views": [{"name", "fixed": "ap.tiff", "K":
//! [[…]] (assumed), "world_to_camera": [[…]], "width"?, "height"?}, …], "init": {"R", "t"}, "truth"?:
//! {"R", "t"}, "similarity"?: "ncc" | "gc" | "gncc" | "lncc[:P]", "levels"?: [16, 8, 4, 2], "global"?: true,
//! "seed"?: 0}` with the anatomy `A` one of `{"phantom": "L3", "soft_tissue"?: false}`, `{"meshes":
//! [{"file", "mu_per_mm"}, …]}` (the first mesh is the vertebra: its vertices are the targets) or
//! `{"ct", "seg", "label", "labels"?}` (`label` a level name or id in the `labels` convention,
//! TotalSegmentator by default). Files are relative to the problem file. A view's size defaults to a
//! detector centred on its principal point, as in the landmark problem. A fixed image whose sidecar says
//! it holds counts (`units` of an intensity or X-ray-model image) is log-converted with its `I0`;
//! otherwise it is taken as a line integral.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::Deserialize;
use serde_json::{Value, json};

use super::anatomy::{MovingScope, level_targets, phantom_moving};
use super::evaluate::{mtre_mm, projected_tre_px, subsample};
use super::moving::{MeshDrr, MovingDrr};
use super::register::{IntensityOptions, IntensityProblem, IntensityView, register_intensity};
use super::similarity::Similarity;
use crate::anatomy::ct::{SurfaceOptions, VoxelMask, label_surface, read_ct, read_labels};
use crate::anatomy::labels::LabelConvention;
use crate::anatomy::{Level, PhantomOptions, build_phantom, read_mesh};
use crate::geometry::{Intrinsics, RigidTransform, View};
use crate::io::{ImageF32, Sidecar, read_tiff_f32, sidecar_path, units};
use crate::registration::pose_errors;
use crate::render::volume::{VolumeRenderOptions, VolumeRenderer};
use crate::render::{Backend, RenderScene, SceneMesh, VolumeOnBackend};
use crate::{Error, Result};

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PoseJson {
    #[serde(rename = "R")]
    r: [[f64; 3]; 3],
    t: [f64; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MeshJson {
    file: PathBuf,
    mu_per_mm: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AnatomyJson {
    phantom: Option<String>,
    #[serde(default)]
    soft_tissue: bool,
    meshes: Option<Vec<MeshJson>>,
    ct: Option<PathBuf>,
    seg: Option<PathBuf>,
    label: Option<Value>,
    labels: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ViewJson {
    name: String,
    fixed: PathBuf,
    #[serde(rename = "K")]
    k: [[f64; 3]; 3],
    world_to_camera: [[f64; 4]; 4],
    width: Option<u32>,
    height: Option<u32>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ProblemJson {
    anatomy: AnatomyJson,
    moving: Option<String>,
    views: Vec<ViewJson>,
    init: PoseJson,
    truth: Option<PoseJson>,
    similarity: Option<String>,
    levels: Option<Vec<u32>>,
    global: Option<bool>,
    seed: Option<u64>,
}

/// A problem file read and built: the problem, the options it asks for, the poses.
pub struct LoadedIntensityProblem {
    pub problem: IntensityProblem,
    pub options: IntensityOptions,
    pub init: RigidTransform,
    pub truth: Option<RigidTransform>,
}

impl LoadedIntensityProblem {
    /// Reads and builds `path` (anatomy, fixed images, views); every error names its field. A mesh or
    /// phantom anatomy renders with `backend`; a CT anatomy renders on the CPU, or on the GPU with
    /// `gpu` (embree and bvh are refused for it).
    pub fn read(path: &Path, backend: Backend) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let pj: ProblemJson =
            serde_json::from_str(&text).map_err(|e| Error::format(path, e.to_string()))?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let mut options = IntensityOptions::default();
        if let Some(s) = &pj.similarity {
            options.similarity = Similarity::parse(s)?;
        }
        if let Some(l) = &pj.levels {
            if l.is_empty() || l.iter().any(|&b| b == 0 || b > 64) {
                return Err(Error::invalid(
                    "levels",
                    format!("{l:?}: give binning factors between 1 and 64, coarsest first"),
                ));
            }
            options.levels = l.clone();
        }
        options.global = pj.global.unwrap_or(options.global);
        options.cmaes.seed = pj.seed.unwrap_or(0);
        let scope = MovingScope::parse(pj.moving.as_deref().unwrap_or("level"))?;
        let mut views = Vec::with_capacity(pj.views.len());
        for (i, v) in pj.views.iter().enumerate() {
            views.push(read_view(v, i, dir)?);
        }
        let (moving, targets) = build_anatomy(&pj.anatomy, scope, dir, backend)?;
        let init = RigidTransform::from_rt(pj.init.r, pj.init.t, "init")?;
        let truth = pj
            .truth
            .as_ref()
            .map(|p| RigidTransform::from_rt(p.r, p.t, "truth"))
            .transpose()?;
        let problem = IntensityProblem {
            moving,
            views,
            targets,
        };
        problem.validate()?;
        Ok(LoadedIntensityProblem {
            problem,
            options,
            init,
            truth,
        })
    }
}

fn read_view(v: &ViewJson, i: usize, dir: &Path) -> Result<IntensityView> {
    let field = format!("views[{i}]");
    let guess = |c: f64| (2.0 * c + 1.0).round().clamp(1.0, 16384.0) as u32;
    let k = Intrinsics::from_matrix(
        v.k,
        v.width.unwrap_or(guess(v.k[0][2])),
        v.height.unwrap_or(guess(v.k[1][2])),
    )
    .map_err(|e| Error::invalid(format!("{field}.K"), e.to_string()))?;
    let t = RigidTransform::from_rows(v.world_to_camera, &format!("{field}.world_to_camera"))?;
    let path = dir.join(&v.fixed);
    let fixed =
        read_fixed(&path).map_err(|e| Error::invalid(format!("{field}.fixed"), e.to_string()))?;
    if (fixed.width, fixed.height) != (k.width, k.height) {
        return Err(Error::invalid(
            format!("{field}.fixed"),
            format!(
                "{} is {}×{} px but the view is {}×{} (its width/height, or 2·cx + 1 × 2·cy + 1)",
                path.display(),
                fixed.width,
                fixed.height,
                k.width,
                k.height
            ),
        ));
    }
    Ok(IntensityView {
        view: View::new(v.name.clone(), k, t),
        fixed,
    })
}

/// A fixed image in the line-integral domain: counts (by their sidecar's units) are log-converted with
/// the sidecar's `I0`.
fn read_fixed(path: &Path) -> Result<ImageF32> {
    let mut img = read_tiff_f32(path)?;
    let sc = sidecar_path(path);
    if !sc.exists() {
        return Ok(img);
    }
    let s = Sidecar::read(&sc)?;
    let i0 = match s.units.as_str() {
        units::INTENSITY => s.details.get("I0").and_then(Value::as_f64),
        units::XRAY_COUNTS => s
            .details
            .get("xray_model")
            .and_then(|m| m.get("photons_i0"))
            .and_then(Value::as_f64),
        _ => return Ok(img),
    };
    let i0 = i0
        .filter(|v| *v > 0.0)
        .ok_or_else(|| Error::format(&sc, "an intensity image's sidecar must record its I0"))?;
    for x in &mut img.data {
        *x = -(f64::from(*x).max(0.5) / i0).ln() as f32;
    }
    Ok(img)
}

/// Fails unless exactly one anatomy kind is given.
fn anatomy_kind(a: &AnatomyJson) -> Result<&'static str> {
    let kinds: Vec<&str> = [
        ("phantom", a.phantom.is_some()),
        ("meshes", a.meshes.is_some()),
        ("ct", a.ct.is_some()),
    ]
    .into_iter()
    .filter_map(|(k, on)| on.then_some(k))
    .collect();
    match kinds.as_slice() {
        [one] => Ok(one),
        _ => Err(Error::invalid(
            "anatomy",
            "give exactly one of \"phantom\", \"meshes\" or {\"ct\", \"seg\", \"label\"}",
        )),
    }
}

fn build_anatomy(
    a: &AnatomyJson,
    scope: MovingScope,
    dir: &Path,
    backend: Backend,
) -> Result<(MovingDrr, Vec<glam::DVec3>)> {
    match anatomy_kind(a)? {
        "phantom" => {
            let spec = a.phantom.as_deref().unwrap_or_default();
            let level =
                Level::parse(spec).map_err(|e| Error::invalid("anatomy.phantom", e.to_string()))?;
            let phantom = build_phantom(&PhantomOptions {
                soft_tissue: a.soft_tissue,
                ..PhantomOptions::default()
            })?;
            Ok((
                phantom_moving(&phantom, level, scope, backend)?,
                level_targets(&phantom, level)?,
            ))
        }
        "meshes" => {
            let list = a.meshes.as_deref().unwrap_or_default();
            if list.is_empty() {
                return Err(Error::invalid("anatomy.meshes", "no mesh"));
            }
            let take = if scope == MovingScope::Level {
                1
            } else {
                list.len()
            };
            let mut meshes = Vec::new();
            for (i, m) in list.iter().enumerate().take(take) {
                let mesh = read_mesh(&dir.join(&m.file)).map_err(|e| {
                    Error::invalid(format!("anatomy.meshes[{i}].file"), e.to_string())
                })?;
                meshes.push(SceneMesh {
                    mesh: Arc::new(mesh),
                    mu_per_mm: m.mu_per_mm,
                    object: format!("mesh{i}"),
                });
            }
            let targets = subsample(&meshes[0].mesh.vertices, super::MAX_TARGET_POINTS);
            let renderer = backend.renderer(RenderScene::new(meshes)?)?;
            Ok((MovingDrr::Mesh(MeshDrr::new(renderer)), targets))
        }
        _ if !matches!(backend, Backend::Raster | Backend::Gpu) => Err(Error::invalid(
            "backend",
            format!(
                "{}: a CT anatomy renders with the CPU's volume renderer (the default) or the GPU's \
                 (gpu); embree and bvh trace meshes",
                backend.name()
            ),
        )),
        _ => {
            let ct_path = dir.join(a.ct.as_deref().unwrap_or(Path::new("")));
            let seg_path = dir.join(a.seg.as_deref().ok_or_else(|| {
                Error::invalid("anatomy.seg", "a CT anatomy needs its segmentation")
            })?);
            let convention: LabelConvention = match &a.labels {
                Some(s) => s.parse()?,
                None => LabelConvention::default(),
            };
            let label = match &a.label {
                Some(Value::Number(n)) => convention.resolve(&n.to_string())?,
                Some(Value::String(s)) => convention.resolve(s)?,
                _ => return Err(Error::invalid("anatomy.label", "a level name or label id")),
            };
            let ct = read_ct(&ct_path).map_err(|e| Error::invalid("anatomy.ct", e.to_string()))?;
            let seg =
                read_labels(&seg_path).map_err(|e| Error::invalid("anatomy.seg", e.to_string()))?;
            if seg.count(label) == 0 {
                return Err(Error::invalid(
                    "anatomy.label",
                    format!("label {label} does not occur in {}", seg_path.display()),
                ));
            }
            let surface = label_surface(&seg, label, &SurfaceOptions::default())?;
            let mask = VoxelMask::from_labels(&seg, &[label])?;
            let mask = (scope == MovingScope::Level).then_some(&mask);
            let renderer = VolumeRenderer::new(&ct, &VolumeRenderOptions::default(), mask)?;
            let targets = subsample(&surface.vertices, super::MAX_TARGET_POINTS);
            Ok((
                MovingDrr::Volume(Arc::new(VolumeOnBackend::new(renderer, backend)?)),
                targets,
            ))
        }
    }
}

/// Registers a loaded problem and returns the `R.json` record: `R`, `t`, `similarity`,
/// `per_view_similarity`, `evaluations`, `renders`, `seconds`, `converged`, `stages`, and with a truth
/// `rot_err_deg`, `trans_err_mm`, `mtre_mm`, `initial_mtre_mm` and `projected_tre_px` per view.
pub fn run_intensity_problem(loaded: &LoadedIntensityProblem) -> Result<Value> {
    let r = register_intensity(&loaded.problem, &loaded.init, &loaded.options)?;
    let mut record = json!({
        "R": r.pose.rotation_rows(),
        "t": r.pose.translation.to_array(),
        "similarity": r.similarity,
        "similarity_name": loaded.options.similarity.name(),
        "per_view_similarity": r.per_view_similarity,
        "evaluations": r.evaluations,
        "renders": r.renders,
        "seconds": r.seconds,
        "converged": r.converged,
        "levels": loaded.options.levels,
        "stages": r.stages,
        "tool": crate::io::TOOL,
        "kind": crate::io::kind::REGISTRATION,
    });
    if let Some(truth) = loaded.truth {
        let t = &loaded.problem.targets;
        let e = pose_errors(&r.pose, &truth);
        record["rot_err_deg"] = json!(e.rot_err_deg);
        record["trans_err_mm"] = json!(e.trans_err_mm);
        record["mtre_mm"] = json!(mtre_mm(&r.pose, &truth, t));
        record["initial_mtre_mm"] = json!(mtre_mm(&loaded.init, &truth, t));
        let per: serde_json::Map<String, Value> = loaded
            .problem
            .views
            .iter()
            .map(|v| {
                (
                    v.view.name.clone(),
                    json!(projected_tre_px(&v.view, &r.pose, &truth, t)),
                )
            })
            .collect();
        record["projected_tre_px"] = Value::Object(per);
    }
    Ok(record)
}
