//! CT volume DRRs: the line integral of the linear attenuation coefficient through a CT,
//! `∫ μ(HU(x)) dl` with `μ(HU) = μ_water · max(0, 1 + HU / 1000)` ([`mu_from_hu`], mm⁻¹; the output is
//! unitless).
//!
//! Two ray integrators over the same μ voxel grid:
//! * [`VolumeMethod::Siddon`]: exact for the piecewise-constant voxel model (Siddon 1985), walked from
//!   one minor-axis crossing to the next with differences of running sums along the dominant axis, see
//!   [`siddon`];
//! * [`VolumeMethod::Trilinear`]: midpoint-rule samples of the trilinearly interpolated μ field, see
//!   [`trilinear`].
//!
//! Rays come from [`View`] (source at the camera centre, one ray per pixel centre), so the same
//! intrinsics, extrinsics and perturbations apply as for the thickness renderer. Rays are clipped to the
//! volume's box (or a mask's bounding box) in continuous voxel-index space via the inverse affine; the ray
//! parameter stays in world millimetres because the index map is affine.

mod prefix;
mod select;
pub mod siddon;
pub mod trilinear;

use std::fmt;
use std::str::FromStr;
use std::sync::{Arc, OnceLock};

use glam::{DMat4, DVec2, DVec3};
use rayon::prelude::*;
use serde::Serialize;

use self::prefix::AxisPrefix;
pub use self::select::select_voxels;

pub use crate::anatomy::ct::{CtVolume, VoxelMask};
use crate::anatomy::{MU_WATER_PER_MM, mu_from_hu};
use crate::geometry::{Ray, View, box_corners};
use crate::io::ImageF32;
use crate::{Error, Result};

/// How a ray's line integral is evaluated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum VolumeMethod {
    /// Exact voxel traversal (Siddon's voxel model).
    #[default]
    Siddon,
    /// Trilinear interpolation sampled at ≤ half the smallest voxel spacing.
    Trilinear,
}

impl FromStr for VolumeMethod {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "siddon" | "jacobs" => Ok(VolumeMethod::Siddon),
            "trilinear" => Ok(VolumeMethod::Trilinear),
            _ => Err(Error::invalid(
                "method",
                format!("unknown volume DRR method {s:?}: use siddon or trilinear"),
            )),
        }
    }
}

impl fmt::Display for VolumeMethod {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            VolumeMethod::Siddon => "siddon",
            VolumeMethod::Trilinear => "trilinear",
        })
    }
}

/// Options of a CT volume DRR.
#[derive(Debug, Clone, PartialEq)]
pub struct VolumeRenderOptions {
    pub method: VolumeMethod,
    /// μ of water (mm⁻¹) in `μ(HU) = μ_water · max(0, 1 + HU/1000)`.
    pub mu_water: f64,
    /// Trilinear step (mm); capped at half the smallest voxel spacing. `None` = that cap.
    pub step_mm: Option<f64>,
}

impl Default for VolumeRenderOptions {
    fn default() -> Self {
        VolumeRenderOptions {
            method: VolumeMethod::Siddon,
            mu_water: MU_WATER_PER_MM,
            step_mm: None,
        }
    }
}

/// The finest trilinear step, as a fraction of the smallest voxel spacing: `spacing / 100`.
pub const MIN_STEPS_PER_VOXEL_INV: f64 = 100.0;

/// A CT prepared for rendering: the μ grid (masked voxels zeroed), the world→index map and clip box.
#[derive(Debug, Clone)]
pub struct VolumeRenderer {
    pub(crate) dims: [usize; 3],
    pub(crate) mu: Vec<f32>,
    pub(crate) world_to_index: DMat4,
    /// Inclusive voxel-index range that can contribute (whole volume, or the mask's bounding box).
    pub(crate) lo: [usize; 3],
    pub(crate) hi: [usize; 3],
    method: VolumeMethod,
    mu_water: f64,
    step_mm: f64,
    /// Per dominant axis, μ's running sums over the clip box for the Siddon walk: built on
    /// the first ray that walks along that axis (an AP view needs one axis, a lateral another), and
    /// shared by clones (μ never changes after construction; [`Self::with_values`] starts afresh).
    pub(crate) prefix: [OnceLock<Arc<AxisPrefix>>; 3],
}

/// What a CT DRR's sidecar records about its making (`details`).
#[derive(Debug, Clone, Serialize)]
pub struct VolumeDetails {
    /// `ct-volume`.
    pub renderer: &'static str,
    pub method: String,
    pub mu_water_per_mm: f64,
    /// The trilinear step used (mm).
    pub step_mm: f64,
}

