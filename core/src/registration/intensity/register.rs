//! The registration pipeline: a coarse-to-fine schedule of binned detectors; CMA-ES at the coarsest
//! level (optional), then Levenberg–Marquardt at every level, each level starting from the last one's
//! pose.

use std::time::Instant;

use glam::DVec3;

use super::cmaes::{CmaesOptions, minimize};
use super::lm::{LmOptions, refine};
use super::moving::MovingDrr;
use super::objective::Objective;
use super::pyramid::{binned_image, binned_view, subsampled_image, subsampled_view};
use super::similarity::Similarity;
use crate::geometry::{RigidTransform, View};
use crate::io::ImageF32;
use crate::{Error, Result};

/// One view of an intensity problem: the view with the **assumed** K and the fixed image (line-integral
/// domain, the view's size).
#[derive(Debug, Clone)]
pub struct IntensityView {
    pub view: View,
    pub fixed: ImageF32,
}

/// The moving anatomy, the views with their fixed images, and the target points.
pub struct IntensityProblem {
    pub moving: MovingDrr,
    pub views: Vec<IntensityView>,
    /// Target points (model frame, mm): the mTRE is measured on them and their mean is the rotation
    /// centre.
    pub targets: Vec<DVec3>,
}

impl IntensityProblem {
    /// The rotation centre: the mean of the target points (model frame).
    pub fn centre(&self) -> DVec3 {
        self.targets.iter().fold(DVec3::ZERO, |a, &p| a + p) / self.targets.len().max(1) as f64
    }

    /// RMS distance of the targets from the centre (mm), the scale of the rotation parameters.
    pub fn rho_mm(&self) -> f64 {
        let c = self.centre();
        let n = self.targets.len().max(1) as f64;
        (self
            .targets
            .iter()
            .map(|p| (*p - c).length_squared())
            .sum::<f64>()
            / n)
            .sqrt()
            .max(1.0)
    }

    /// Checks the views (at least one; every fixed image of its view's size) and the targets.
    pub fn validate(&self) -> Result<()> {
        if self.views.is_empty() {
            return Err(Error::invalid("views", "at least one view is needed"));
        }
        if self.targets.is_empty() {
            return Err(Error::invalid("anatomy", "no target points"));
        }
        for (i, v) in self.views.iter().enumerate() {
            v.view.intrinsics.validate()?;
            let k = &v.view.intrinsics;
            if (v.fixed.width, v.fixed.height) != (k.width, k.height) {
                return Err(Error::invalid(
                    format!("views[{i}].fixed"),
                    format!(
                        "the fixed image is {}×{} px but view '{}' is {}×{}",
                        v.fixed.width, v.fixed.height, v.view.name, k.width, k.height
                    ),
                ));
            }
            if v.fixed.data.iter().any(|x| !x.is_finite()) {
                return Err(Error::invalid(
                    format!("views[{i}].fixed"),
                    "the fixed image has a non-finite pixel",
                ));
            }
        }
        Ok(())
    }
}

/// Least relative decrease of the cost that keeps a coarse level's refinement going (see
/// [`register_intensity`]).
pub const COARSE_REL_TOL: f64 = 1e-5;

/// Most Jacobians a coarse level's refinement forms, after the coarsest (see [`register_intensity`]).
pub const COARSE_MAX_ITERATIONS: usize = 6;

/// Settings of [`register_intensity`].
#[derive(Debug, Clone, PartialEq)]
pub struct IntensityOptions {
    pub similarity: Similarity,
    /// Binning factors, coarsest first (e.g. `[8, 4, 2]`; 1 = the full detector).
    pub levels: Vec<u32>,
    /// Run CMA-ES at the coarsest level before its refinement.
    pub global: bool,
    /// Gaussian smoothing σ (px of each level) of both images before comparison at every level but the
    /// finest (0 = none): it widens the basin of the thin cortical edges on the coarse levels, while
    /// the finest level compares the images themselves (smoothed there too, the phantom's optimum
    /// flattened so that refinement stopped ~0.2 mm short).
    pub smooth_px: f64,
    pub cmaes: CmaesOptions,
    /// Rays per level pixel along each axis of the moving DRR on the levels that bin (box-averaged, as
    /// the fixed image's binning averages detector pixels; capped by, and a divisor of, each level's
    /// binning) after the coarsest level, which always renders one (CMA-ES there only has to find the
    /// basin: for the CT target 2 × 2 rays tripled its time and did not shorten the later levels);
    /// `None` chooses by the moving DRR: 1 for meshes, 2 for volumes. With one ray at each
    /// binned pixel's centre the moving image samples the anatomy differently from the binned fixed
    /// image, which moves that level's optimum by a fraction of its pixel (the next level corrects it;
    /// on the finest level see `subsample_finest`). A volume's coarse levels end closer to the truth
    /// with 2 × 2 rays, which saves more finest-level iterations than the rays cost.
    pub supersample: Option<u32>,
    /// How the finest level samples the detector when it bins (`b > 1`); `None` chooses by the moving
    /// DRR: subsampled for meshes, binned for volumes. *Subsampled* (`Some(true)`) keeps every `b`-th
    /// pixel of the fixed image ([`super::pyramid::subsampled_image`]) and renders the moving DRR
    /// through exactly those pixels' rays: at the true K the two images sample the same rays, so the
    /// optimum is the true pose at one ray per level pixel (measured: 40 of 40 starts of phantom L3
    /// within 0.05 mm). *Binned* (`Some(false)`) averages `b × b` pixels and renders `supersample²` rays
    /// per pixel: it averages the fixed image's noise, and for a CT volume it is what converges — its
    /// DRR of voxels has a kink wherever a ray crosses a voxel boundary, and one ray per pixel (the
    /// subsampled level, or the full detector) stalls 0.1–0.3 mm from the truth, while the average of
    /// 2 × 2 rays is smooth enough to reach it.
    pub subsample_finest: Option<bool>,
    /// Refinement settings; the finite-difference step is `lm.h · b` at binning `b`; `lm.broyden`
    /// applies to the finest level (coarse levels always difference, see [`register_intensity`]).
    pub lm: LmOptions,
}

