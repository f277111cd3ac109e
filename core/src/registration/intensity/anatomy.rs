//! Registration targets built from the phantom: the moving DRR (the level alone or the whole
//! anatomy), the target points, and fixed images that look like fluoroscopy.

use glam::DVec3;

use super::evaluate::subsample;
use super::moving::{MeshDrr, MovingDrr};
use crate::anatomy::{Level, Phantom};
use crate::geometry::{RigidTransform, View};
use crate::io::{ImageF32, XrayModel};
use crate::render::{Backend, ThicknessOptions, ThicknessRenderer, phantom_scene};
use crate::{Error, Result};

/// At most this many target points (the level's cortical surface vertices, subsampled).
pub const MAX_TARGET_POINTS: usize = 2000;

/// What the moving DRR shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MovingScope {
    /// The registered level alone (its cortical and cancellous surfaces; a masked CT).
    Level,
    /// Everything the anatomy holds (neighbouring levels, discs, soft tissue; the whole CT).
    Anatomy,
}

impl MovingScope {
    /// `level` or `anatomy`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "level" => Ok(MovingScope::Level),
            "anatomy" => Ok(MovingScope::Anatomy),
            _ => Err(Error::invalid(
                "moving",
                format!("unknown moving DRR '{s}' (use level or anatomy)"),
            )),
        }
    }
}

/// The phantom reduced to one level: its vertebra alone, no discs, no soft tissue (absolute μ).
pub fn level_alone(phantom: &Phantom, level: Level) -> Result<Phantom> {
    let v = phantom
        .vertebrae
        .iter()
        .find(|v| v.level == level)
        .ok_or_else(|| Error::invalid("anatomy", format!("the phantom has no level {level}")))?;
    Ok(Phantom {
        vertebrae: vec![v.clone()],
        discs: Vec::new(),
        soft_tissue: None,
        disc_shapes: Vec::new(),
        soft_tissue_shape: None,
        cortical_mm: phantom.cortical_mm,
    })
}

/// A thickness renderer (raster backend) of `phantom`.
pub fn phantom_renderer(phantom: &Phantom) -> Result<ThicknessRenderer> {
    Backend::Raster.renderer(phantom_scene(phantom)?)
}

/// The moving DRR of `level` of `phantom` rendered with `backend`: the level alone or the whole
/// phantom.
pub fn phantom_moving(
    phantom: &Phantom,
    level: Level,
    scope: MovingScope,
    backend: Backend,
) -> Result<MovingDrr> {
    let renderer = match scope {
        MovingScope::Level => backend.renderer(phantom_scene(&level_alone(phantom, level)?)?)?,
        MovingScope::Anatomy => backend.renderer(phantom_scene(phantom)?)?,
    };
    Ok(MovingDrr::Mesh(MeshDrr::new(renderer)))
}

/// The target points of `level`: its cortical surface vertices, subsampled to at most
/// [`MAX_TARGET_POINTS`] (model frame = the phantom's world frame).
pub fn level_targets(phantom: &Phantom, level: Level) -> Result<Vec<DVec3>> {
    let v = level_alone(phantom, level)?;
    Ok(subsample(
        &v.vertebrae[0].cortical.vertices,
        MAX_TARGET_POINTS,
    ))
}

/// A fixed image in the line-integral domain: the DRR of `renderer` at pose `truth` seen from `view`
/// (the true K), through the X-ray model with its log conversion when one is given.
pub fn fixed_image(
    renderer: &ThicknessRenderer,
    view: &View,
    truth: &RigidTransform,
    model: Option<&XrayModel>,
) -> Result<ImageF32> {
    let moved = View {
        world_to_camera: view.world_to_camera.compose(truth),
        ..view.clone()
    };
    let li = renderer
        .render(&moved, &ThicknessOptions::image_only())?
        .line_integral;
    Ok(match model {
        Some(m) => XrayModel { log: true, ..*m }.apply(&li),
        None => li,
    })
}