impl VolumeRenderer {
    /// Converts HU to μ, applies the optional mask (which must be on the CT's grid) and fixes the step.
    pub fn new(
        ct: &CtVolume,
        opts: &VolumeRenderOptions,
        mask: Option<&VoxelMask>,
    ) -> Result<Self> {
        if !(opts.mu_water.is_finite() && opts.mu_water > 0.0) {
            return Err(Error::invalid(
                "mu_water",
                format!("{} must be a positive number (mm⁻¹)", opts.mu_water),
            ));
        }
        let mu_water = opts.mu_water as f32;
        let mut mu: Vec<f32> = ct
            .values
            .par_iter()
            .map(|&hu| mu_from_hu(hu, mu_water))
            .collect();
        let (mut lo, mut hi) = ([0; 3], ct.dims.map(|n| n - 1));
        if let Some(m) = mask {
            if m.dims != ct.dims {
                return Err(Error::invalid(
                    "mask",
                    format!(
                        "segmentation grid {:?} differs from the CT grid {:?} (resample it onto the CT)",
                        m.dims, ct.dims
                    ),
                ));
            }
            mu.par_iter_mut()
                .zip(m.keep.par_iter())
                .for_each(|(v, &k)| *v = if k { *v } else { 0.0 });
            (lo, hi) = m.bbox;
            if opts.method == VolumeMethod::Trilinear {
                // The interpolated field reaches one voxel beyond the outermost kept centre.
                lo = lo.map(|v| v.saturating_sub(1));
                hi = [0, 1, 2].map(|a| (hi[a] + 1).min(ct.dims[a] - 1));
            }
        }
        let spacing = ct.spacing_mm().min_element();
        let half_spacing = 0.5 * spacing;
        let step_mm = match opts.step_mm {
            Some(s) if s.is_finite() && s > 0.0 && s < spacing / MIN_STEPS_PER_VOXEL_INV => {
                return Err(Error::invalid(
                    "step_mm",
                    format!(
                        "{} mm is finer than 1/{MIN_STEPS_PER_VOXEL_INV} of the CT's smallest voxel \
                         spacing ({spacing} mm): it samples each voxel over {MIN_STEPS_PER_VOXEL_INV} \
                         times along a ray and only multiplies the work (a 1024² DRR through 500 voxels \
                         would take over 5·10¹⁰ samples); give a step of at least {} mm",
                        crate::error::shown(s),
                        spacing / MIN_STEPS_PER_VOXEL_INV
                    ),
                ));
            }
            Some(s) if s.is_finite() && s > 0.0 => s.min(half_spacing),
            Some(s) => {
                return Err(Error::invalid(
                    "step_mm",
                    format!("{s} must be a positive length"),
                ));
            }
            None => half_spacing,
        };
        Ok(VolumeRenderer {
            dims: ct.dims,
            mu,
            world_to_index: ct.world_to_index(),
            lo,
            hi,
            method: opts.method,
            mu_water: opts.mu_water,
            step_mm,
            prefix: Default::default(),
        })
    }

    /// The same CT geometry (grid, placement, mask's clip box) with voxel values `value(hu)` where this
    /// renderer's μ is not 0 (masked voxels and air stay 0): a material channel's density grid for the
    /// spectral render. `hu` is the CT's values, on this renderer's grid.
    pub fn with_values(&self, hu: &[f32], value: impl Fn(f32) -> f32 + Sync) -> Result<Self> {
        if hu.len() != self.mu.len() {
            return Err(Error::invalid(
                "hu",
                format!("{} voxels for a grid of {}", hu.len(), self.mu.len()),
            ));
        }
        let mu = self
            .mu
            .par_iter()
            .zip(hu.par_iter())
            .map(|(&m, &h)| if m == 0.0 { 0.0 } else { value(h) })
            .collect();
        // New values, so new running sums: none are carried over from this renderer.
        Ok(VolumeRenderer {
            dims: self.dims,
            mu,
            world_to_index: self.world_to_index,
            lo: self.lo,
            hi: self.hi,
            method: self.method,
            mu_water: self.mu_water,
            step_mm: self.step_mm,
            prefix: Default::default(),
        })
    }

