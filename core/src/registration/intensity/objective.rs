//! The cost one resolution level minimises, over the moving DRR of [`super::moving`].
//!
//! Parameters `p = (ρ ω, t)` (six numbers, all in mm-equivalents) act on a base pose `T₀` about the
//! rotation centre `c = T₀(c_model)` in world coordinates, as in landmark registration:
//! `T(p) = [Y ↦ exp([ω]×)(Y − c) + c + t] ∘ T₀`, with `ρ` the RMS radius of the target points about
//! the centre (so a unit of rotation parameter moves the targets by about 1 mm).

use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use glam::DVec3;
use rayon::prelude::*;

use super::moving::{LevelRenderer, MovingDrr};
use super::pyramid::{binned_image, binned_image_into};
use super::similarity::{FixedFeatures, Similarity};
use crate::geometry::{RigidTransform, View, rotation_exp};
use crate::io::{ImageF32, gaussian_blur};
#[cfg(feature = "gpu")]
use crate::render::VolumeOnBackend;
use crate::{Error, Result};

/// The buffers one view's evaluation works in, kept between evaluations.
struct Buffers {
    render: ImageF32,
    binned: ImageF32,
    features: Vec<f64>,
    residual: Vec<f64>,
}

impl Default for Buffers {
    fn default() -> Self {
        Buffers {
            render: ImageF32::zeros(0, 0),
            binned: ImageF32::zeros(0, 0),
            features: Vec::new(),
            residual: Vec::new(),
        }
    }
}

/// The pose of parameters `p` about world centre `c` applied after `base` (see the module docs).
pub fn pose_of(p: &[f64; 6], base: &RigidTransform, c: DVec3, rho_mm: f64) -> RigidTransform {
    let r = rotation_exp(DVec3::new(p[0], p[1], p[2]) / rho_mm);
    let t = DVec3::new(p[3], p[4], p[5]);
    RigidTransform {
        rotation: r * base.rotation,
        translation: r * (base.translation - c) + c + t,
    }
}

/// One view of one level: the binned view with the assumed K and the fixed image's features.
pub struct LevelView {
    pub view: View,
    pub fixed: FixedFeatures,
    eps: Vec<f64>,
}

/// A pose's stacked residual: in host memory, or (a CT level on the gpu backend) on the GPU, where the
/// LM's products read it (`super::device`).
pub enum Residual {
    Host(Vec<f64>),
    #[cfg(feature = "gpu")]
    Device(super::device::DeviceResidual),
}

/// A similarity value and the least-squares cost of one pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Evaluation {
    /// `Σ_v ‖r_v‖² / V`, which is `2 (1 − S)` when every moving block has energy.
    pub cost: f64,
    /// The mean over views of the similarity.
    pub similarity: f64,
    pub per_view: Vec<f64>,
}

/// The cost of one resolution level.
pub struct Objective<'a> {
    moving: LevelRenderer<'a>,
    /// The moving DRR is rendered `supersample × supersample` rays per level pixel and box-averaged,
    /// as the fixed image's binning averages its detector pixels.
    supersample: u32,
    /// Mesh DRRs are rendered by signed sums (checked against the paired render at the base pose of
    /// every view when the objective was made).
    summed: bool,
    smooth_px: f64,
    views: Vec<LevelView>,
    base: RigidTransform,
    centre: DVec3,
    rho_mm: f64,
    evaluations: AtomicU64,
    /// Evaluation buffers, one set taken per view being evaluated and put back afterwards, so the loop
    /// renders, bins and normalises into memory it already has.
    buffers: Mutex<Vec<Buffers>>,
    /// A level on the gpu backend (a CT, or meshes) whose views share one size: evaluated on the GPU
    /// ([`super::device`]), only scalars read back (and, for meshes, the host's few pixels).
    #[cfg(feature = "gpu")]
    device: Option<super::device::DeviceLevel<'a>>,
}

