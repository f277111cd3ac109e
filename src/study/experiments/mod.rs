//! The experiments of a study: what one work unit computes. `Context` holds what the units share
//! (C-arm, per-target renderers, marker renderers, landmarks), built once before the parallel loop.

mod projection;
mod registration;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Arc, OnceLock};

use glam::{DVec2, DVec3};

use super::config::{MeshTarget, StudyConfig};
use super::units::{Unit, UnitRows, targets};
use crate::anatomy::{
    Level, Phantom, PhantomOptions, TriMesh, build_phantom, parse_levels, read_landmarks, read_mesh,
};
use crate::geometry::{CArm, View};
use crate::render::{RenderScene, SceneMesh, ThicknessDrr, ThicknessRenderer, phantom_scene};
use crate::{Error, Result};

/// A landmark marker: a small sphere rendered alone, so its blob centroid measures the landmark.
pub struct Marker {
    pub name: String,
    pub position: DVec3,
    pub renderer: ThicknessRenderer,
}

/// One studied object (a level or the segment).
pub struct Target {
    pub name: String,
    pub renderer: ThicknessRenderer,
    pub landmarks: Vec<(String, DVec3)>,
    pub markers: Vec<Marker>,
}

/// What every unit shares.
pub struct Context {
    pub cfg: StudyConfig,
    pub carm: CArm,
    pub targets: Vec<Target>,
    /// Where heatmap figures go.
    pub figures_dir: PathBuf,
    /// A one-thread pool for image metrics whose parallel reductions would otherwise depend on the
    /// thread count (determinism).
    pub metrics_pool: rayon::ThreadPool,
    /// Reference renders per (target, view), computed once on first use (they are deterministic, so
    /// which unit computes one does not matter).
    references: BTreeMap<(String, String), ReferenceCell>,
}

/// A lazily computed reference (the error kept as text so the cell can be shared).
type ReferenceCell = OnceLock<std::result::Result<Arc<Reference>, String>>;

/// The unperturbed render of a target in a view and its marker centroids.
pub struct Reference {
    pub drr: Option<ThicknessDrr>,
    pub markers: Vec<Option<DVec2>>,
}

impl Context {
    /// Builds the phantom, the scenes and the marker renderers.
    pub fn build(cfg: &StudyConfig, figures_dir: PathBuf) -> Result<Context> {
        let carm = cfg.carm()?;
        // Each level alone is built on its own, so it sits where the views aim (the world origin), as in
        // the paper's single-vertebra experiments; the segment is the whole stack.
        let phantom_of = |levels: Vec<Level>| {
            build_phantom(&PhantomOptions {
                levels,
                voxel_mm: cfg.anatomy.voxel_mm,
                discs: false,
                soft_tissue: false,
                ..PhantomOptions::default()
            })
        };
        let mut built = Vec::new();
        for name in targets(cfg) {
            if let Some(m) = cfg.anatomy.meshes.iter().find(|m| m.name == name) {
                built.push(mesh_target(cfg, m)?);
                continue;
            }
            let levels = if name == "segment" {
                cfg.levels()?
            } else {
                parse_levels(&name)?
            };
            built.push(build_target(cfg, &phantom_of(levels)?, &name)?);
        }
        let metrics_pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .map_err(|e| Error::Numerical(format!("building the metrics thread pool: {e}")))?;
        let mut references = BTreeMap::new();
        for t in &built {
            for v in &cfg.geometry.views {
                references.insert((t.name.clone(), v.clone()), OnceLock::new());
            }
        }
        Ok(Context {
            cfg: cfg.clone(),
            carm,
            targets: built,
            figures_dir,
            metrics_pool,
            references,
        })
    }

    /// The target called `name`.
    pub fn target(&self, name: &str) -> Result<&Target> {
        self.targets
            .iter()
            .find(|t| t.name == name)
            .ok_or_else(|| Error::invalid("target", format!("unknown target '{name}'")))
    }

    /// The reference render of `t` in `view` (cached).
    pub fn reference(&self, t: &Target, view: &View) -> Result<Arc<Reference>> {
        let cell = self
            .references
            .get(&(t.name.clone(), view.name.clone()))
            .ok_or_else(|| Error::invalid("view", format!("no reference for '{}'", view.name)))?;
        cell.get_or_init(|| {
            projection::reference(self, t, view)
                .map(Arc::new)
                .map_err(|e| e.to_string())
        })
        .clone()
        .map_err(Error::Numerical)
    }

    /// Runs one unit.
    pub fn run(&self, unit: &Unit) -> Result<UnitRows> {
        match unit {
            Unit::Projection { target, view, p } => {
                projection::run(self, self.target(target)?, view, p)
            }
            Unit::Registration { .. } => registration::run(self, unit),
        }
    }
}

/// The scene of one level (or all levels for `segment`), its landmarks and markers.
fn build_target(cfg: &StudyConfig, phantom: &Phantom, name: &str) -> Result<Target> {
    let sub = phantom;
    if sub.vertebrae.is_empty() {
        return Err(Error::invalid(
            "anatomy.levels",
            format!("no level '{name}' in the phantom"),
        ));
    }
    let backend = cfg.geometry.backend;
    let renderer = backend.renderer(phantom_scene(sub)?)?;
    target_with_landmarks(cfg, name, renderer, sub.landmarks(), name == "segment")
}

/// A target with its landmarks (prefixed with the level when `prefix_level`) and, when the landmark
/// experiment runs, one marker sphere per landmark.
fn target_with_landmarks(
    cfg: &StudyConfig,
    name: &str,
    renderer: ThicknessRenderer,
    sets: Vec<crate::anatomy::Landmarks>,
    prefix_level: bool,
) -> Result<Target> {
    let mut landmarks = Vec::new();
    for set in sets {
        for (n, &p) in &set.points {
            let full = if prefix_level {
                format!("{}/{n}", set.level)
            } else {
                n.clone()
            };
            landmarks.push((full, p));
        }
    }
    let markers = if cfg.runs("landmarks") {
        landmarks
            .iter()
            .map(|(n, p)| marker(cfg, n, *p))
            .collect::<Result<Vec<_>>>()?
    } else {
        Vec::new()
    };
    Ok(Target {
        name: name.to_string(),
        renderer,
        landmarks,
        markers,
    })
}

/// A target from the user's mesh files and landmarks JSON.
fn mesh_target(cfg: &StudyConfig, m: &MeshTarget) -> Result<Target> {
    let meshes = m
        .files
        .iter()
        .map(|f| {
            Ok(SceneMesh {
                mesh: Arc::new(read_mesh(f)?),
                mu_per_mm: m.mu_per_mm,
                object: m.name.clone(),
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let renderer = cfg.geometry.backend.renderer(RenderScene::new(meshes)?)?;
    let sets = read_landmarks(&m.landmarks)?;
    let several = sets.len() > 1;
    target_with_landmarks(cfg, &m.name, renderer, sets, several)
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
