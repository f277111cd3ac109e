//! The experiments of a study: what one work unit computes. `Context` holds what the units share
//! (C-arm, per-target renderers, marker renderers, landmarks), built once before the parallel loop.
//!
//! The runner sees this module's public face only: [`load_inputs`] (read and check input files before
//! the output folder is touched), [`Context::build`], [`Context::prepare_references`], [`Context::run`].

mod calibration;
mod calibration_intensity;
mod calibration_physical;
mod ct;
mod intensity;
mod on_detector;
mod physical;
mod projection;
pub use projection::OUTLINE_KEY;
mod registration;
mod screws;
pub use screws::{SCREWS_KEY, screw_image_path};
mod tracking;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::config::{Experiment, MeshTarget, SEGMENT_TARGET, StudyConfig};
use super::schema::UnitRows;
use super::timings::{Phase, Timings};
use super::units::{Unit, targets};
use crate::anatomy::{
    Landmarks, Level, Phantom, PhantomOptions, TriMesh, build_phantom, parse_levels,
    read_landmarks, read_mesh,
};
use crate::geometry::{CArm, View};
use crate::io::ImageF32;
use crate::render::{
    RenderScene, SceneMesh, ThicknessDrr, ThicknessRenderer, VolumeOnBackend,
    orient_outward_warning, phantom_scene,
};
use crate::{Error, Result};
use ct::CtInput;

/// The folder of `out` that holds each (target, view)'s reference DRR (TIFF + JSON sidecar), the
/// background of the landmark overlay figures.
pub const REFERENCES_DIR: &str = "references";

/// `out/references/<target>_<view>.tiff`: the reference DRR of `target` in `view`.
pub fn reference_image_path(out: &Path, target: &str, view: &str) -> PathBuf {
    out.join(REFERENCES_DIR)
        .join(format!("{target}_{view}.tiff"))
}

/// Where the float difference image |A − B| of `target` in `view` at focal Δf `df_px` is written (beside
/// the reference DRRs), the data of the report's composed heatmap panel.
pub fn difference_image_path(out: &Path, target: &str, view: &str, df_px: f64) -> PathBuf {
    out.join(REFERENCES_DIR)
        .join(format!("{target}_{view}_absdiff_df{df_px}.tiff"))
}

/// The study's input files read and checked (mesh targets' surfaces and landmarks, CT volumes and label
/// maps and their landmarks), and the warnings they raised.
#[derive(Default)]
pub struct Inputs {
    meshes: Vec<MeshInput>,
    ct: Vec<CtInput>,
    /// What the runner prints before the work starts (inside-out meshes flipped, open meshes).
    pub warnings: Vec<String>,
}

/// A `[[anatomy.meshes]]` target read and checked: its scene (meshes oriented outward) and landmarks.
struct MeshInput {
    scene: RenderScene,
    landmarks: Vec<Landmarks>,
}

/// Reads and checks every input file the study needs beyond its config (meshes readable and valid,
/// landmarks parsed and non-empty, labels present, grids match), so a bad input fails before any
/// output is written; errors name the config key.
pub fn load_inputs(cfg: &StudyConfig) -> Result<Inputs> {
    let mut warnings = Vec::new();
    let meshes = cfg
        .anatomy
        .meshes
        .iter()
        .map(|m| load_mesh_input(m, &mut warnings))
        .collect::<Result<Vec<_>>>()?;
    Ok(Inputs {
        meshes,
        ct: ct::load_inputs(cfg)?,
        warnings,
    })
}

