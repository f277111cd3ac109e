//! Relative (tracking) error: the same target registered at two true poses with the same wrong
//! geometry, and the error of the estimated relative motion beside the absolute errors.
//!
//! The relative pose of pose 2 in the frame of pose 1 is `Δ = T₁⁻¹ T₂`. A calibration error that is a
//! rigid motion `C` of the whole C-arm makes every estimate `Ť = C T` (exactly, noise-free), so
//! `Δ̌ = Ť₁⁻¹ Ť₂ = T₁⁻¹ C⁻¹ C T₂ = Δ`: it cancels from the relative pose while the absolute errors are
//! the size of `C` — the point of Jain et al. (MICCAI 2005). Other errors cancel in part.

use glam::DVec3;

use super::{
    Method, RegistrationOptions, RegistrationProblem, perturb_pose, pose_errors, register,
};
use crate::Result;
use crate::geometry::{RigidTransform, View, rotation_exp};

/// The target's motion between the two poses: a rotation by `rotation_deg` (axis-angle vector,
/// degrees, world axes) about `centre`, then a translation by `translation_mm` (world).
pub fn motion(rotation_deg: DVec3, translation_mm: DVec3, centre: DVec3) -> RigidTransform {
    let r = rotation_exp(rotation_deg * std::f64::consts::PI / 180.0);
    RigidTransform::new(r, centre - r * centre + translation_mm)
}

/// Rotation (degrees), translation (mm) and target registration error (mean over the landmarks, mm)
/// of an estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Errors {
    pub rot_deg: f64,
    pub trans_mm: f64,
    pub tre_mm: f64,
}

impl Errors {
    fn of(estimate: &RigidTransform, truth: &RigidTransform, points: &[DVec3]) -> Errors {
        let e = pose_errors(estimate, truth);
        let n = points.len().max(1) as f64;
        let tre = points
            .iter()
            .map(|&x| (estimate.apply(x) - truth.apply(x)).length())
            .sum::<f64>()
            / n;
        Errors {
            rot_deg: e.rot_err_deg,
            trans_mm: e.trans_err_mm,
            tre_mm: tre,
        }
    }

    const NAN: Errors = Errors {
        rot_deg: f64::NAN,
        trans_mm: f64::NAN,
        tre_mm: f64::NAN,
    };
}

/// The absolute errors at each pose and the error of the relative pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tracking {
    pub first: Errors,
    pub second: Errors,
    pub relative: Errors,
    /// The larger mean reprojection residual of the two solves (px).
    pub residual_px: f64,
    /// Both solves stopped by their tolerances at poses that can be the anatomy.
    pub converged: bool,
    /// The estimated poses (None where a solve failed), for errors at other points.
    pub estimates: [Option<RigidTransform>; 2],
}

impl Tracking {
    /// The largest absolute error (mm) at `points` at pose 1, and the largest error of the relative pose
    /// there (its estimate against `moved`); NaN where a solve failed or there is no point.
    pub fn max_errors_at(&self, points: &[DVec3], moved: &RigidTransform) -> (f64, f64) {
        let worst = |est: &RigidTransform, truth: &RigidTransform| {
            points
                .iter()
                .map(|&x| (est.apply(x) - truth.apply(x)).length())
                .fold(f64::NAN, f64::max)
        };
        let abs = self.estimates[0].map_or(f64::NAN, |e| worst(&e, &RigidTransform::IDENTITY));
        let rel = match self.estimates {
            [Some(a), Some(b)] => worst(&a.inverse().compose(&b), moved),
            _ => f64::NAN,
        };
        (abs, rel)
    }
}

/// How each registration starts: the truth turned by `rot_deg` about a random axis through the
/// landmarks' centroid and moved `trans_mm` in a random direction, drawn from `seed`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Start {
    pub rot_deg: f64,
    pub trans_mm: f64,
    pub seed: u64,
}