impl Default for IntensityOptions {
    fn default() -> Self {
        IntensityOptions {
            similarity: Similarity::Ncc,
            levels: vec![16, 8, 4, 2],
            global: true,
            smooth_px: 1.0,
            supersample: None,
            subsample_finest: None,
            cmaes: CmaesOptions {
                sigma0: 4.0,
                lambda: None,
                max_generations: 30,
                tol_x: 0.3,
                tol_fun: 1e-7,
                seed: 0,
            },
            lm: LmOptions {
                h: 0.05,
                max_iterations: 30,
                rel_tol: 1e-7,
                step_tol: 2e-4,
                abs_tol: 1e-14,
                broyden: true,
            },
        }
    }
}

/// Where `obj`'s evaluations run (see [`StageReport::similarity_on`]).
fn evaluated_on(obj: &Objective) -> &'static str {
    if obj.on_device() { "gpu" } else { "cpu" }
}

/// What one stage of one level did.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct StageReport {
    pub bin: u32,
    /// `cmaes` or `lm`.
    pub stage: &'static str,
    pub evaluations: u64,
    pub iterations: usize,
    pub stop: &'static str,
    pub similarity: f64,
    /// Where the level's evaluations ran: `gpu` (a CT or meshes on the gpu backend: render, pyramid,
    /// smoothing, similarity and the LM's products on the GPU, only scalars read back — and for meshes
    /// the host's few pixels, evaluated and written into the image on the GPU) or `cpu` (the similarity
    /// on the host, whatever rendered the DRRs).
    pub similarity_on: &'static str,
    /// Wall time of the stage (s).
    pub seconds: f64,
}

/// The registered pose and how it was reached.
#[derive(Debug, Clone, PartialEq)]
pub struct IntensityResult {
    /// Model → world.
    pub pose: RigidTransform,
    /// Final similarity (mean over views) at the finest level.
    pub similarity: f64,
    pub per_view_similarity: Vec<f64>,
    /// Pose evaluations (each renders every view once).
    pub evaluations: u64,
    /// DRRs rendered (evaluations × views).
    pub renders: u64,
    pub seconds: f64,
    /// The finest level's refinement stopped by a tolerance, not by its iteration cap.
    pub converged: bool,
    pub stages: Vec<StageReport>,
}

/// Checks that the target centre at `pose` is in front of every view's source and on its detector.
pub fn check_visible(problem: &IntensityProblem, pose: &RigidTransform, field: &str) -> Result<()> {
    let c = pose.apply(problem.centre());
    for v in &problem.views {
        let k = &v.view.intrinsics;
        let depth = v.view.depth(c);
        if depth <= 0.0 {
            // The pinhole formula would give a mirrored pixel, perhaps inside the detector: not quoted.
            return Err(Error::invalid(
                field,
                format!(
                    "the anatomy is not visible in view '{}': its centre lies at or behind the source \
                     (depth {depth:.1} mm along the central ray)",
                    v.view.name
                ),
            ));
        }
        let x = v.view.project(c);
        let inside = x.x >= -0.5
            && x.y >= -0.5
            && x.x <= f64::from(k.width) - 0.5
            && x.y <= f64::from(k.height) - 0.5;
        if !inside {
            return Err(Error::invalid(
                field,
                format!(
                    "the anatomy is not visible in view '{}': its centre projects to ({:.0}, {:.0}) px, \
                     outside the {}×{} detector",
                    v.view.name, x.x, x.y, k.width, k.height
                ),
            ));
        }
    }
    Ok(())
}

