//! The registration problem: model landmarks, the views that observe them, and its JSON file format.
//!
//! File layout (`spinedrr register --problem P.json`):
//! `{"landmarks_3d": {"name": [x, y, z], …}, "views": [{"name": "ap", "K": [[…]], "world_to_camera": [[…]],
//! "observed": {"name": [u, v], …}}, …], "init": {"R": [[…]], "t": […]}, "truth": {"R": [[…]], "t": […]}}`.
//! `init` and `truth` are optional; `R`, `t` map model coordinates to world. Views may also carry
//! `width` and `height` (pixels); they default to a detector centred on the principal point.

use std::collections::BTreeMap;

use glam::{DVec2, DVec3};
use serde::Deserialize;

use crate::anatomy::landmarks::unique_keys;
use crate::geometry::{Intrinsics, RigidTransform, View};
use crate::math::symmetric_eigen;
use crate::{Error, Result};

/// One view's observations: `(landmark index, observed pixel)` pairs.
#[derive(Debug, Clone, PartialEq)]
pub struct ObservedView {
    /// The view with the *assumed* intrinsics the solver projects with.
    pub view: View,
    pub observed: Vec<(usize, DVec2)>,
}

/// Model landmarks (model frame, mm) and their observations in one or more views.
#[derive(Debug, Clone, PartialEq)]
pub struct RegistrationProblem {
    pub names: Vec<String>,
    pub model_points: Vec<DVec3>,
    pub views: Vec<ObservedView>,
}