impl<'a> Objective<'a> {
    /// The objective of `views` (binned, assumed K) against `fixed` (binned alike) about the model centre
    /// `centre_model`, starting from `base`, with the moving meshes at detail factor `detail` (see
    /// [`MeshDrr`]) and both images smoothed by a Gaussian of `smooth_px` (0 = none) before
    /// comparison. The moving normalisation's regulariser is scaled by the moving-to-fixed energy ratio
    /// at `base`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        moving: &'a MovingDrr,
        detail: u32,
        views: Vec<(View, ImageF32)>,
        sim: Similarity,
        smooth_px: f64,
        base: RigidTransform,
        centre_model: DVec3,
        rho_mm: f64,
    ) -> Result<Self> {
        Self::supersampled(
            moving,
            detail,
            1,
            views,
            sim,
            smooth_px,
            base,
            centre_model,
            rho_mm,
        )
    }

    /// [`Objective::new`] with the moving DRR rendered through each view binned `supersample` times
    /// finer (`views` hold those finer views; the fixed images are of the level's size, `supersample`
    /// times smaller) and box-averaged down to the level: the moving image then samples the anatomy
    /// as the binned fixed image does, so their optimum is the same sub-pixel pose.
    #[allow(clippy::too_many_arguments)]
    pub fn supersampled(
        moving: &'a MovingDrr,
        detail: u32,
        supersample: u32,
        views: Vec<(View, ImageF32)>,
        sim: Similarity,
        smooth_px: f64,
        base: RigidTransform,
        centre_model: DVec3,
        rho_mm: f64,
    ) -> Result<Self> {
        let moving = moving.level(detail)?;
        let supersample = supersample.max(1);
        let mut out = Vec::with_capacity(views.len());
        let mut summed = true;
        #[cfg(feature = "gpu")]
        let level_size = views.first().map_or((0, 0), |(_, f)| (f.width, f.height));
        for (view, fixed) in views {
            let fixed = gaussian_blur(&fixed, smooth_px);
            let f = FixedFeatures::new(sim, &fixed, &format!("views[{}].fixed", view.name))?;
            let paired = moving.render_at(&view, &base)?;
            summed = summed && moving.sums_like(&view, &base, &paired)?;
            let first = binned_image(&paired, supersample);
            if (first.width, first.height) != (fixed.width, fixed.height) {
                return Err(Error::Internal(format!(
                    "view '{}': the moving DRR binned by {supersample} is {}×{} px, the fixed image {}×{}",
                    view.name, first.width, first.height, fixed.width, fixed.height
                )));
            }
            let img = gaussian_blur(&first, smooth_px);
            let mut scratch = Vec::new();
            let layout = super::similarity::features(sim, &img, &mut scratch)?;
            let e = super::similarity::normalise(
                &mut scratch,
                &layout,
                &vec![0.0; layout.blocks.len()],
            );
            let moving_energy: f64 = e
                .iter()
                .zip(&f.layout.weights)
                .filter(|(_, w)| **w > 0.0)
                .map(|(e, _)| e)
                .sum();
            if moving_energy <= 0.0 {
                return Err(Error::invalid(
                    "init",
                    format!(
                        "the anatomy is not visible in view '{}' at the initial pose",
                        view.name
                    ),
                ));
            }
            let eps = f.moving_eps(moving_energy / f.used_energy());
            out.push(LevelView {
                view,
                fixed: f,
                eps,
            });
        }
        #[cfg(feature = "gpu")]
        let device = {
            use super::device::{DeviceLevel, Source};
            let source = match &moving {
                LevelRenderer::Volume(v) => {
                    let v: &'a VolumeOnBackend = v;
                    v.gpu().map(Source::Ct)
                }
                LevelRenderer::Mesh(r) => r.gpu_context().map(|_| Source::Mesh {
                    renderer: std::sync::Arc::clone(r),
                    summed,
                }),
            };
            match source {
                Some(source) => {
                    let views: Vec<_> = out
                        .iter()
                        .map(|lv| (&lv.view, &lv.fixed, lv.eps.as_slice()))
                        .collect();
                    DeviceLevel::new(source, &views, supersample, smooth_px, level_size)?
                }
                None => None,
            }
        };
        Ok(Objective {
            #[cfg(feature = "gpu")]
            device,
            moving,
            supersample,
            summed,
            smooth_px,
            views: out,
            base,
            centre: base.apply(centre_model),
            rho_mm,
            // The render at `base` above counts as one evaluation.
            evaluations: AtomicU64::new(1),
            buffers: Mutex::new(Vec::new()),
        })
    }

    fn take_buffers(&self) -> Buffers {
        self.buffers
            .lock()
            .ok()
            .and_then(|mut v| v.pop())
            .unwrap_or_default()
    }

    fn put_buffers(&self, b: Buffers) {
        if let Ok(mut v) = self.buffers.lock() {
            v.push(b);
        }
    }

    /// The similarity of one view at `pose`; its residual is left in `b.residual`.
    fn evaluate_view(&self, lv: &LevelView, pose: &RigidTransform, b: &mut Buffers) -> Result<f64> {
        self.moving
            .render_into(&lv.view, pose, &mut b.render, self.summed)?;
        let img = if self.supersample > 1 {
            binned_image_into(&b.render, self.supersample, &mut b.binned);
            &b.binned
        } else {
            &b.render
        };
        if self.smooth_px > 0.0 {
            let img = gaussian_blur(img, self.smooth_px);
            lv.fixed
                .residual(&img, &lv.eps, &mut b.features, &mut b.residual)
        } else {
            lv.fixed
                .residual(img, &lv.eps, &mut b.features, &mut b.residual)
        }
    }

    /// The pose of parameters `p`.
    pub fn pose(&self, p: &[f64; 6]) -> RigidTransform {
        pose_of(p, &self.base, self.centre, self.rho_mm)
    }

    /// Evaluations so far (each renders every view once).
    pub fn evaluations(&self) -> u64 {
        self.evaluations.load(Ordering::Relaxed)
    }

    pub fn view_count(&self) -> usize {
        self.views.len()
    }

    /// The objective with its similarity evaluated on the host even where the GPU could (a CT or meshes
    /// on the gpu backend then render there and the CPU bins, smooths and compares the images read
    /// back): to compare the two.
    pub fn on_host(self) -> Self {
        #[cfg(feature = "gpu")]
        {
            let mut s = self;
            s.device = None;
            s
        }
        #[cfg(not(feature = "gpu"))]
        self
    }

    /// The objective with a GPU level's Jacobian evaluated pose after pose (six dispatches of each pass)
    /// instead of in one dispatch, as a level too large for the adapter to hold six poses' views is: to
    /// compare the two.
    pub fn columns_one_by_one(self) -> Self {
        #[cfg(feature = "gpu")]
        {
            let mut s = self;
            if let Some(d) = &mut s.device {
                d.columns_one_by_one();
            }
            s
        }
        #[cfg(not(feature = "gpu"))]
        self
    }

    /// Whether the level is evaluated on the GPU (the gpu backend): render, pyramid, smoothing,
    /// similarity and the LM's products there, only scalars read back.
    pub fn on_device(&self) -> bool {
        #[cfg(feature = "gpu")]
        if self.device.is_some() {
            return true;
        }
        false
    }

    /// The views seen from `pose`: the camera moves instead of the anatomy.
    #[cfg(feature = "gpu")]
    fn moved_views(&self, pose: &RigidTransform) -> Vec<View> {
        self.views
            .iter()
            .map(|lv| super::moving::seen_from(&lv.view, pose))
            .collect()
    }

    /// Evaluates `p` and keeps its stacked residual where the level computes it.
    pub fn residual_at(&self, p: &[f64; 6]) -> Result<(Evaluation, Residual)> {
        #[cfg(feature = "gpu")]
        if let Some(d) = &self.device {
            let (e, r) = self.device_evaluate(d, p)?;
            return Ok((e, Residual::Device(r)));
        }
        let mut r = Vec::new();
        let e = self.evaluate(p, Some(&mut r))?;
        Ok((e, Residual::Host(r)))
    }

    #[cfg(feature = "gpu")]
    fn device_evaluate(
        &self,
        d: &super::device::DeviceLevel,
        p: &[f64; 6],
    ) -> Result<(Evaluation, super::device::DeviceResidual)> {
        self.evaluations.fetch_add(1, Ordering::Relaxed);
        let (sums, r) = d.evaluate(&self.moved_views(&self.pose(p)))?;
        let n = sums.similarity.len().max(1) as f64;
        Ok((
            Evaluation {
                cost: sums.squared.iter().sum::<f64>() / n,
                similarity: sums.similarity.iter().sum::<f64>() / n,
                per_view: sums.similarity,
            },
            r,
        ))
    }

    /// The GPU level, when the level is evaluated there.
    #[cfg(feature = "gpu")]
    pub(super) fn device(&self) -> Result<&super::device::DeviceLevel<'a>> {
        self.device
            .as_ref()
            .ok_or_else(|| Error::Internal("a GPU residual of a level evaluated on the CPU".into()))
    }

    /// The forward-difference Jacobian of step `h` at `p` (residual `r`) on the GPU: the six poses
    /// `p + h e_k` rendered and compared in one submission.
    #[cfg(feature = "gpu")]
    pub(super) fn device_jacobian(
        &self,
        p: &[f64; 6],
        r: &super::device::DeviceResidual,
        h: f64,
    ) -> Result<super::device::DeviceJacobian> {
        let d = self.device()?;
        let columns: Vec<Vec<View>> = (0..6)
            .map(|k| {
                let mut q = *p;
                q[k] += h;
                self.moved_views(&self.pose(&q))
            })
            .collect();
        self.evaluations.fetch_add(6, Ordering::Relaxed);
        d.jacobian(&columns, r, h)
    }

    /// Evaluates `p`; with `residual`, also writes the stacked residual `r_v / √V` of every view.
    pub fn evaluate(&self, p: &[f64; 6], residual: Option<&mut Vec<f64>>) -> Result<Evaluation> {
        #[cfg(feature = "gpu")]
        if let Some(d) = &self.device {
            let (e, r) = self.device_evaluate(d, p)?;
            if let Some(out) = residual {
                *out = d.read_residual(&r)?;
            }
            return Ok(e);
        }
        self.evaluations.fetch_add(1, Ordering::Relaxed);
        let pose = self.pose(p);
        let scale = 1.0 / (self.views.len() as f64).sqrt();
        let per: Vec<(f64, Buffers)> = self
            .views
            .par_iter()
            .map(|lv| {
                let mut b = self.take_buffers();
                let r = self.evaluate_view(lv, &pose, &mut b);
                match r {
                    Ok(s) => Ok((s, b)),
                    Err(e) => {
                        self.put_buffers(b);
                        Err(e)
                    }
                }
            })
            .collect::<Result<_>>()?;
        let mut cost = 0.0;
        let mut per_view = Vec::with_capacity(per.len());
        let mut residual = residual;
        if let Some(out) = residual.as_deref_mut() {
            out.clear();
        }
        for (s, b) in per {
            cost += b.residual.iter().map(|x| x * x).sum::<f64>();
            per_view.push(s);
            if let Some(out) = residual.as_deref_mut() {
                out.extend(b.residual.iter().map(|x| x * scale));
            }
            self.put_buffers(b);
        }
        let n = per_view.len() as f64;
        Ok(Evaluation {
            cost: cost / n,
            similarity: per_view.iter().sum::<f64>() / n,
            per_view,
        })
    }
}
