//! Controlled perturbations for registration experiments: a seeded generator, Gaussian pixel noise and
//! initial poses a given angle and distance from the truth.

use glam::{DVec2, DVec3};

use super::RegistrationProblem;
use crate::geometry::{RigidTransform, rotation_exp};

/// SplitMix64 (Steele, Lea & Flood 2014): a tiny, seedable, statistically sound generator, so results
/// are reproducible from a seed without a global RNG.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `(0, 1)`.
    pub fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    /// Standard normal by the Box–Muller transform.
    pub fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// A uniformly distributed unit vector.
    pub fn unit_vector(&mut self) -> DVec3 {
        loop {
            let v = DVec3::new(self.normal(), self.normal(), self.normal());
            if v.length() > 1e-9 {
                return v.normalize();
            }
        }
    }
}

/// Adds independent Gaussian noise of standard deviation `sigma_px` to both coordinates of every
/// observation.
pub fn add_pixel_noise(
    problem: &RegistrationProblem,
    sigma_px: f64,
    seed: u64,
) -> RegistrationProblem {
    let mut rng = SplitMix64::new(seed);
    let mut out = problem.clone();
    for ov in &mut out.views {
        for (_, x) in &mut ov.observed {
            *x += DVec2::new(rng.normal(), rng.normal()) * sigma_px;
        }
    }
    out
}

/// `truth` rotated by exactly `rot_deg` about a random axis through `centre` (world) and translated by
/// exactly `trans_mm` in a random direction.
pub fn perturb_pose(
    truth: &RigidTransform,
    rot_deg: f64,
    trans_mm: f64,
    centre: DVec3,
    seed: u64,
) -> RigidTransform {
    let mut rng = SplitMix64::new(seed);
    let r = rotation_exp(rng.unit_vector() * rot_deg.to_radians());
    let dt = rng.unit_vector() * trans_mm;
    RigidTransform {
        rotation: r * truth.rotation,
        translation: r * (truth.translation - centre) + centre + dt,
    }
}
