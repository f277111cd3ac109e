//! The pedicle-screw experiment: each planned screw of a target (its clinical points
//! `…pedicle_entry` → `…pedicle_tip`: the phantom's planned trajectories, or a user's landmarks of those
//! names) under every perturbation of the grid, in two ways a surgeon meets a wrong calibration:
//!
//! - **drawn** (`screws.csv`): the screw at its true pose projected through the assumed view against
//!   its true image — an overlay from a tracked pose with the wrong calibration — in px of the detector
//!   and in mm at the screw (divided by the true magnification there);
//! - **navigated** (`screw_navigation.csv`): the target registered from its landmarks in all the study's
//!   views with the assumed views (noise-free, started at the truth: the calibration's bias), and the
//!   planned screw carried by that pose — its tip, entry and axis errors in 3-D — and the tip as that
//!   system draws it on each view (`nav_tip_px` of `screws.csv`).
//!
//! A phantom target also gets its radiographs for the report's screw figure: the monochromatic DRR and
//! the spectral one with the screws in place (`[intensity_registration.spectral]`'s technique), in
//! `references/screws_<target>_<view>_{mono,spectral}.tiff`, the screws' entry and tip points in the
//! spectral image's sidecar.

use std::path::{Path, PathBuf};

use glam::{DVec2, DVec3};
use serde_json::json;

use super::{Context, REFERENCES_DIR, Target};
use crate::Result;
use crate::anatomy::screw::{PlannedScrew, planned_screws};
use crate::geometry::{Perturbation, RigidTransform, View};
use crate::io::{Sidecar, sidecar_path, write_tiff_f32};
use crate::render::{Backend, SpectralRenderer, ThicknessOptions};
use crate::study::config::Family;
use crate::study::schema::{ScrewNavigationRow, ScrewRow, UnitRows};
use crate::study::timings::Phase;

/// The unsigned angle (degrees) between two 2-D directions; NaN when either is shorter than `min`.
fn angle_2d_deg(a: DVec2, b: DVec2, min: f64) -> f64 {
    if a.length() < min || b.length() < min {
        return f64::NAN;
    }
    // atan2 of the cross and dot products: exact near 0°, where an arccosine loses half the digits.
    a.perp_dot(b).abs().atan2(a.dot(b)).to_degrees()
}

/// The landmark registration of `t` observed exactly through `truth` and solved with `assumed` (direct
/// LM from the truth): the pose, residual and convergence; `None` when the solve fails.
fn navigate(t: &Target, truth: &[View], assumed: &[View]) -> Option<(RigidTransform, f64, bool)> {
    super::intensity::landmark_registration(&t.landmarks, truth, assumed)
        .map(|r| (r.pose, r.residual_px, r.converged))
}

/// `references/screws/<target>_<view>_<model>.tiff` (`model`: `mono` or `spectral`).
pub fn screw_image_path(out: &Path, target: &str, view: &str, model: &str) -> PathBuf {
    out.join(REFERENCES_DIR)
        .join("screws")
        .join(format!("{target}_{view}_{model}.tiff"))
}

/// The sidecar key of the spectral screw image's planned screws (`[{name, entry, tip}]`, world mm).
pub const SCREWS_KEY: &str = "planned_screws";

/// Writes the monochromatic DRR and the spectral radiograph with the screws of `t` in each view.
fn write_images(ctx: &Context, t: &Target, screws: &[PlannedScrew], views: &[View]) -> Result<()> {
    let Some(scene) = &t.screw_scene else {
        return Ok(());
    };
    let technique = &ctx.cfg.intensity_registration.spectral;
    let spectral = ctx.timings.time(Phase::Scene, 1, || {
        SpectralRenderer::new(scene, technique.model()?, Backend::Raster)
    })?;
    let planned: Vec<serde_json::Value> = screws
        .iter()
        .map(|s| json!({ "name": s.name, "entry": s.entry.to_array(), "tip": s.tip.to_array() }))
        .collect();
    for view in views {
        let mono = ctx.timings.time(Phase::RenderTarget, 1, || {
            t.renderer.render(view, &ThicknessOptions::image_only())
        })?;
        let radiograph = ctx
            .timings
            .time(Phase::RenderTarget, 1, || spectral.render(view))?;
        for (model, image, units) in [
            (
                "mono",
                &mono.line_integral,
                "line integral ∫μ dl (μ in 1/mm)",
            ),
            (
                "spectral",
                &radiograph.line_integral,
                "−ln(I/I0) of the detected signal",
            ),
        ] {
            let path = screw_image_path(&ctx.out, &t.name, &view.name, model);
            if let Some(dir) = path.parent() {
                std::fs::create_dir_all(dir).map_err(|e| crate::Error::io(dir, e))?;
            }
            write_tiff_f32(&path, image)?;
            let mut side = Sidecar::new("drr", units, view, &Perturbation::NONE)?;
            side.details.insert("target".into(), t.name.clone().into());
            if model == "spectral" {
                side.details
                    .insert("technique".into(), technique.describe().into());
                side.details.insert("spectral".into(), spectral.summary());
                side.details
                    .insert(SCREWS_KEY.into(), planned.clone().into());
            }
            side.write(&sidecar_path(&path))?;
        }
    }
    Ok(())
}