/// Seconds since `clock`, which restarts.
fn lap(clock: &mut Instant) -> f64 {
    let s = clock.elapsed().as_secs_f64();
    *clock = Instant::now();
    s
}

/// Registers `problem` from `init` (model → world).
pub fn register_intensity(
    problem: &IntensityProblem,
    init: &RigidTransform,
    opts: &IntensityOptions,
) -> Result<IntensityResult> {
    let start = Instant::now();
    problem.validate()?;
    if opts.levels.is_empty() {
        return Err(Error::invalid("levels", "at least one resolution level"));
    }
    check_visible(problem, init, "init")?;
    let (centre, rho) = (problem.centre(), problem.rho_mm());
    let mut pose = *init;
    let mut stages = Vec::new();
    let (mut evaluations, mut last) = (0u64, None);
    let mesh = matches!(problem.moving, MovingDrr::Mesh(_));
    let rays = opts.supersample.unwrap_or(if mesh { 1 } else { 2 });
    let finest_bin = opts.levels[opts.levels.len() - 1].max(1);
    for (li, &b) in opts.levels.iter().enumerate() {
        let finest = li + 1 == opts.levels.len();
        let subsample = finest && b > 1 && opts.subsample_finest.unwrap_or(mesh);
        // The largest factor ≤ the supersampling that divides the binning, on a binned level.
        // The coarsest level, the global search's, renders one ray per pixel whatever the DRR (unless
        // it is also the finest).
        let rays = if li == 0 && !finest { 1 } else { rays };
        let ss = (1..=rays.max(1).min(b.max(1)))
            .rev()
            .find(|s| b % s == 0 && !subsample)
            .unwrap_or(1);
        let views = problem
            .views
            .iter()
            .map(|v| {
                Ok(if subsample {
                    (subsampled_view(&v.view, b)?, subsampled_image(&v.fixed, b))
                } else {
                    (binned_view(&v.view, b / ss)?, binned_image(&v.fixed, b))
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let obj = Objective::supersampled(
            &problem.moving,
            (b / finest_bin).max(1),
            ss,
            views,
            opts.similarity,
            if finest { 0.0 } else { opts.smooth_px },
            pose,
            centre,
            rho,
        )?;
        let mut p0 = [0.0; 6];
        let mut clock = Instant::now();
        if li == 0 && opts.global {
            let cma = minimize(|p| Ok(obj.evaluate(p, None)?.cost), p0, &opts.cmaes)?;
            p0 = cma.best;
            stages.push(StageReport {
                bin: b,
                stage: "cmaes",
                evaluations: obj.evaluations(),
                iterations: cma.generations,
                stop: cma.stop,
                similarity: 1.0 - cma.best_cost / 2.0,
                similarity_on: evaluated_on(&obj),
                seconds: lap(&mut clock),
            });
        }
        let before = obj.evaluations();
        // A coarse level only has to hand the next one a start inside its basin: its refinement stops
        // at a step of ten times the finest step tolerance per binned pixel, a relative decrease of
        // COARSE_REL_TOL or, after the coarsest level (which may have to travel from a far start),
        // COARSE_MAX_ITERATIONS Jacobians. Coarse levels form every Jacobian by differences (their
        // smoothed costs converge in a few full iterations; secant updates took more evaluations,
        // measured on phantom L3 and its CT); the finest level, where a render costs most, updates it
        // by Broyden's secants.
        let lm = if finest {
            LmOptions {
                h: opts.lm.h * f64::from(b),
                ..opts.lm
            }
        } else {
            LmOptions {
                h: opts.lm.h * f64::from(b),
                rel_tol: opts.lm.rel_tol.max(COARSE_REL_TOL),
                step_tol: opts.lm.step_tol * 10.0 * f64::from(b),
                broyden: false,
                max_iterations: if li == 0 {
                    opts.lm.max_iterations
                } else {
                    opts.lm.max_iterations.min(COARSE_MAX_ITERATIONS)
                },
                ..opts.lm
            }
        };
        let r = refine(&obj, p0, &lm)?;
        stages.push(StageReport {
            bin: b,
            stage: "lm",
            evaluations: obj.evaluations() - before,
            iterations: r.iterations,
            stop: r.stop,
            similarity: r.eval.similarity,
            similarity_on: evaluated_on(&obj),
            seconds: lap(&mut clock),
        });
        pose = obj.pose(&r.p);
        evaluations += obj.evaluations();
        last = Some(r);
    }
    let Some(last) = last else {
        return Err(Error::Internal("no level ran".into()));
    };
    Ok(IntensityResult {
        pose,
        similarity: last.eval.similarity,
        per_view_similarity: last.eval.per_view,
        evaluations,
        renders: evaluations * problem.views.len() as u64,
        seconds: start.elapsed().as_secs_f64(),
        converged: last.converged,
        stages,
    })
}