    /// Whether world point `p` lies inside the box of the voxels that attenuate (μ > 0, after the mask),
    /// each voxel taken as its whole cell: an X-ray source there would sit inside the patient. Air
    /// (−1000 HU, μ = 0) around the body does not count, so a source in the scan's empty margin is fine.
    pub fn attenuating_box_contains(&self, p: DVec3) -> bool {
        let x = self.world_to_index.transform_point3(p);
        let inside = |lo: [usize; 3], hi: [usize; 3]| {
            (0..3).all(|a| x[a] >= lo[a] as f64 - 0.5 && x[a] <= hi[a] as f64 + 0.5)
        };
        // The attenuating voxels lie in the clip box: outside it (the usual case) nothing is scanned.
        if !inside(self.lo, self.hi) {
            return false;
        }
        let [nx, ny, _] = self.dims;
        let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
        for (n, _) in self.mu.iter().enumerate().filter(|(_, m)| **m > 0.0) {
            let ijk = [n % nx, n / nx % ny, n / (nx * ny)];
            for a in 0..3 {
                lo[a] = lo[a].min(ijk[a]);
                hi[a] = hi[a].max(ijk[a]);
            }
        }
        lo[0] != usize::MAX && inside(lo, hi)
    }

    /// μ's running sums along `axis` over the clip box, built on first use.
    pub(crate) fn axis_prefix(&self, axis: usize) -> &AxisPrefix {
        self.prefix[axis].get_or_init(|| {
            Arc::new(AxisPrefix::build(
                &self.mu, self.dims, self.lo, self.hi, axis,
            ))
        })
    }

    /// The ray integrator.
    pub fn method(&self) -> VolumeMethod {
        self.method
    }

    /// The trilinear step actually used (mm).
    pub fn step_mm(&self) -> f64 {
        self.step_mm
    }

    /// The sidecar record of this renderer.
    pub fn details(&self) -> VolumeDetails {
        VolumeDetails {
            renderer: "ct-volume",
            method: self.method.to_string(),
            mu_water_per_mm: self.mu_water,
            step_mm: self.step_mm,
        }
    }

    /// The ray in index space: origin `p0` and per-mm direction `dp` (`p(t) = p0 + t·dp`, t in mm).
    #[inline]
    fn index_ray(&self, ray: &Ray) -> (DVec3, DVec3) {
        (
            self.world_to_index.transform_point3(ray.origin),
            self.world_to_index.transform_vector3(ray.dir),
        )
    }

