//! Registration experiment: landmarks observed through the true K (plus optional noise), solved with the
//! perturbed K from a perturbed initial pose; errors against the true pose (identity: landmarks are in
//! world coordinates).

use super::Context;
use crate::Result;
use crate::geometry::{Perturbation, RigidTransform, View};
use crate::registration::{
    RegistrationOptions, RegistrationProblem, add_pixel_noise, model_centroid, perturb_pose,
    pose_errors, register,
};
use crate::study::schema::{RegistrationRow, UnitRows};
use crate::study::timings::Phase;
use crate::study::units::{Unit, derive_seed};

/// Runs trials `first..first + count` of one registration cell.
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
    let solver = method.solver();
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
    let pert = Perturbation {
        df_px: *df_px,
        ..Perturbation::piercing(*piercing_px, *piercing_px)
    };
    let r = &ctx.cfg.registration;
    let key = unit.seed_key();
    let mut rows = UnitRows::default();
    for trial in *first..first + count {
        let seed = derive_seed(ctx.cfg.seed, &key, trial as u64);
        let observed = if r.noise_px > 0.0 {
            add_pixel_noise(&problem, r.noise_px, seed)
        } else {
            problem.clone()
        };
        let assumed = observed.with_intrinsics(|v| pert.apply(&v.intrinsics))?;
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
        let solved = ctx
            .timings
            .time(Phase::Registration, 1, || register(&assumed, solver, &opts));
        let row = match solved {
            Ok(res) => {
                let e = pose_errors(&res.pose, &truth);
                (
                    e.rot_err_deg,
                    e.trans_err_mm,
                    res.residual_px,
                    res.iterations,
                    // Stopped by its tolerances at a pose that cannot be the anatomy: not converged.
                    res.converged && assumed.implausible(&res.pose).is_none(),
                )
            }
            // A failed solve is a measurement too: it shows up as NaN errors, not as a lost study.
            Err(_) => (f64::NAN, f64::NAN, f64::NAN, 0, false),
        };
        rows.registration.push(RegistrationRow {
            target: target.clone(),
            method: *method,
            df_px: *df_px,
            piercing_px: *piercing_px,
            trial,
            rot_err_deg: row.0,
            trans_err_mm: row.1,
            residual_px: row.2,
            iterations: row.3,
            converged: row.4,
        });
    }
    Ok(rows)
}
