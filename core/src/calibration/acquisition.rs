//! Simulated acquisition of a calibration: each BB's image position in each placement, either its
//! projection through the true geometry (`View::project`) or the blob centroid of a rendered BB sphere
//! (the thickness renderer, measured as the study measures its landmark markers), then seeded Gaussian
//! detection noise.

use std::sync::Arc;

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

use super::phantom::{CalibrationPhantom, Placement};
use crate::analysis::marker_centroid;
use crate::anatomy::TriMesh;
use crate::geometry::{CArm, RigidTransform, View};
use crate::registration::SplitMix64;
use crate::render::{Backend, RenderScene, SceneMesh};
use crate::{Error, Result};

/// How a BB's image position is measured before noise is added.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "lowercase")]
pub enum Detection {
    /// The exact projection of the BB centre.
    Projected,
    /// The blob centroid of a rendered sphere of `radius_mm` (raster thickness renderer).
    Rendered { radius_mm: f64 },
}

/// One calibration image: the phantom placed in front of one view, and its BBs' image positions.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationImage {
    pub view: String,
    /// The true phantom → camera transform of this image.
    pub phantom_to_camera: RigidTransform,
    /// The phantom → world placement.
    pub phantom_to_world: RigidTransform,
    /// `(BB index, pixel)` of every BB used by the calibration.
    pub observed: Vec<(usize, DVec2)>,
}

/// The view through which the phantom frame is seen in one image (phantom frame as the world).
pub fn phantom_view(carm: &CArm, p: &Placement) -> Result<View> {
    let v = carm.view(&p.view)?;
    Ok(View::new(
        v.name.clone(),
        v.intrinsics,
        v.world_to_camera.compose(&p.phantom_to_world),
    ))
}

/// Checks that the BB projects in front of the source and onto the detector (pixel centres at
/// integers, so the detector spans `[−0.5, width − 0.5]`).
pub fn check_on_detector(view: &View, bb: DVec3, what: &str) -> Result<DVec2> {
    let k = view.intrinsics;
    let x = view.project(bb);
    let on = view.depth(bb) > 0.0
        && x.x >= -0.5
        && x.y >= -0.5
        && x.x <= f64::from(k.width) - 0.5
        && x.y <= f64::from(k.height) - 0.5;
    if !on {
        return Err(Error::invalid(
            what,
            format!(
                "projects to ({:.1}, {:.1}) px in view '{}', off the {}×{} detector: move or shrink \
                 the phantom",
                x.x, x.y, view.name, k.width, k.height
            ),
        ));
    }
    Ok(x)
}

/// The noise-free image positions of `bbs` (phantom indices) in every placement.
pub fn ideal_images(
    carm: &CArm,
    phantom: &CalibrationPhantom,
    placements: &[Placement],
    bbs: &[usize],
    detection: Detection,
) -> Result<Vec<CalibrationImage>> {
    let pts = phantom.points();
    let renderer = match detection {
        Detection::Projected => None,
        Detection::Rendered { radius_mm } => {
            if !(radius_mm.is_finite() && radius_mm > 0.0) {
                return Err(Error::invalid(
                    "bb_radius_mm",
                    format!("must be positive, got {radius_mm}"),
                ));
            }
            Some(radius_mm)
        }
    };
    placements
        .iter()
        .enumerate()
        .map(|(j, p)| {
            let view = phantom_view(carm, p)?;
            let mut observed = Vec::with_capacity(bbs.len());
            for &i in bbs {
                let what = format!("phantom '{}' BB {i} (image {j})", phantom.name);
                let x = check_on_detector(&view, pts[i], &what)?;
                let x = match renderer {
                    None => x,
                    Some(r) => rendered_centroid(&view, pts[i], r)?.ok_or_else(|| {
                        Error::invalid(what, "its rendered blob is cut by the detector edge")
                    })?,
                };
                observed.push((i, x));
            }
            Ok(CalibrationImage {
                view: p.view.clone(),
                phantom_to_camera: view.world_to_camera,
                phantom_to_world: p.phantom_to_world,
                observed,
            })
        })
        .collect()
}

/// The centroid of one BB sphere rendered alone (raster backend).
fn rendered_centroid(view: &View, centre: DVec3, radius_mm: f64) -> Result<Option<DVec2>> {
    let sphere = TriMesh::icosphere("bb", centre, radius_mm, 3);
    let scene = RenderScene::new(vec![SceneMesh {
        mesh: Arc::new(sphere),
        mu_per_mm: 1.0,
        object: "bb".into(),
    }])?;
    let renderer = Backend::Raster.renderer(scene)?;
    marker_centroid(&renderer, view, centre, radius_mm)
}

/// `images` with independent Gaussian noise of `sigma_px` on both coordinates of every BB, drawn from
/// `seed` in image and BB order.
pub fn with_noise(images: &[CalibrationImage], sigma_px: f64, seed: u64) -> Vec<CalibrationImage> {
    let mut rng = SplitMix64::new(seed);
    images
        .iter()
        .map(|im| CalibrationImage {
            observed: im
                .observed
                .iter()
                .map(|&(i, x)| (i, x + DVec2::new(rng.normal(), rng.normal()) * sigma_px))
                .collect(),
            ..im.clone()
        })
        .collect()
}

/// Checks a detection noise σ (px): finite and ≥ 0.
pub fn check_sigma(sigma_px: f64) -> Result<()> {
    if sigma_px.is_finite() && sigma_px >= 0.0 {
        Ok(())
    } else {
        Err(Error::invalid(
            "noise-px",
            format!("the detection noise σ must be a finite number ≥ 0 px, got {sigma_px}"),
        ))
    }
}