/// A problem read from a file, with its optional initial and true poses.
#[derive(Debug, Clone)]
pub struct LoadedProblem {
    pub problem: RegistrationProblem,
    pub init: Option<RigidTransform>,
    pub truth: Option<RigidTransform>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PoseJson {
    #[serde(rename = "R")]
    r: [[f64; 3]; 3],
    t: [f64; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ViewJson {
    name: String,
    #[serde(rename = "K")]
    k: [[f64; 3]; 3],
    world_to_camera: [[f64; 4]; 4],
    #[serde(deserialize_with = "unique_keys")]
    observed: BTreeMap<String, [f64; 2]>,
    #[serde(default)]
    width: Option<u32>,
    #[serde(default)]
    height: Option<u32>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ProblemJson {
    #[serde(deserialize_with = "unique_keys")]
    landmarks_3d: BTreeMap<String, [f64; 3]>,
    views: Vec<ViewJson>,
    #[serde(default)]
    init: Option<PoseJson>,
    #[serde(default)]
    truth: Option<PoseJson>,
}

impl RegistrationProblem {
    /// Builds and validates a problem (see [`RegistrationProblem::validate`]).
    pub fn new(
        names: Vec<String>,
        model_points: Vec<DVec3>,
        views: Vec<ObservedView>,
    ) -> Result<Self> {
        let p = RegistrationProblem {
            names,
            model_points,
            views,
        };
        p.validate()?;
        Ok(p)
    }

    /// Noise-free observations of `model_points` at pose `truth` (model → world) in each view.
    pub fn synthesize(
        names: Vec<String>,
        model_points: Vec<DVec3>,
        views: &[View],
        truth: &RigidTransform,
    ) -> Result<Self> {
        let views = views
            .iter()
            .map(|v| ObservedView {
                view: v.clone(),
                observed: model_points
                    .iter()
                    .enumerate()
                    .map(|(i, &x)| (i, v.project(truth.apply(x))))
                    .collect(),
            })
            .collect();
        Self::new(names, model_points, views)
    }

    /// The same observations with every view's intrinsics replaced (the solver's *assumed* K).
    pub fn with_intrinsics(&self, k: impl Fn(&View) -> Result<Intrinsics>) -> Result<Self> {
        let mut out = self.clone();
        for ov in &mut out.views {
            ov.view.intrinsics = k(&ov.view)?;
        }
        Ok(out)
    }

    /// The same observations with every view replaced (the solver's *assumed* camera: a physical
    /// perturbation changes the pose as well as K).
    pub fn with_views(&self, f: impl Fn(&View) -> Result<View>) -> Result<Self> {
        let mut out = self.clone();
        for ov in &mut out.views {
            ov.view = f(&ov.view)?;
        }
        Ok(out)
    }

    /// Only the named views (in the given order).
    pub fn select_views(&self, names: &[String]) -> Result<Self> {
        let mut out = self.clone();
        out.views = names
            .iter()
            .map(|n| {
                self.views
                    .iter()
                    .find(|v| &v.view.name == n)
                    .cloned()
                    .ok_or_else(|| Error::invalid("view", format!("the problem has no view '{n}'")))
            })
            .collect::<Result<_>>()?;
        out.validate()?;
        Ok(out)
    }

    /// Total number of 2D observations.
    pub fn observation_count(&self) -> usize {
        self.views.iter().map(|v| v.observed.len()).sum()
    }

    /// Indices of the landmarks observed in at least two views.
    pub fn multi_view_landmarks(&self) -> Vec<usize> {
        // Views that observe each landmark (a view listing a landmark twice counts once).
        let n = self.model_points.len();
        let (mut views_seeing, mut last_view) = (vec![0usize; n], vec![usize::MAX; n]);
        for (vi, v) in self.views.iter().enumerate() {
            for &(j, _) in &v.observed {
                if j < n && last_view[j] != vi {
                    last_view[j] = vi;
                    views_seeing[j] += 1;
                }
            }
        }
        (0..n).filter(|&i| views_seeing[i] >= 2).collect()
    }

    /// Checks sizes, finiteness, landmark indices, the minimum landmark count (4 for one view, 3 seen in
    /// two views otherwise) and that the observed landmarks are not collinear.
    pub fn validate(&self) -> Result<()> {
        if self.names.len() != self.model_points.len() {
            return Err(Error::invalid(
                "landmarks_3d",
                "names and points differ in number",
            ));
        }
        for (n, p) in self.names.iter().zip(&self.model_points) {
            if !p.is_finite() {
                return Err(Error::invalid(
                    format!("landmarks_3d.{n}"),
                    "must be finite",
                ));
            }
        }
        if self.views.is_empty() {
            return Err(Error::invalid("views", "the problem has no view"));
        }
        let mut first_of: BTreeMap<&str, usize> = BTreeMap::new();
        for (vi, ov) in self.views.iter().enumerate() {
            let name = ov.view.name.as_str();
            if let Some(first) = first_of.insert(name, vi) {
                return Err(Error::invalid(
                    format!("views[{vi}].name"),
                    format!(
                        "'{name}' is also the name of views[{first}]: view names must be unique"
                    ),
                ));
            }
        }
        for (vi, ov) in self.views.iter().enumerate() {
            ov.view.intrinsics.validate()?;
            for &(i, x) in &ov.observed {
                let field = format!("views[{vi}].observed");
                let name = self.names.get(i).ok_or_else(|| {
                    Error::invalid(field.clone(), format!("landmark index {i} out of range"))
                })?;
                if !x.is_finite() {
                    return Err(Error::invalid(format!("{field}.{name}"), "must be finite"));
                }
            }
        }
        let used: Vec<usize> = if self.views.len() == 1 {
            let used: Vec<usize> = self.views[0].observed.iter().map(|&(i, _)| i).collect();
            if used.len() < 4 {
                return Err(Error::invalid(
                    "views[0].observed",
                    format!(
                        "a single-view registration needs at least 4 landmarks, got {}",
                        used.len()
                    ),
                ));
            }
            used
        } else {
            let used = self.multi_view_landmarks();
            if used.len() < 3 {
                return Err(Error::invalid(
                    "views[*].observed",
                    format!(
                        "a multi-view registration needs at least 3 landmarks seen in two views, got {}",
                        used.len()
                    ),
                ));
            }
            used
        };
        check_not_collinear(used.iter().map(|&i| self.model_points[i]))
    }
}

/// Rejects point sets whose spread is (numerically) one-dimensional: the pose about their line is
/// unobservable. Uses the eigenvalues of the scatter matrix.
fn check_not_collinear(points: impl Iterator<Item = DVec3> + Clone) -> Result<()> {
    let n = points.clone().count() as f64;
    let mean = points.clone().fold(DVec3::ZERO, |a, p| a + p) / n;
    let mut s = [[0.0; 3]; 3];
    for p in points {
        let d = (p - mean).to_array();
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += d[i] * d[j];
            }
        }
    }
    let w = symmetric_eigen(s).values;
    if !w.iter().all(|v| v.is_finite()) {
        return Err(Error::invalid(
            "landmarks_3d",
            "the landmark coordinates are too large to compute with (their spread overflows)",
        ));
    }
    if w[2] <= 0.0 || w[1] <= 1e-10 * w[2] {
        return Err(Error::invalid(
            "landmarks_3d",
            "the observed landmarks are collinear or coincident (degenerate): the pose is not determined",
        ));
    }
    Ok(())
}

fn pose_from_json(p: &PoseJson, field: &str) -> Result<RigidTransform> {
    RigidTransform::from_rt(p.r, p.t, field)
}

fn view_from_json(v: &ViewJson, vi: usize) -> Result<View> {
    let field = format!("views[{vi}]");
    let guess = |c: f64| (2.0 * c + 1.0).round().clamp(1.0, 16384.0) as u32;
    let k = Intrinsics::from_matrix(
        v.k,
        v.width.unwrap_or(guess(v.k[0][2])),
        v.height.unwrap_or(guess(v.k[1][2])),
    )
    .map_err(|e| Error::invalid(format!("{field}.K"), e.to_string()))?;
    let t = RigidTransform::from_rows(v.world_to_camera, &format!("{field}.world_to_camera"))?;
    Ok(View::new(v.name.clone(), k, t))
}

impl LoadedProblem {
    /// Parses a problem JSON document; `origin` (a path) names it in errors.
    pub fn from_json_str(text: &str, origin: &str) -> Result<Self> {
        let pj: ProblemJson =
            serde_json::from_str(text).map_err(|e| Error::format(origin, e.to_string()))?;
        let in_origin = |e: Error| Error::format(origin, e.to_string());
        let names: Vec<String> = pj.landmarks_3d.keys().cloned().collect();
        let index: BTreeMap<&str, usize> = names
            .iter()
            .enumerate()
            .map(|(i, n)| (n.as_str(), i))
            .collect();
        let model_points = pj.landmarks_3d.values().map(|&p| DVec3::from(p)).collect();
        let mut views = Vec::with_capacity(pj.views.len());
        for (vi, vj) in pj.views.iter().enumerate() {
            let view = view_from_json(vj, vi).map_err(in_origin)?;
            let mut observed = Vec::with_capacity(vj.observed.len());
            for (name, &x) in &vj.observed {
                let i = *index.get(name.as_str()).ok_or_else(|| {
                    in_origin(Error::invalid(
                        format!("views[{vi}].observed.{name}"),
                        "no landmark of that name in landmarks_3d",
                    ))
                })?;
                observed.push((i, DVec2::from(x)));
            }
            views.push(ObservedView { view, observed });
        }
        let problem = RegistrationProblem::new(names, model_points, views).map_err(in_origin)?;
        let init = pj
            .init
            .as_ref()
            .map(|p| pose_from_json(p, "init"))
            .transpose();
        let truth = pj
            .truth
            .as_ref()
            .map(|p| pose_from_json(p, "truth"))
            .transpose();
        Ok(LoadedProblem {
            problem,
            init: init.map_err(in_origin)?,
            truth: truth.map_err(in_origin)?,
        })
    }

    /// Reads a problem file.
    pub fn read(path: &std::path::Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::from_json_str(&text, &path.display().to_string())
    }
}

/// Ratio beyond which a pose's projected landmark spread disagrees with the observed one (see
/// [`RegistrationProblem::implausible`]): a calibration error changes the scale by a few per cent, a pose
/// run off towards infinity (or onto the source) by orders of magnitude.
pub const MAX_SPREAD_RATIO: f64 = 4.0;

impl RegistrationProblem {
    /// Why `pose` cannot be the anatomy the views observed, or `None`: a landmark at or behind a view's
    /// source (the pinhole's mirror solution projects the same pixels through the back of the source),
    /// or the landmarks projected into a cloud whose RMS spread is more than [`MAX_SPREAD_RATIO`] times
    /// larger or smaller than the observed one's (the pose ran off towards infinity, or onto the source).
    /// A solver may stop by its tolerances at such a pose; it has not registered. (The residual alone
    /// cannot say it: a calibration error — what the study measures — leaves residuals of a quarter of a
    /// small target's spread, as large as a flipped local minimum's.)
    pub fn implausible(&self, pose: &RigidTransform) -> Option<String> {
        for v in &self.views {
            let behind = v
                .observed
                .iter()
                .filter(|(i, _)| v.view.depth(pose.apply(self.model_points[*i])) <= 0.0)
                .count();
            if behind > 0 {
                return Some(format!(
                    "{behind} landmark(s) lie at or behind the source of view '{}' at this pose (the \
                     mirror solution)",
                    v.view.name
                ));
            }
            let spread = |pts: &[DVec2]| {
                let c = pts.iter().fold(DVec2::ZERO, |a, &p| a + p) / pts.len().max(1) as f64;
                (pts.iter().map(|p| (*p - c).length_squared()).sum::<f64>()
                    / pts.len().max(1) as f64)
                    .sqrt()
            };
            let observed: Vec<DVec2> = v.observed.iter().map(|(_, x)| *x).collect();
            let projected: Vec<DVec2> = v
                .observed
                .iter()
                .map(|(i, _)| v.view.project(pose.apply(self.model_points[*i])))
                .collect();
            let (so, sp) = (spread(&observed), spread(&projected));
            if so > 0.0 && !(sp >= so / MAX_SPREAD_RATIO && sp <= so * MAX_SPREAD_RATIO) {
                return Some(format!(
                    "the landmarks project into a cloud of RMS spread {} px in view '{}' where the \
                     observed one spans {so:.1} px (the pose ran off along the view's axis)",
                    crate::error::shown(sp),
                    v.view.name
                ));
            }
        }
        None
    }
}

#[cfg(test)]
mod implausible_tests {
    use super::*;
    use crate::geometry::CArm;

    /// Eight corners of a 40 mm box at the isocentre observed without error in AP and LAT.
    fn problem() -> RegistrationProblem {
        let model_points: Vec<DVec3> =
            crate::geometry::box_corners(DVec3::splat(-20.0), DVec3::splat(20.0)).to_vec();
        let carm = CArm::default_paper();
        let views = ["ap", "lat"]
            .iter()
            .map(|n| {
                let view = carm.view(n).unwrap().clone();
                let observed = model_points
                    .iter()
                    .enumerate()
                    .map(|(i, &p)| (i, view.project(p)))
                    .collect();
                ObservedView { view, observed }
            })
            .collect();
        RegistrationProblem {
            names: (0..8).map(|i| format!("c{i}")).collect(),
            model_points,
            views,
        }
    }

    #[test]
    fn the_truth_passes_and_mirrored_run_off_and_misfit_poses_are_named() {
        let p = problem();
        assert_eq!(p.implausible(&RigidTransform::IDENTITY), None);
        // Behind the AP source: the box moved through the source to the far side.
        let s = p.views[0].view.source_world();
        let behind = RigidTransform {
            translation: 2.0 * s,
            ..RigidTransform::IDENTITY
        };
        let why = p.implausible(&behind).unwrap();
        assert!(why.contains("behind the source of view 'ap'"), "{why}");
        // Run off along the AP axis, away from the source, to 1e6 mm: the cloud shrinks to a point.
        let off = RigidTransform {
            translation: -1e6 * s.normalize(),
            ..RigidTransform::IDENTITY
        };
        let why = p.implausible(&off).unwrap();
        assert!(why.contains("RMS spread") && why.contains("'ap'"), "{why}");
    }
}
