//! Registration experiment: landmarks observed through the true cameras (plus optional noise), solved
//! with the assumed ones — the perturbed K of a Δf × piercing cell (`registration.csv`), or the camera a
//! physical cell of `[perturbations.physical]` amounts to, pose and K (`registration_physical.csv`) —
//! from a perturbed initial pose; errors against the true pose (identity: landmarks are in world
//! coordinates).

use glam::DVec3;

use super::{Context, Target};
use crate::Result;
use crate::geometry::{Perturbation, RigidTransform, View};
use crate::registration::{
    RegistrationOptions, RegistrationProblem, add_pixel_noise, model_centroid, perturb_pose,
    pose_errors, register,
};
use crate::study::config::{RegistrationMethod, RegistrationPhysicalCell, physical_cell_key};
use crate::study::schema::{RegistrationPhysicalRow, RegistrationRow, UnitRows};
use crate::study::timings::Phase;
use crate::study::units::{Unit, derive_seed};

/// One trial's outcome: the solved pose (None when the solve failed), its mean residual (px), iterations,
/// and whether it converged to a pose that can be the anatomy.
struct Trial {
    index: usize,
    pose: Option<RigidTransform>,
    residual_px: f64,
    iterations: usize,
    converged: bool,
}

/// Runs trials `first..first + count` of `target` by `method`, the solver seeing each view as
/// `assume(true view)`; the draws of trial i derive from `(seed, key, i)`.
fn trials(
    ctx: &Context,
    t: &Target,
    method: RegistrationMethod,
    assume: impl Fn(&View) -> Result<View>,
    key: &str,
    (first, count): (usize, usize),
) -> Result<Vec<Trial>> {
    let views = method
        .views()
        .iter()
        .map(|n| ctx.carm.view(n).cloned())
        .collect::<Result<Vec<View>>>()?;
    let truth = RigidTransform::IDENTITY;
    let names = t.landmarks.iter().map(|(n, _)| n.clone()).collect();
    let points = t.landmarks.iter().map(|(_, p)| *p).collect();
    let problem = RegistrationProblem::synthesize(names, points, &views, &truth)?;
    let centre = model_centroid(&problem);
    let r = &ctx.cfg.registration;
    let mut out = Vec::with_capacity(count);
    for index in first..first + count {
        let seed = derive_seed(ctx.cfg.seed, key, index as u64);
        let observed = if r.noise_px > 0.0 {
            add_pixel_noise(&problem, r.noise_px, seed)
        } else {
            problem.clone()
        };
        let assumed = observed.with_views(&assume)?;
        let init = perturb_pose(
            &truth,
            r.init_rot_deg,
            r.init_trans_mm,
            centre,
            seed ^ 0x5eed,
        );
        let opts = RegistrationOptions {
            init: Some(init),
            ..RegistrationOptions::default()
        };
        let solved = ctx.timings.time(Phase::Registration, 1, || {
            register(&assumed, method.solver(), &opts)
        });
        out.push(match solved {
            Ok(res) => Trial {
                index,
                pose: Some(res.pose),
                residual_px: res.residual_px,
                iterations: res.iterations,
                // Stopped by its tolerances at a pose that cannot be the anatomy: not converged.
                converged: res.converged && assumed.implausible(&res.pose).is_none(),
            },
            // A failed solve is a measurement too: it shows up as NaN errors, not as a lost study.
            Err(_) => Trial {
                index,
                pose: None,
                residual_px: f64::NAN,
                iterations: 0,
                converged: false,
            },
        });
    }
    Ok(out)
}

/// Runs trials `first..first + count` of one Δf × piercing registration cell.
pub fn run(ctx: &Context, unit: &Unit) -> Result<UnitRows> {
    let Unit::Registration {
        target,
        method,
        df_px,
        piercing_px,
        first,
        count,
    } = unit
    else {
        return Ok(UnitRows::default());
    };
    let t = ctx.target(target)?;
    let pert = Perturbation {
        df_px: *df_px,
        ..Perturbation::piercing(*piercing_px, *piercing_px)
    };
    let assume = |v: &View| {
        Ok(View {
            intrinsics: pert.apply(&v.intrinsics)?,
            ..v.clone()
        })
    };
    let done = trials(ctx, t, *method, assume, &unit.seed_key(), (*first, *count))?;
    let mut rows = UnitRows::default();
    for tr in done {
        let e = tr.pose.map(|p| pose_errors(&p, &RigidTransform::IDENTITY));
        rows.registration.push(RegistrationRow {
            target: target.clone(),
            method: *method,
            df_px: *df_px,
            piercing_px: *piercing_px,
            trial: tr.index,
            rot_err_deg: e.map_or(f64::NAN, |e| e.rot_err_deg),
            trans_err_mm: e.map_or(f64::NAN, |e| e.trans_err_mm),
            residual_px: tr.residual_px,
            iterations: tr.iterations,
            converged: tr.converged,
        });
    }
    Ok(rows)
}

/// The mean and the largest distance (mm) between `points` moved by `pose` and where they are (the
/// truth is the identity); NaN without points.
fn point_errors(pose: &RigidTransform, points: &[DVec3]) -> (f64, f64) {
    if points.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let d: Vec<f64> = points
        .iter()
        .map(|&x| (pose.apply(x) - x).length())
        .collect();
    (
        d.iter().sum::<f64>() / d.len() as f64,
        d.iter().copied().fold(f64::NAN, f64::max),
    )
}

/// Runs trials of one physical registration cell: the solver's cameras are
/// [`View::perturbed`] by the cell (K, pose and all).
pub fn run_physical(ctx: &Context, c: &RegistrationPhysicalCell) -> Result<UnitRows> {
    let t = ctx.target(&c.target)?;
    let p = c.perturbation;
    let (key, value) = physical_cell_key(&p).ok_or_else(|| {
        crate::Error::invalid(
            "perturbations.physical",
            format!("{p} is not one physical key alone"),
        )
    })?;
    let done = trials(
        ctx,
        t,
        c.method,
        |v: &View| v.perturbed(&p),
        &c.seed_key(),
        (c.first, c.count),
    )?;
    let landmarks: Vec<DVec3> = t.landmarks.iter().map(|(_, p)| *p).collect();
    let clinical: Vec<DVec3> = t.clinical.iter().map(|(_, p)| *p).collect();
    let mut rows = UnitRows::default();
    for tr in done {
        let e = tr.pose.map(|p| pose_errors(&p, &RigidTransform::IDENTITY));
        let tre = tr.pose.map_or(f64::NAN, |p| point_errors(&p, &landmarks).0);
        let pedicle = tr.pose.map_or(f64::NAN, |p| point_errors(&p, &clinical).1);
        rows.registration_physical.push(RegistrationPhysicalRow {
            target: c.target.clone(),
            method: c.method,
            key: key.to_string(),
            value,
            trial: tr.index,
            rot_err_deg: e.map_or(f64::NAN, |e| e.rot_err_deg),
            trans_err_mm: e.map_or(f64::NAN, |e| e.trans_err_mm),
            tre_mm: tre,
            pedicle_err_max_mm: pedicle,
            residual_px: tr.residual_px,
            iterations: tr.iterations,
            converged: tr.converged,
        });
    }
    Ok(rows)
}