/// Reads one mesh target: every file (flipped outward when closed and inside out, with a warning; an
/// open one is kept with a warning, as `render` does) and its landmarks.
fn load_mesh_input(m: &MeshTarget, warnings: &mut Vec<String>) -> Result<MeshInput> {
    let named = |key: &str, e: Error| Error::invalid(key, format!("target '{}': {e}", m.name));
    let mut meshes = Vec::new();
    for f in &m.files {
        let mut mesh = read_mesh(f).map_err(|e| named("anatomy.meshes.files", e))?;
        if let Some(w) = orient_outward_warning(&mut mesh, &f.display().to_string()) {
            warnings.push(format!("target '{}': {w}", m.name));
        }
        meshes.push(SceneMesh {
            mesh: Arc::new(mesh),
            mu_per_mm: m.mu_per_mm,
            object: m.name.clone(),
        });
    }
    let scene = RenderScene::new(meshes).map_err(|e| named("anatomy.meshes.files", e))?;
    warnings.extend(
        scene
            .open_mesh_warnings()
            .into_iter()
            .map(|w| format!("target '{}': {w}", m.name)),
    );
    let landmarks =
        read_landmarks(&m.landmarks).map_err(|e| named("anatomy.meshes.landmarks", e))?;
    if landmarks.iter().all(|s| s.points.is_empty()) {
        return Err(Error::invalid(
            "anatomy.meshes.landmarks",
            format!(
                "target '{}': {} holds no landmarks",
                m.name,
                m.landmarks.display()
            ),
        ));
    }
    Ok(MeshInput { scene, landmarks })
}

/// A landmark marker: a small sphere rendered alone, so its blob centroid measures the landmark.
pub struct Marker {
    pub name: String,
    pub position: DVec3,
    pub renderer: ThicknessRenderer,
}

/// One studied object (a level, a segment, a mesh target).
pub struct Target {
    pub name: String,
    /// Thickness renderer: silhouettes and contours, and image metrics when there is no `volume`.
    pub renderer: ThicknessRenderer,
    /// CT volume DRR masked to the target's labels (CT targets): image metrics and heatmaps.
    pub volume: Option<Arc<VolumeOnBackend>>,
    pub landmarks: Vec<(String, DVec3)>,
    /// Clinical target points (world mm): the phantom's planned pedicle-screw entry, isthmus and tip per
    /// side, or a user target's landmarks whose name contains `pedicle`. Errors there are what a screw's
    /// 1–2 mm margin is measured against.
    pub clinical: Vec<(String, DVec3)>,
    pub markers: Vec<Marker>,
    /// How a CT target was moved to the world origin (recorded in its reference sidecars).
    pub placement: Option<crate::anatomy::ct::Placed>,
    /// A phantom target in its materials with its planned pedicle screws (when the screws experiment
    /// runs): the spectral radiographs of the screw figure.
    pub screw_scene: Option<crate::render::SpectralScene>,
}

/// What every unit shares.
pub struct Context {
    pub cfg: StudyConfig,
    pub carm: CArm,
    pub targets: Vec<Target>,
    /// Where heatmap figures go.
    pub figures_dir: PathBuf,
    /// The study's output folder (reference images go to [`reference_image_path`]).
    pub out: PathBuf,
    /// One-thread pools for image metrics, whose parallel reductions would otherwise depend on the
    /// thread count (determinism): one per worker, so workers do not queue behind each other.
    metrics_pools: Vec<rayon::ThreadPool>,
    /// Reference renders per (target, view), computed by [`Context::prepare_references`] before the
    /// units run (so no unit waits on another for one).
    references: BTreeMap<(String, String), Arc<Reference>>,
    /// Where the time goes (shared with the runner).
    pub timings: Arc<Timings>,
    /// The levels of the intensity-registration experiment, built once (empty when it does not run).
    pub intensity: Vec<intensity::IntensityTarget>,
}

/// The unperturbed render of a target in a view and its marker centroids.
pub struct Reference {
    pub drr: Option<ThicknessDrr>,
    /// The CT volume DRR, for targets with a volume.
    pub volume_drr: Option<ImageF32>,
    pub markers: Vec<Option<DVec2>>,
}

