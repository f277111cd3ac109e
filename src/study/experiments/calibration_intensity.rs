//! The calibration experiment's intensity-based registration: the target's DRRs through the **true**
//! views are the fixed images (noise-free, the target alone), and the pose is registered from the true
//! pose with DRRs through the **estimated** geometry (AP + LAT summed NCC, Levenberg–Marquardt on a
//! two-level pyramid, no global stage: the question is the bias a calibration error leaves, not the
//! capture range). Its mTRE is measured on the target's surface points, as the landmark registration's
//! is.
//!
//! Both images are rendered on the registration's finest grid (the study's detector binned to about
//! [`FINEST_WIDTH_PX`] wide, K scaled with it), one ray per pixel centre, so that at the true K the
//! fixed and the moving DRR are sampled alike and the optimum is exactly the true pose (the finest level
//! is that grid itself, so the library neither bins nor subsamples it).

use std::sync::Arc;

use glam::DVec3;

use super::Target;
use crate::Result;
use crate::geometry::{CArm, RigidTransform, View};
use crate::registration::intensity::{
    IntensityOptions, IntensityProblem, IntensityView, MAX_TARGET_POINTS, MeshDrr, MovingDrr,
    binned_view, mtre_mm, register_intensity, subsample,
};
use crate::registration::pose_errors;

/// The finest pyramid level is about this many pixels wide.
const FINEST_WIDTH_PX: u32 = 512;

/// The binning of the study's detector of `width` px that gives the registration's finest grid (about
/// [`FINEST_WIDTH_PX`] wide; 1024 px: 2).
pub fn finest_bin(width: u32) -> u32 {
    (width / FINEST_WIDTH_PX).max(1)
}

/// The pyramid, relative to the finest grid: half of it, then itself.
const LEVELS: [u32; 2] = [2, 1];

/// The target's surface points (every mesh's vertices, subsampled): where registration error is
/// measured.
pub fn surface_targets(t: &Target) -> Vec<DVec3> {
    let all: Vec<DVec3> = t
        .renderer
        .scene()
        .meshes
        .iter()
        .flat_map(|m| m.mesh.vertices.iter().copied())
        .collect();
    subsample(&all, MAX_TARGET_POINTS)
}

/// The moving DRR and the fixed images of one target, built once per work unit: an intensity problem
/// whose views are swapped for each estimated geometry.
pub struct IntensityBench {
    /// The study detector's binning to the finest grid.
    bin: u32,
    problem: IntensityProblem,
}

/// Registration error of one geometry: (mTRE mm, rotation error deg, translation error mm).
pub type IntensityError = (f64, f64, f64);

impl IntensityBench {
    /// The target's moving DRR (its CT volume when it has one, else its meshes) and its fixed images
    /// through every true view of `carm`; the mTRE is measured on `targets` (model frame = world: the
    /// true pose is the identity).
    pub fn new(t: &Target, carm: &CArm, targets: Vec<DVec3>) -> Result<Self> {
        let bin = finest_bin(carm.views.first().map_or(1, |v| v.intrinsics.width));
        let moving = match &t.volume {
            // The target's volume renderer, on the study's backend (shared, not copied).
            Some(v) => MovingDrr::Volume(Arc::clone(v)),
            // The target's renderer's backend (the study's).
            None => MovingDrr::Mesh(MeshDrr::new(
                t.renderer.backend().renderer(t.renderer.scene().clone())?,
            )),
        };
        let views = carm
            .views
            .iter()
            .map(|v| {
                let view = binned_view(v, bin)?;
                let fixed = moving.render_at(&view, &RigidTransform::IDENTITY)?;
                Ok(IntensityView { view, fixed })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(IntensityBench {
            bin,
            problem: IntensityProblem {
                moving,
                views,
                targets,
            },
        })
    }

    /// Registers with `views` (the estimated geometry, one per true view, in the same order); NaN when
    /// the solve fails.
    pub fn register(&mut self, views: &[View]) -> IntensityError {
        for (iv, v) in self.problem.views.iter_mut().zip(views) {
            match binned_view(v, self.bin) {
                Ok(b) => iv.view = b,
                Err(_) => return (f64::NAN, f64::NAN, f64::NAN),
            }
        }
        let opts = IntensityOptions {
            levels: LEVELS.to_vec(),
            global: false,
            supersample: Some(1),
            ..IntensityOptions::default()
        };
        match register_intensity(&self.problem, &RigidTransform::IDENTITY, &opts) {
            Ok(r) => {
                let e = pose_errors(&r.pose, &RigidTransform::IDENTITY);
                (
                    mtre_mm(&r.pose, &RigidTransform::IDENTITY, &self.problem.targets),
                    e.rot_err_deg,
                    e.trans_err_mm,
                )
            }
            Err(_) => (f64::NAN, f64::NAN, f64::NAN),
        }
    }
}