/// Registers the landmarks `points` (model = world at pose 1, the identity) observed through the true
/// `views` at pose 1 and at pose `moved`, each with the assumed cameras `assume(view)`, by `solver`.
/// Noise-free: the errors are the geometry's alone. A solve that fails gives NaN errors and
/// `converged = false`.
pub fn track(
    names: Vec<String>,
    points: Vec<DVec3>,
    views: &[View],
    assume: impl Fn(&View) -> Result<View>,
    moved: &RigidTransform,
    solver: Method,
    start: Start,
) -> Result<Tracking> {
    let truths = [RigidTransform::IDENTITY, *moved];
    let mut estimates = Vec::with_capacity(2);
    let mut residual = f64::NAN;
    let mut converged = true;
    for (i, truth) in truths.iter().enumerate() {
        let observed =
            RegistrationProblem::synthesize(names.clone(), points.clone(), views, truth)?;
        let assumed = observed.with_views(&assume)?;
        let centre = truth.apply(super::model_centroid(&observed));
        let init = perturb_pose(
            truth,
            start.rot_deg,
            start.trans_mm,
            centre,
            start.seed ^ (i as u64 + 1),
        );
        let opts = RegistrationOptions {
            init: Some(init),
            ..RegistrationOptions::default()
        };
        match register(&assumed, solver, &opts) {
            Ok(res) => {
                converged &= res.converged && assumed.implausible(&res.pose).is_none();
                residual = residual.max(res.residual_px);
                estimates.push(Some(res.pose));
            }
            Err(_) => {
                converged = false;
                estimates.push(None);
            }
        }
    }
    let of = |e: Option<&RigidTransform>, t: &RigidTransform| {
        e.map_or(Errors::NAN, |e| Errors::of(e, t, &points))
    };
    let relative = match (estimates[0], estimates[1]) {
        (Some(a), Some(b)) => Errors::of(&a.inverse().compose(&b), moved, &points),
        _ => Errors::NAN,
    };
    Ok(Tracking {
        first: of(estimates[0].as_ref(), &truths[0]),
        second: of(estimates[1].as_ref(), &truths[1]),
        relative,
        residual_px: residual,
        converged,
        estimates: [estimates[0], estimates[1]],
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{CArm, Perturbation};

    fn landmarks() -> (Vec<String>, Vec<DVec3>) {
        // A vertebra-sized cloud of landmarks around the world origin (where both views aim).
        let points = vec![
            DVec3::new(-20.0, -15.0, -12.0),
            DVec3::new(22.0, -10.0, 10.0),
            DVec3::new(-18.0, 25.0, 14.0),
            DVec3::new(15.0, 30.0, -16.0),
            DVec3::new(0.0, -35.0, 0.0),
            DVec3::new(3.0, 5.0, 20.0),
            DVec3::new(-5.0, 10.0, -22.0),
        ];
        let names = (0..points.len()).map(|i| format!("p{i}")).collect();
        (names, points)
    }

    const START: Start = Start {
        rot_deg: 2.0,
        trans_mm: 2.0,
        seed: 7,
    };

    #[test]
    fn a_rigid_error_of_the_whole_c_arm_cancels_from_the_relative_pose() {
        let carm = CArm::default_paper();
        let (names, points) = landmarks();
        // Focal spot and detector of every view moved together by one world vector: the whole C-arm
        // translated, K unchanged. (The keys are in each view's camera axes, so the vector is
        // expressed in each view's axes.)
        let w = DVec3::new(6.0, -4.0, 9.0);
        let shift = |v: &View| {
            let d = v.world_to_camera.rotation * w;
            v.perturbed(&Perturbation {
                src_dx_mm: d.x,
                src_dy_mm: d.y,
                src_dz_mm: d.z,
                det_dx_mm: d.x,
                det_dy_mm: d.y,
                det_dz_mm: d.z,
                ..Perturbation::NONE
            })
        };
        let m = motion(
            DVec3::new(0.0, 0.0, 5.0),
            DVec3::new(10.0, 0.0, 0.0),
            DVec3::ZERO,
        );
        for views in [vec!["ap"], vec!["ap", "lat"]] {
            let vs: Vec<View> = views
                .iter()
                .map(|n| carm.view(n).unwrap().clone())
                .collect();
            let t = track(
                names.clone(),
                points.clone(),
                &vs,
                shift,
                &m,
                Method::Direct,
                START,
            )
            .unwrap();
            assert!(t.converged, "{views:?}: {t:?}");
            // Absolute: the C-arm moved by |(6, −4, 9)| = 11.5 mm relative to the anatomy.
            assert!((t.first.tre_mm - w.length()).abs() < 1e-6, "{t:?}");
            assert!(
                t.relative.tre_mm < 1e-6 && t.relative.rot_deg < 1e-6,
                "{views:?}: {t:?}"
            );
        }
    }

    #[test]
    fn a_focal_scale_in_one_view_scales_a_motion_along_the_central_ray() {
        // One view cannot tell the focal length from depth: with fx' = α fx the target is placed at α
        // times its depth, so a motion d along the central ray is estimated as α d, an error (α − 1) d.
        let carm = CArm::default_paper();
        let ap = carm.view("ap").unwrap().clone();
        let (names, points) = landmarks();
        let alpha = 1.05;
        let d = 10.0;
        // The AP central ray is world +y.
        let m = motion(DVec3::ZERO, DVec3::new(0.0, d, 0.0), DVec3::ZERO);
        let p = Perturbation {
            alpha_f: alpha,
            ..Perturbation::NONE
        };
        let t = track(
            names,
            points,
            std::slice::from_ref(&ap),
            |v| v.perturbed(&p),
            &m,
            Method::Direct,
            START,
        )
        .unwrap();
        assert!(t.converged, "{t:?}");
        let expected = (alpha - 1.0) * d;
        assert!(
            (t.relative.trans_mm - expected).abs() < 0.02 * expected,
            "relative {} mm, analytic {expected} mm",
            t.relative.trans_mm
        );
        // The absolute error is that of the whole depth, (α − 1) × 1000 mm: far larger.
        assert!(t.first.trans_mm > 20.0 * t.relative.trans_mm, "{t:?}");
    }
}