impl Context {
    /// Builds the phantom, the mesh and CT targets (from inputs read by [`load_inputs`]), the scenes
    /// and the marker renderers; anatomy in parallel over targets on `pool`. Products go under `out`.
    pub fn build(
        cfg: &StudyConfig,
        inputs: Inputs,
        out: &Path,
        timings: Arc<Timings>,
        pool: &rayon::ThreadPool,
    ) -> Result<Context> {
        let carm = cfg.carm()?;
        // Each level alone is built on its own, so its body centre is the world origin, as in
        // the paper's single-vertebra experiments; the segment is the whole stack.
        let phantom_of = |levels: Vec<Level>| {
            build_phantom(&PhantomOptions {
                levels,
                voxel_mm: cfg.anatomy.voxel_mm,
                discs: false,
                soft_tissue: false,
                ..PhantomOptions::default()
            })
            .map_err(|e| match e {
                // The grid-size limit names the phantom's option; here it is this config key.
                Error::Invalid { field, message } if field.starts_with("voxel_mm") => {
                    Error::invalid(format!("anatomy.{field}"), message)
                }
                other => other,
            })
        };
        let t = &timings;
        // Anatomy is built in parallel over targets (each build is deterministic).
        let phantom_targets: Vec<String> = cfg
            .anatomy
            .levels
            .iter()
            .cloned()
            .chain(
                (cfg.anatomy.segment && !cfg.anatomy.levels.is_empty())
                    .then(|| SEGMENT_TARGET.to_string()),
            )
            .collect();
        let phantoms = pool.install(|| {
            phantom_targets
                .par_iter()
                .map(|name| {
                    let levels = if name == SEGMENT_TARGET {
                        cfg.levels()?
                    } else {
                        parse_levels(name)?
                    };
                    t.time(Phase::Anatomy, 1, || phantom_of(levels))
                })
                .collect::<Result<Vec<Phantom>>>()
        })?;
        // Renderers are built one target at a time (they are not `Send`; Embree parallelises its own
        // BVH builds).
        let mut built = Vec::new();
        for (name, phantom) in phantom_targets.iter().zip(&phantoms) {
            built.push(build_target(cfg, phantom, name, t)?);
        }
        drop(phantoms);
        for (m, input) in cfg.anatomy.meshes.iter().zip(inputs.meshes) {
            built.push(mesh_target(cfg, m, input, t)?);
        }
        for input in inputs.ct {
            built.extend(ct::build_targets(cfg, input, t, pool)?);
        }
        // The order of `targets(cfg)`, whatever the build order.
        let order = targets(cfg);
        built.sort_by_key(|b| order.iter().position(|n| *n == b.name));
        let metrics_pools = (0..pool.current_num_threads())
            .map(|_| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(1)
                    .build()
                    .map_err(|e| Error::Resource(format!("building a metrics thread pool: {e}")))
            })
            .collect::<Result<Vec<_>>>()?;
        let intensity = if cfg.runs(Experiment::IntensityRegistration) {
            intensity::prepare(cfg, t)?
        } else {
            Vec::new()
        };
        Ok(Context {
            cfg: cfg.clone(),
            carm,
            targets: built,
            figures_dir: out.join("figures"),
            out: out.to_path_buf(),
            metrics_pools,
            references: BTreeMap::new(),
            timings,
            intensity,
        })
    }

    /// The target called `name`.
    pub fn target(&self, name: &str) -> Result<&Target> {
        self.targets
            .iter()
            .find(|t| t.name == name)
            .ok_or_else(|| Error::invalid("target", format!("unknown target '{name}'")))
    }

    /// Renders, in parallel on `pool`, the references the projection units of `units` need.
    pub fn prepare_references(&mut self, units: &[&Unit], pool: &rayon::ThreadPool) -> Result<()> {
        let mut pairs: Vec<(String, String)> = Vec::new();
        for u in units {
            if let Unit::Projection { target, view, .. } = u {
                let key = (target.clone(), view.clone());
                if !pairs.contains(&key) && !self.references.contains_key(&key) {
                    pairs.push(key);
                }
            }
        }
        let this = &*self;
        let refs = pool.install(|| {
            pairs
                .par_iter()
                .map(|(t, v)| projection::reference(this, this.target(t)?, this.carm.view(v)?))
                .collect::<Result<Vec<_>>>()
        })?;
        for (key, r) in pairs.into_iter().zip(refs) {
            self.references.insert(key, Arc::new(r));
        }
        Ok(())
    }

    /// The reference render of `t` in `view` (see [`Context::prepare_references`]).
    pub fn reference(&self, t: &Target, view: &View) -> Result<Arc<Reference>> {
        self.references
            .get(&(t.name.clone(), view.name.clone()))
            .cloned()
            .ok_or_else(|| {
                Error::Internal(format!(
                    "no reference render of '{}' in view '{}' was prepared",
                    t.name, view.name
                ))
            })
    }

    /// Runs `f` (image metrics with parallel reductions) on the calling worker's one-thread pool, from
    /// a plain thread: a rayon worker waiting in `install` would run other units meanwhile (nesting
    /// them inside this one); a blocked plain thread just waits. One thread means one reduction order,
    /// so the result does not depend on the run's thread count.
    pub fn isolated_metrics<T: Send>(&self, f: impl FnOnce() -> T + Send) -> T {
        let i = rayon::current_thread_index().unwrap_or(0);
        let pool = &self.metrics_pools[i % self.metrics_pools.len()];
        std::thread::scope(|s| match s.spawn(|| pool.install(f)).join() {
            Ok(v) => v,
            Err(panic) => std::panic::resume_unwind(panic),
        })
    }

    /// Runs one unit.
    pub fn run(&self, unit: &Unit) -> Result<UnitRows> {
        match unit {
            Unit::Projection { target, view, p } => {
                projection::run(self, self.target(target)?, view, p)
            }
            Unit::Registration { .. } => registration::run(self, unit),
            Unit::Calibration(c) => match &c.physical {
                Some(q) => calibration_physical::run(self, c, q),
                None => calibration::run(self, c),
            },
            Unit::Intensity(c) => intensity::run(self, c),
            Unit::Tracking(c) => tracking::run(self, c),
            Unit::Screws { target } => screws::run(self, target),
            Unit::RegistrationPhysical(c) => registration::run_physical(self, c),
        }
    }
}

