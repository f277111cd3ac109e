//! [`Context::check_on_detector`]: every projection cell must put some of its target on the detector,
//! checked for the whole grid before the first unit (an empty silhouette would otherwise abort the
//! study in the middle, at that cell).

use glam::DVec3;

use super::{Context, Target};
use crate::geometry::View;
use crate::study::config::Experiment;
use crate::study::units::projection_perturbations;
use crate::{Error, Result};

impl Context {
    /// Checks that in every view and under every perturbation of the grid, some vertex of every target
    /// lies in front of the source and projects inside the detector; the error names the target, the
    /// view, the perturbation and its config key, and where the target lands.
    pub fn check_on_detector(&self) -> Result<()> {
        if self.cfg.runs(Experiment::Landmarks) || self.cfg.runs(Experiment::Registration) {
            self.check_landmarks_in_view()?;
        }
        if !(self.cfg.runs(Experiment::Projection) || self.cfg.runs(Experiment::Landmarks)) {
            return Ok(());
        }
        let perturbations = projection_perturbations(&self.cfg);
        for t in &self.targets {
            for name in &self.cfg.geometry.views {
                let view = self.carm.view(name)?;
                for np in &perturbations {
                    let pv = view.perturbed(&np.perturbation)?;
                    if !lands_on_detector(vertices(t), &pv) {
                        return Err(Error::invalid(
                            np.family.config_keys(),
                            format!(
                                "target '{}' is not on the detector in view '{}' under perturbation \
                                 {} (family {}): its vertices {}",
                                t.name,
                                name,
                                np.perturbation,
                                np.family,
                                where_it_lands(vertices(t), &pv)
                            ),
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    /// Checks every target's landmarks: each within reach of its anatomy (the bounding box's diagonal,
    /// at least 100 mm), none at or behind a view's source (it has no projection), and in each reference
    /// view some projecting onto the detector — else the target's landmark rows would be NaN. The error
    /// names the target, the view and the landmarks, and points at the usual cause, a landmarks file in
    /// another frame or unit than the anatomy.
    fn check_landmarks_in_view(&self) -> Result<()> {
        const CAUSE: &str = "are the landmarks in the anatomy's frame and unit (world mm, RAS+)?";
        for t in self.targets.iter().filter(|t| !t.landmarks.is_empty()) {
            let (lo, hi) = vertices(t).fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(a, b), p| {
                (a.min(p), b.max(p))
            });
            // A landmark belongs to its anatomy: within the box's diagonal (at least 100 mm) of it.
            let reach = (hi - lo).length().max(100.0);
            for (l, p) in t.landmarks.iter().filter(|_| lo.cmple(hi).all()) {
                let away = (p.clamp(lo, hi) - *p).length();
                if away > reach {
                    return Err(Error::invalid(
                        "landmarks",
                        format!(
                            "target '{}': landmark '{l}' at ({:.1}, {:.1}, {:.1}) mm lies {away:.0} mm \
                             from the target's bounding box ([{:.1}, {:.1}, {:.1}] to [{:.1}, {:.1}, {:.1}] \
                             mm; at most {reach:.0} mm, its diagonal or 100 mm, is accepted); {CAUSE}",
                            t.name, p.x, p.y, p.z, lo.x, lo.y, lo.z, hi.x, hi.y, hi.z
                        ),
                    ));
                }
            }
            for name in &self.cfg.geometry.views {
                let view = self.carm.view(name)?;
                if let Some((l, p)) = t.landmarks.iter().find(|(_, p)| view.depth(*p) <= 0.0) {
                    return Err(Error::invalid(
                        "landmarks",
                        format!(
                            "target '{}': landmark '{l}' at ({:.1}, {:.1}, {:.1}) mm lies at or behind the \
                             source of view '{name}' (depth {:.1} mm): it cannot be projected; {CAUSE}",
                            t.name,
                            p.x,
                            p.y,
                            p.z,
                            view.depth(*p)
                        ),
                    ));
                }
                let points = || t.landmarks.iter().map(|(_, p)| *p);
                if !lands_on_detector(points(), view) {
                    return Err(Error::invalid(
                        "landmarks",
                        format!(
                            "target '{}': none of its {} landmarks projects onto the detector of view \
                             '{name}' (they {}), so every landmark measurement would be NaN; {CAUSE}",
                            t.name,
                            t.landmarks.len(),
                            where_it_lands(points(), view)
                        ),
                    ));
                }
            }
        }
        Ok(())
    }
}

fn vertices(t: &Target) -> impl Iterator<Item = DVec3> + '_ {
    t.renderer
        .scene()
        .meshes
        .iter()
        .flat_map(|m| m.mesh.vertices.iter().copied())
}

/// Whether some of the world `points` is in front of the source and projects inside the detector of
/// `view`.
fn lands_on_detector(mut points: impl Iterator<Item = DVec3>, view: &View) -> bool {
    let k = &view.intrinsics;
    let (w, h) = (f64::from(k.width) - 0.5, f64::from(k.height) - 0.5);
    points.any(|p| {
        if view.depth(p) <= 0.0 {
            return false;
        }
        let q = view.project(p);
        (-0.5..=w).contains(&q.x) && (-0.5..=h).contains(&q.y)
    })
}

/// The pixel range the world `points` in front of the source project to, against the detector size, as
/// a predicate ("project to …" or "lie behind the source").
fn where_it_lands(points: impl Iterator<Item = DVec3>, view: &View) -> String {
    let (mut lo, mut hi) = (glam::DVec2::INFINITY, glam::DVec2::NEG_INFINITY);
    for p in points.filter(|&p| view.depth(p) > 0.0) {
        let q = view.project(p);
        lo = lo.min(q);
        hi = hi.max(q);
    }
    let k = &view.intrinsics;
    if lo.x > hi.x {
        return "lie behind the source".into();
    }
    format!(
        "project to u ∈ [{:.1}, {:.1}], v ∈ [{:.1}, {:.1}] px, the detector is {} × {} px",
        lo.x, hi.x, lo.y, hi.y, k.width, k.height
    )
}
