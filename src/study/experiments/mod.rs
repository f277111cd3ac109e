//! The experiments of a study: what one work unit computes. `Context` holds what the units share
//! (C-arm, per-target renderers, marker renderers, landmarks), built once before the parallel loop.

mod projection;
mod registration;

use std::path::PathBuf;
use std::sync::Arc;

use glam::DVec3;

use super::config::StudyConfig;
use super::units::{Unit, UnitRows, targets};
use crate::anatomy::{Phantom, PhantomOptions, TriMesh, build_phantom};
use crate::geometry::CArm;
use crate::render::{RenderScene, SceneMesh, ThicknessRenderer, phantom_scene};
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
}

impl Context {
    /// Builds the phantom, the scenes and the marker renderers.
    pub fn build(cfg: &StudyConfig, figures_dir: PathBuf) -> Result<Context> {
        let carm = cfg.carm()?;
        let phantom = build_phantom(&PhantomOptions {
            levels: cfg.levels()?,
            voxel_mm: cfg.anatomy.voxel_mm,
            discs: false,
            soft_tissue: false,
            ..PhantomOptions::default()
        })?;
        let targets = targets(cfg)
            .iter()
            .map(|t| build_target(cfg, &phantom, t))
            .collect::<Result<Vec<_>>>()?;
        let metrics_pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .map_err(|e| Error::Numerical(format!("building the metrics thread pool: {e}")))?;
        Ok(Context {
            cfg: cfg.clone(),
            carm,
            targets,
            figures_dir,
            metrics_pool,
        })
    }

    /// The target called `name`.
    pub fn target(&self, name: &str) -> Result<&Target> {
        self.targets
            .iter()
            .find(|t| t.name == name)
            .ok_or_else(|| Error::invalid("target", format!("unknown target '{name}'")))
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
    let mut sub = phantom.clone();
    if name != "segment" {
        sub.vertebrae.retain(|v| v.level.name() == name);
    }
    if sub.vertebrae.is_empty() {
        return Err(Error::invalid(
            "anatomy.levels",
            format!("no level '{name}' in the phantom"),
        ));
    }
    let backend = cfg.geometry.backend;
    let renderer = backend.renderer(phantom_scene(&sub)?)?;
    let segment = name == "segment";
    let mut landmarks = Vec::new();
    for set in sub.landmarks() {
        for (lname, &p) in &set.points {
            let full = if segment {
                format!("{}/{lname}", set.level)
            } else {
                lname.clone()
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
