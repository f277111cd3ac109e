//! The physical family of the projection experiment: the whole-object metrics of a focal spot or a
//! detector moved (mm) or rotated (degrees), beside the assumed camera the error amounts to and the
//! exact shift of the target's landmarks on the detector (`physical.csv`).

use glam::DVec2;

use super::Target;
use crate::geometry::{View, rotation_angle_deg};
use crate::study::config::physical_cell_key;
use crate::study::schema::{PhysicalRow, ProjectionRow};
use crate::study::units::NamedPerturbation;
use crate::{Error, Result};

/// The row of one physical cell from its whole-object metrics `whole` (reference `view`, assumed `pv`).
pub fn row(
    t: &Target,
    view: &View,
    pv: &View,
    np: &NamedPerturbation,
    whole: &ProjectionRow,
) -> Result<PhysicalRow> {
    let (key, value) = physical_cell_key(&np.perturbation).ok_or_else(|| {
        Error::Internal(format!(
            "physical cell '{}' does not set exactly one physical key",
            np.perturbation
        ))
    })?;
    let pitch_mm = view.sdd_mm.map_or(f64::NAN, |s| s / view.intrinsics.fx);
    let shifts: Vec<f64> = t
        .landmarks
        .iter()
        .map(|(_, x)| *x)
        .filter(|x| view.depth(*x) > 0.0 && pv.depth(*x) > 0.0)
        .map(|x| (view.project(x), pv.project(x)))
        .filter(|(x, _)| on_detector(view, *x))
        .map(|(x, y)| (y - x).length())
        .collect();
    let mean = if shifts.is_empty() {
        f64::NAN
    } else {
        shifts.iter().sum::<f64>() / shifts.len() as f64
    };
    let max = shifts.iter().copied().fold(f64::NAN, f64::max);
    let k = pv.intrinsics;
    let turned = pv.world_to_camera.rotation * view.world_to_camera.rotation.transpose();
    Ok(PhysicalRow {
        target: t.name.clone(),
        view: view.name.clone(),
        key: key.into(),
        value,
        fx_px: k.fx,
        fy_px: k.fy,
        skew_px: k.skew,
        cx_px: k.cx,
        cy_px: k.cy,
        camera_moved_mm: (pv.source_world() - view.source_world()).length(),
        camera_turned_deg: rotation_angle_deg(turned),
        cut_by_edge: whole.cut_by_edge,
        dice: whole.dice,
        iou: whole.iou,
        chamfer_mean_px: whole.chamfer_mean_px,
        hd95_px: whole.hd95_px,
        ncc: whole.ncc,
        landmarks: shifts.len(),
        landmark_shift_mean_px: mean,
        landmark_shift_max_px: max,
        landmark_shift_mean_mm: mean * pitch_mm,
    })
}

/// Whether pixel `x` lies on `view`'s detector (pixel centres at integers, edges at −0.5).
fn on_detector(view: &View, x: DVec2) -> bool {
    let k = &view.intrinsics;
    x.x >= -0.5
        && x.y >= -0.5
        && x.x <= f64::from(k.width) - 0.5
        && x.y <= f64::from(k.height) - 0.5
}