/// Runs every perturbation of the grid for the planned screws of `target` (no rows when it has none).
pub fn run(ctx: &Context, target: &str) -> Result<UnitRows> {
    let t = ctx.target(target)?;
    let screws = planned_screws(&t.clinical);
    let mut rows = UnitRows::default();
    if screws.is_empty() {
        return Ok(rows);
    }
    let truth: Vec<View> = ctx.cfg.studied_views(&ctx.carm).cloned().collect();
    write_images(ctx, t, &screws, &truth)?;
    let views_name = truth
        .iter()
        .map(|v| v.name.as_str())
        .collect::<Vec<_>>()
        .join("+");
    for (family, q) in ctx.cfg.perturbations.cells() {
        let assumed = truth
            .iter()
            .map(|v| v.perturbed(&q))
            .collect::<Result<Vec<View>>>()?;
        let nav = ctx
            .timings
            .time(Phase::Registration, 1, || navigate(t, &truth, &assumed));
        let (df_px, piercing_px) = intrinsic_values(family, &q);
        let perturbation = q.to_string();
        for s in &screws {
            for (tv, av) in truth.iter().zip(&assumed) {
                let px = |p: DVec3| (av.project(p) - tv.project(p)).length();
                let at = |p: DVec3, d: f64| d * tv.depth(p) / tv.intrinsics.fx;
                let true_axis = tv.project(s.tip) - tv.project(s.entry);
                let drawn_axis = av.project(s.tip) - av.project(s.entry);
                let (tip_px, entry_px) = (px(s.tip), px(s.entry));
                let nav_tip_px = nav.as_ref().map_or(f64::NAN, |(pose, _, _)| {
                    (av.project(pose.apply(s.tip)) - tv.project(s.tip)).length()
                });
                rows.screws.push(ScrewRow {
                    target: target.to_string(),
                    screw: s.name.clone(),
                    view: tv.name.clone(),
                    family,
                    perturbation: perturbation.clone(),
                    df_px,
                    piercing_px,
                    length_mm: (s.tip - s.entry).length(),
                    tip_px,
                    tip_mm: at(s.tip, tip_px),
                    entry_px,
                    entry_mm: at(s.entry, entry_px),
                    axis_deg: angle_2d_deg(true_axis, drawn_axis, 1.0),
                    projected_length_px: true_axis.length(),
                    nav_tip_px,
                });
            }
            let (tip_mm, entry_mm, axis_deg, residual_px, converged) = match &nav {
                Some((pose, residual, converged)) => {
                    let axis = (s.tip - s.entry).normalize();
                    let moved = pose.apply_vector(axis).normalize();
                    (
                        (pose.apply(s.tip) - s.tip).length(),
                        (pose.apply(s.entry) - s.entry).length(),
                        axis.dot(moved).clamp(-1.0, 1.0).acos().to_degrees(),
                        *residual,
                        *converged,
                    )
                }
                None => (f64::NAN, f64::NAN, f64::NAN, f64::NAN, false),
            };
            rows.screw_navigation.push(ScrewNavigationRow {
                target: target.to_string(),
                screw: s.name.clone(),
                views: views_name.clone(),
                family,
                perturbation: perturbation.clone(),
                df_px,
                piercing_px,
                tip_mm,
                entry_mm,
                axis_deg,
                residual_px,
                converged,
            });
        }
    }
    Ok(rows)
}

/// The Δf and piercing shift of an intrinsic cell (0 for the other families' keys).
fn intrinsic_values(family: Family, q: &Perturbation) -> (f64, f64) {
    match family {
        Family::Physical => (0.0, 0.0),
        _ => (q.df_px, q.dcx_px),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_2d_angle_is_unsigned_and_undefined_for_a_point() {
        let a = DVec2::new(10.0, 0.0);
        assert!((angle_2d_deg(a, DVec2::new(10.0, 10.0), 1.0) - 45.0).abs() < 1e-12);
        assert!((angle_2d_deg(a, DVec2::new(10.0, -10.0), 1.0) - 45.0).abs() < 1e-12);
        assert!(angle_2d_deg(a, DVec2::new(0.1, 0.0), 1.0).is_nan());
    }
}
