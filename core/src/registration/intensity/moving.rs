//! The moving DRR: the anatomy built once (a thickness renderer over its meshes, with coarser levels of
//! detail for the coarse levels, or a CT volume renderer) in model coordinates. A DRR at pose `T`
//! (model → world) seen from view `(K, W)` is the DRR of the unmoved model seen from `(K, W · T)`: the
//! camera moves instead of the anatomy, so nothing is rebuilt per evaluation (the raster backend only
//! re-projects the vertices).

use std::sync::{Arc, Mutex};

use crate::anatomy::decimate;
use crate::geometry::{RigidTransform, View};
use crate::io::ImageF32;
use crate::render::VolumeOnBackend;
use crate::render::{Backend, RenderScene, SceneMesh, ThicknessRenderer};
use crate::{Error, Result};

/// What the moving DRR is rendered from (built once, model coordinates).
pub enum MovingDrr {
    /// Closed meshes with μ (the level alone, or the whole anatomy), rendered by a thickness renderer.
    Mesh(MeshDrr),
    /// A CT (optionally masked to the level) rendered by Siddon or trilinear sampling, on the CPU or
    /// (the gpu backend) in the GPU's compute shader.
    Volume(Arc<VolumeOnBackend>),
}

impl MovingDrr {
    /// The GPU adapter the moving DRR renders on (meshes on the gpu backend), else `None`.
    pub fn gpu_adapter(&self) -> Option<String> {
        match self {
            MovingDrr::Mesh(m) => m.full.gpu_adapter(),
            MovingDrr::Volume(v) => v.gpu_adapter(),
        }
    }

    /// The backend the moving DRR renders with (`None` for a CT, which the volume renderer renders).
    pub fn backend(&self) -> Option<Backend> {
        match self {
            MovingDrr::Mesh(m) => Some(m.full.backend()),
            MovingDrr::Volume(v) => v.gpu_adapter().map(|_| Backend::Gpu),
        }
    }
}

/// Fewest triangles a decimated mesh of a coarse level keeps.
const MIN_LOD_TRIANGLES: usize = 500;

/// A mesh scene and its coarser versions for coarse resolution levels: at detail factor `f` (the
/// level's binning over the finest level's), each mesh decimated to `1/f²` of its triangles (at least
/// [`MIN_LOD_TRIANGLES`]), built on first use and kept. The finest level always renders the full
/// meshes, so the final optimum is the full model's.
pub struct MeshDrr {
    full: Arc<ThicknessRenderer>,
    lods: Mutex<Vec<(u32, Arc<ThicknessRenderer>)>>,
}

impl MeshDrr {
    pub fn new(renderer: ThicknessRenderer) -> Self {
        MeshDrr {
            full: Arc::new(renderer),
            lods: Mutex::new(Vec::new()),
        }
    }

    /// Another handle on the same renderers (the full meshes and every level of detail built so far),
    /// without rebuilding anything: build the levels a schedule needs with [`MeshDrr::at_detail`] first,
    /// then share one moving DRR between many problems.
    pub fn share(&self) -> Result<MeshDrr> {
        let lods = self
            .lods
            .lock()
            .map_err(|_| Error::Internal("level-of-detail cache poisoned".into()))?
            .clone();
        Ok(MeshDrr {
            full: self.full.clone(),
            lods: Mutex::new(lods),
        })
    }

    /// The renderer of detail factor `factor` (1 = the full meshes).
    pub fn at_detail(&self, factor: u32) -> Result<Arc<ThicknessRenderer>> {
        if factor <= 1 {
            return Ok(self.full.clone());
        }
        let mut lods = self
            .lods
            .lock()
            .map_err(|_| Error::Internal("level-of-detail cache poisoned".into()))?;
        if let Some((_, r)) = lods.iter().find(|(f, _)| *f == factor) {
            return Ok(r.clone());
        }
        let div = (factor as usize).pow(2);
        let meshes = self
            .full
            .scene()
            .meshes
            .iter()
            .map(|m| {
                let n = m.mesh.triangles.len();
                let target = (n / div).max(MIN_LOD_TRIANGLES);
                let mesh = if target < n {
                    Arc::new(decimate(&m.mesh, target)?)
                } else {
                    m.mesh.clone()
                };
                Ok(SceneMesh { mesh, ..m.clone() })
            })
            .collect::<Result<Vec<_>>>()?;
        let r = Arc::new(self.full.backend().renderer(RenderScene::new(meshes)?)?);
        lods.push((factor, r.clone()));
        Ok(r)
    }
}

/// The renderer one level uses: a mesh renderer of its detail, or the volume.
pub(super) enum LevelRenderer<'a> {
    Mesh(Arc<ThicknessRenderer>),
    Volume(&'a VolumeOnBackend),
}

impl MovingDrr {
    /// The line-integral DRR of the model at `pose` seen from `view` (full detail).
    pub fn render_at(&self, view: &View, pose: &RigidTransform) -> Result<ImageF32> {
        self.level(1)?.render_at(view, pose)
    }

    pub(super) fn level(&self, detail: u32) -> Result<LevelRenderer<'_>> {
        Ok(match self {
            MovingDrr::Mesh(m) => LevelRenderer::Mesh(m.at_detail(detail)?),
            MovingDrr::Volume(v) => LevelRenderer::Volume(v.as_ref()),
        })
    }
}

impl LevelRenderer<'_> {
    pub(super) fn render_at(&self, view: &View, pose: &RigidTransform) -> Result<ImageF32> {
        let mut out = ImageF32::zeros(0, 0);
        self.render_into(view, pose, &mut out, false)?;
        Ok(out)
    }

    /// Renders into `out`, reusing its buffer;
    /// `summed` takes a mesh renderer's signed-sum path
    /// ([`ThicknessRenderer::render_line_integral_summed_into`]) instead of the paired one.
    pub(super) fn render_into(
        &self,
        view: &View,
        pose: &RigidTransform,
        out: &mut ImageF32,
        summed: bool,
    ) -> Result<()> {
        let moved = seen_from(view, pose);
        match self {
            LevelRenderer::Mesh(r) if summed => {
                r.render_line_integral_summed_into(&moved, out)?;
            }
            LevelRenderer::Mesh(r) => {
                r.render_line_integral_into(&moved, out)?;
            }
            LevelRenderer::Volume(v) => v.render_into(&moved, out)?,
        }
        Ok(())
    }

    /// Whether the signed-sum render of `view` at `pose` is the paired render `paired` (within f32
    /// rounding of the largest value): then the meshes are summed in the loop. It is not when a mesh
    /// intersects itself (see [`ThicknessRenderer::render_line_integral_summed_into`]).
    pub(super) fn sums_like(
        &self,
        view: &View,
        pose: &RigidTransform,
        paired: &ImageF32,
    ) -> Result<bool> {
        if !matches!(self, LevelRenderer::Mesh(_)) {
            return Ok(false);
        }
        let mut summed = ImageF32::zeros(0, 0);
        self.render_into(view, pose, &mut summed, true)?;
        let peak = paired.data.iter().fold(0f32, |m, x| m.max(x.abs()));
        let tol = 1e-5 * peak + 1e-6;
        Ok(summed.data.len() == paired.data.len()
            && summed
                .data
                .iter()
                .zip(&paired.data)
                .all(|(a, b)| (a - b).abs() <= tol))
    }
}

/// `view` seen by the anatomy at `pose` (model → world): the camera moves instead of the anatomy.
pub(super) fn seen_from(view: &View, pose: &RigidTransform) -> View {
    View {
        world_to_camera: view.world_to_camera.compose(pose),
        ..view.clone()
    }
}
