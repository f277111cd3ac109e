//! The tracking experiment: one target registered at two true poses with the same wrong geometry
//! ([`crate::registration::tracking::track`]), noise-free, one row per cell (`tracking.csv`).

use glam::DVec3;

use super::Context;
use crate::Result;
use crate::geometry::{View, rotation_angle_deg};
use crate::registration::tracking::{Start, motion, track};
use crate::study::config::TrackingCell;
use crate::study::schema::{TrackingRow, UnitRows};
use crate::study::timings::Phase;
use crate::study::units::derive_seed;

/// Runs one tracking cell.
pub fn run(ctx: &Context, c: &TrackingCell) -> Result<UnitRows> {
    let t = ctx.target(&c.target)?;
    let views = c
        .method
        .views()
        .iter()
        .map(|n| ctx.carm.view(n).cloned())
        .collect::<Result<Vec<View>>>()?;
    let names: Vec<String> = t.landmarks.iter().map(|(n, _)| n.clone()).collect();
    let points: Vec<DVec3> = t.landmarks.iter().map(|(_, p)| *p).collect();
    let n = points.len().max(1) as f64;
    let centre = points.iter().fold(DVec3::ZERO, |a, &p| a + p) / n;
    let tr = &ctx.cfg.tracking;
    let moved = motion(
        DVec3::from(tr.rotation_deg),
        DVec3::from(tr.translation_mm),
        centre,
    );
    let r = &ctx.cfg.registration;
    let start = Start {
        rot_deg: r.init_rot_deg,
        trans_mm: r.init_trans_mm,
        seed: derive_seed(ctx.cfg.seed, &c.id(), 0),
    };
    let p = c.perturbation;
    let result = ctx.timings.time(Phase::Registration, 2, || {
        track(
            names,
            points,
            &views,
            |v| v.perturbed(&p),
            &moved,
            c.method.solver(),
            start,
        )
    })?;
    let clinical: Vec<DVec3> = t.clinical.iter().map(|(_, p)| *p).collect();
    let (pedicle_abs, pedicle_rel) = result.max_errors_at(&clinical, &moved);
    let mut rows = UnitRows::default();
    rows.tracking.push(TrackingRow {
        target: c.target.clone(),
        method: c.method,
        family: c.family,
        perturbation: p.to_string(),
        motion_mm: DVec3::from(tr.translation_mm).length(),
        motion_deg: rotation_angle_deg(moved.rotation),
        abs_rot_err_deg: result.first.rot_deg,
        abs_trans_err_mm: result.first.trans_mm,
        abs_tre_mm: result.first.tre_mm,
        abs_tre_2_mm: result.second.tre_mm,
        rel_rot_err_deg: result.relative.rot_deg,
        rel_trans_err_mm: result.relative.trans_mm,
        rel_tre_mm: result.relative.tre_mm,
        pedicle_abs_err_max_mm: pedicle_abs,
        pedicle_rel_err_max_mm: pedicle_rel,
        residual_px: result.residual_px,
        converged: result.converged,
    });
    Ok(rows)
}
