//! [`Context::check_on_detector`]: every projection cell must put some of its target on the detector,
//! checked for the whole grid before the first unit (an empty silhouette would otherwise abort the
//! study in the middle, at that cell).

use super::{Context, Target};
use crate::geometry::View;
use crate::study::config::Experiment;
use crate::study::schema::Family;
use crate::study::units::projection_perturbations;
use crate::{Error, Result};

impl Context {
    /// Checks that in every view and under every perturbation of the grid, some vertex of every target
    /// lies in front of the source and projects inside the detector; the error names the target, the
    /// view, the perturbation and its config key, and where the target lands.
    pub fn check_on_detector(&self) -> Result<()> {
        if !(self.cfg.runs(Experiment::Projection) || self.cfg.runs(Experiment::Landmarks)) {
            return Ok(());
        }
        let perturbations = projection_perturbations(&self.cfg);
        for t in &self.targets {
            for name in &self.cfg.geometry.views {
                let view = self.carm.view(name)?;
                for np in &perturbations {
                    let pv = view.perturbed(&np.perturbation)?;
                    if !lands_on_detector(t, &pv) {
                        return Err(Error::invalid(
                            family_keys(np.family),
                            format!(
                                "target '{}' is not on the detector in view '{}' under perturbation \
                                 {} (family {}): {}",
                                t.name,
                                name,
                                np.perturbation,
                                np.family,
                                where_it_lands(t, &pv)
                            ),
                        ));
                    }
                }
            }
        }
        Ok(())
    }
}

fn vertices(t: &Target) -> impl Iterator<Item = glam::DVec3> + '_ {
    t.renderer
        .scene()
        .meshes
        .iter()
        .flat_map(|m| m.mesh.vertices.iter().copied())
}

/// Whether some vertex of `t` is in front of the source and projects inside the detector of `view`.
fn lands_on_detector(t: &Target, view: &View) -> bool {
    let k = &view.intrinsics;
    let (w, h) = (f64::from(k.width) - 0.5, f64::from(k.height) - 0.5);
    vertices(t).any(|p| {
        if view.depth(p) <= 0.0 {
            return false;
        }
        let q = view.project(p);
        (-0.5..=w).contains(&q.x) && (-0.5..=h).contains(&q.y)
    })
}

/// The pixel range the target's vertices in front of the source project to, against the detector size.
fn where_it_lands(t: &Target, view: &View) -> String {
    let (mut lo, mut hi) = (glam::DVec2::INFINITY, glam::DVec2::NEG_INFINITY);
    for p in vertices(t).filter(|&p| view.depth(p) > 0.0) {
        let q = view.project(p);
        lo = lo.min(q);
        hi = hi.max(q);
    }
    let k = &view.intrinsics;
    if lo.x > hi.x {
        return "it lies behind the source".into();
    }
    format!(
        "it projects to u ∈ [{:.1}, {:.1}], v ∈ [{:.1}, {:.1}] px, the detector is {} × {} px",
        lo.x, hi.x, lo.y, hi.y, k.width, k.height
    )
}

/// The config keys a perturbation family's values come from.
fn family_keys(f: Family) -> &'static str {
    match f {
        Family::Focal => "perturbations.df_px",
        Family::Piercing => "perturbations.piercing_px",
        Family::Joint => "perturbations.df_px / perturbations.piercing_px",
        Family::Skew => "perturbations.skew_px",
        Family::Scale => "perturbations.pixel_scale",
    }
}