    /// Entry and exit parameters (mm, `t ≥ 0`) of the ray in the clip box `[lo − ½, hi + ½]` (slab method),
    /// or `None` when it misses.
    #[inline]
    pub(crate) fn clip(&self, p0: DVec3, dp: DVec3) -> Option<(f64, f64)> {
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for a in 0..3 {
            let lo = self.lo[a] as f64 - 0.5;
            let hi = self.hi[a] as f64 + 0.5;
            if dp[a] == 0.0 {
                if p0[a] < lo || p0[a] > hi {
                    return None;
                }
                continue;
            }
            let inv = 1.0 / dp[a];
            let (ta, tb) = ((lo - p0[a]) * inv, (hi - p0[a]) * inv);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        (t0 < t1).then_some((t0, t1))
    }

    /// The ray's direction in index space (voxels per mm) and its clipped length (mm; 0 when it misses):
    /// for statistics such as voxel visits.
    pub fn clipped_index_segment(&self, ray: &Ray) -> (DVec3, f64) {
        let (p0, dp) = self.index_ray(ray);
        let len = self.clip(p0, dp).map_or(0.0, |(t0, t1)| t1 - t0);
        (dp, len)
    }

    /// `∫ μ dl` along one world ray (unit direction), with the renderer's method.
    pub fn line_integral(&self, ray: &Ray) -> f64 {
        let (p0, dp) = self.index_ray(ray);
        let Some((t0, t1)) = self.clip(p0, dp) else {
            return 0.0;
        };
        match self.method {
            VolumeMethod::Siddon => siddon::integrate(self, p0, dp, t0, t1),
            VolumeMethod::Trilinear => trilinear::integrate(self, p0, dp, t0, t1, self.step_mm),
        }
    }

    /// `∫ μ dl` along one world ray (unit direction) over the stretch `a ≤ t ≤ b` (mm from its origin),
    /// with the renderer's method: what lies in an implant's interval of the ray.
    pub fn segment_integral(&self, ray: &Ray, a: f64, b: f64) -> f64 {
        let (p0, dp) = self.index_ray(ray);
        let Some((t0, t1)) = self.clip(p0, dp) else {
            return 0.0;
        };
        let (t0, t1) = (t0.max(a), t1.min(b));
        if t0 >= t1 {
            return 0.0;
        }
        match self.method {
            VolumeMethod::Siddon => siddon::integrate(self, p0, dp, t0, t1),
            VolumeMethod::Trilinear => trilinear::integrate(self, p0, dp, t0, t1, self.step_mm),
        }
    }

    /// The DRR of `view`: pixel (u, v) holds the line integral along the ray through its centre.
    /// Rows are rendered in parallel (rayon).
    pub fn render(&self, view: &View) -> ImageF32 {
        let mut img = ImageF32::zeros(0, 0);
        self.render_into(view, &mut img);
        img
    }

    /// [`VolumeRenderer::render`] into `out`, reusing its buffer. Only the pixels inside the clip box's
    /// projected footprint trace rays (the others miss the box and stay 0), which is what makes a masked
    /// level cheap: its box covers a small part of the detector.
    pub fn render_into(&self, view: &View, out: &mut ImageF32) {
        let (w, h) = (view.intrinsics.width, view.intrinsics.height);
        out.width = w;
        out.height = h;
        out.data.clear();
        out.data.resize(w as usize * h as usize, 0.0);
        let Some((u0, u1, v0, v1)) = self.footprint(view) else {
            return;
        };
        let m = view.pixel_to_world_dir();
        let origin = view.source_world();
        out.data
            .par_chunks_mut(w as usize)
            .enumerate()
            .skip(v0)
            .take(v1 + 1 - v0)
            .for_each(|(v, row)| {
                for (u, px) in row.iter_mut().enumerate().take(u1 + 1).skip(u0) {
                    let dir = (m * DVec3::new(u as f64, v as f64, 1.0)).normalize();
                    *px = self.line_integral(&Ray { origin, dir }) as f32;
                }
            });
    }

    /// The inclusive pixel range `(u0, u1, v0, v1)` whose rays can meet the clip box ([`footprint`]).
    pub(crate) fn footprint(&self, view: &View) -> Option<(usize, usize, usize, usize)> {
        footprint(&self.world_to_index, self.lo, self.hi, view)
    }
}

/// The inclusive pixel range `(u0, u1, v0, v1)` whose rays can meet the clip box: the bounding box of
/// its eight projected corners widened by a pixel (the projection of a box in front of the source is
/// the convex hull of its projected corners), the whole detector when a corner is not in front of
/// the source, `None` when it lies off the detector.
/// (`world_to_index` maps world points to continuous voxel indices; the box is `[lo − ½, hi + ½]`.)
pub(crate) fn footprint(
    world_to_index: &DMat4,
    lo: [usize; 3],
    hi: [usize; 3],
    view: &View,
) -> Option<(usize, usize, usize, usize)> {
    let (w, h) = (
        view.intrinsics.width as usize,
        view.intrinsics.height as usize,
    );
    if w == 0 || h == 0 {
        return None;
    }
    let whole = Some((0, w - 1, 0, h - 1));
    let index_to_world = world_to_index.inverse();
    let (mut p_lo, mut p_hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
    let (i_lo, i_hi) = (
        DVec3::from_array(lo.map(|v| v as f64 - 0.5)),
        DVec3::from_array(hi.map(|v| v as f64 + 0.5)),
    );
    for i in box_corners(i_lo, i_hi) {
        let x = index_to_world.transform_point3(i);
        if view.depth(x).is_nan() || view.depth(x) <= 1e-6 {
            return whole;
        }
        let px = view.project(x);
        if !px.is_finite() {
            return whole;
        }
        p_lo = p_lo.min(px);
        p_hi = p_hi.max(px);
    }
    let (lo, hi) = ((p_lo - 1.0).ceil(), (p_hi + 1.0).floor());
    if hi.x < 0.0 || hi.y < 0.0 || lo.x > (w - 1) as f64 || lo.y > (h - 1) as f64 {
        return None;
    }
    let clamp = |x: f64, n: usize| x.clamp(0.0, (n - 1) as f64) as usize;
    Some((
        clamp(lo.x, w),
        clamp(hi.x, w),
        clamp(lo.y, h),
        clamp(hi.y, h),
    ))
}

/// Renders the DRR of `ct` seen from `view` (see [`VolumeRenderer`]).
pub fn render_volume(
    ct: &CtVolume,
    view: &View,
    opts: &VolumeRenderOptions,
    mask: Option<&VoxelMask>,
) -> Result<ImageF32> {
    Ok(VolumeRenderer::new(ct, opts, mask)?.render(view))
}