/// How far the segment is moved along the world z axis (mm) by [`segment_placed`]: from the mean height
/// of its levels' body centres to the mean height of the studied views' aims (each central ray's point
/// nearest the world origin). A single level sits at the world origin; a segment of several levels is
/// taller than a vertebra, so it is centred between the views' aim heights instead of on its middle
/// level, which keeps it whole on the detector in both views of the default geometry.
pub fn segment_shift_mm(phantom: &Phantom, carm: &crate::geometry::CArm, views: &[String]) -> f64 {
    let aims: Vec<f64> = carm
        .views
        .iter()
        .filter(|v| views.contains(&v.name))
        .map(|v| v.aim().0.z)
        .collect();
    let centres: Vec<f64> = phantom
        .vertebrae
        .iter()
        .map(|v| v.local_to_world.translation.z)
        .collect();
    if aims.is_empty() || centres.is_empty() {
        return 0.0;
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    mean(&aims) - mean(&centres)
}

/// The segment's vertebrae (meshes, landmarks, poses) moved by [`segment_shift_mm`] along z (the
/// study's phantoms have no discs or soft tissue).
fn segment_placed(phantom: &Phantom, carm: &crate::geometry::CArm, views: &[String]) -> Phantom {
    let d = glam::DVec3::new(0.0, 0.0, segment_shift_mm(phantom, carm, views));
    let t = crate::geometry::RigidTransform::new(glam::DMat3::IDENTITY, d);
    let mut p = phantom.clone();
    for v in &mut p.vertebrae {
        v.cortical.transform(&t);
        v.cancellous.transform(&t);
        for x in v.landmarks.points.values_mut() {
            *x += d;
        }
        v.local_to_world = t.compose(&v.local_to_world);
    }
    p
}

/// The scene of one level (or all levels for `segment`), its landmarks and markers.
fn build_target(
    cfg: &StudyConfig,
    phantom: &Phantom,
    name: &str,
    timings: &Timings,
) -> Result<Target> {
    let sub = phantom;
    if sub.vertebrae.is_empty() {
        return Err(Error::invalid(
            "anatomy.levels",
            format!("no level '{name}' in the phantom"),
        ));
    }
    let placed;
    let sub = if name == SEGMENT_TARGET {
        placed = segment_placed(sub, &cfg.carm()?, &cfg.geometry.views);
        &placed
    } else {
        sub
    };
    let backend = cfg.geometry.backend;
    let renderer = timings.time(Phase::Scene, 1, || backend.renderer(phantom_scene(sub)?))?;
    let mut t = target_with_landmarks(
        cfg,
        name,
        renderer,
        sub.landmarks(),
        name == SEGMENT_TARGET,
        timings,
    )?;
    t.clinical =
        crate::anatomy::Landmarks::named_points(sub.pedicle_targets(), name == SEGMENT_TARGET);
    if cfg.runs(Experiment::Screws) {
        t.screw_scene = Some(timings.time(Phase::Scene, 1, || {
            let mut scene = crate::render::phantom_spectral_scene(sub)?;
            crate::render::add_pedicle_screws(&mut scene, sub)?;
            Ok::<_, Error>(scene)
        })?);
    }
    Ok(t)
}

/// A target with its landmarks (prefixed with the level when `prefix_level`) and, when the landmark
/// experiment runs, one marker sphere per landmark.
fn target_with_landmarks(
    cfg: &StudyConfig,
    name: &str,
    renderer: ThicknessRenderer,
    sets: Vec<crate::anatomy::Landmarks>,
    prefix_level: bool,
    timings: &Timings,
) -> Result<Target> {
    let landmarks = crate::anatomy::Landmarks::named_points(sets, prefix_level);
    let markers = if cfg.runs(Experiment::Landmarks) {
        timings.time(Phase::Scene, landmarks.len() as u64, || {
            landmarks
                .iter()
                .map(|(n, p)| marker(cfg, n, *p))
                .collect::<Result<Vec<_>>>()
        })?
    } else {
        Vec::new()
    };
    // A user's pedicle landmarks are its clinical targets (the phantom's replace them, see
    // `build_target`).
    let clinical = landmarks
        .iter()
        .filter(|(n, _)| n.contains("pedicle"))
        .cloned()
        .collect();
    Ok(Target {
        name: name.to_string(),
        renderer,
        volume: None,
        landmarks,
        clinical,
        markers,
        placement: None,
        screw_scene: None,
    })
}

/// A target from the user's mesh files and landmarks JSON (read by [`load_inputs`]).
fn mesh_target(
    cfg: &StudyConfig,
    m: &MeshTarget,
    input: MeshInput,
    timings: &Timings,
) -> Result<Target> {
    let MeshInput { scene, landmarks } = input;
    let renderer = timings.time(Phase::Scene, 1, || cfg.geometry.backend.renderer(scene))?;
    let several = landmarks.len() > 1;
    target_with_landmarks(cfg, &m.name, renderer, landmarks, several, timings)
}

fn marker(cfg: &StudyConfig, name: &str, position: DVec3) -> Result<Marker> {
    let sphere = TriMesh::icosphere(name, position, cfg.anatomy.marker_radius_mm, 3);
    let scene = RenderScene::new(vec![SceneMesh {
        mesh: Arc::new(sphere),
        mu_per_mm: 1.0,
        object: "marker".into(),
    }])?;
    Ok(Marker {
        name: name.to_string(),
        position,
        renderer: cfg.geometry.backend.renderer(scene)?,
    })
}
