//! The X-ray image model: a radiograph-like image from a DRR line integral `L`.
//!
//! Per pixel, in this order:
//! 1. expected photon count `λ = I0 · exp(−L)` (Beer–Lambert, `I0` photons per pixel in air);
//! 2. quantum noise: the detected count `N ~ Poisson(λ)` (mean and variance `λ`), seeded per image row so
//!    the image depends on the seed alone, not on the thread count;
//! 3. detector blur: a separable Gaussian of standard deviation `σ` px (taps out to `⌈3σ⌉`, normalised,
//!    borders replicated); `σ = 0` is no blur;
//! 4. optionally the log conversion back to a line-integral estimate `L̂ = −ln(max(N, ½) / I0)` (a zero
//!    count has no finite log: it is read as half a photon).
//!
//! The model is recorded in the image's sidecar (`details.xray_model`).

use rand::SeedableRng;
use rand_distr::{Distribution, Poisson};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::ImageF32;
use crate::{Error, Result};

/// Largest blur accepted (px): past it the image is a smear, not a radiograph.
pub const MAX_BLUR_PX: f64 = 64.0;

/// Largest photon count per pixel accepted: Poisson sampling at larger λ is noise below f32 precision.
pub const MAX_PHOTONS: f64 = 1e12;

/// Parameters of the X-ray image model (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct XrayModel {
    /// Photons per pixel in air, `I0`.
    pub photons_i0: f64,
    /// Whether Poisson quantum noise is drawn (false: the expected counts themselves).
    pub poisson: bool,
    /// Gaussian detector blur σ (px); 0 = none.
    pub blur_px: f64,
    /// Seed of the Poisson noise.
    pub seed: u64,
    /// Write `L̂ = −ln(N / I0)` instead of the counts.
    pub log: bool,
}

impl XrayModel {
    /// A validated model: `I0` positive and at most [`MAX_PHOTONS`], `0 ≤ σ ≤` [`MAX_BLUR_PX`].
    pub fn new(photons_i0: f64, blur_px: f64, seed: u64, log: bool) -> Result<Self> {
        if !(photons_i0.is_finite() && photons_i0 > 0.0 && photons_i0 <= MAX_PHOTONS) {
            return Err(Error::invalid(
                "photons",
                format!(
                    "I0 = {} must be a positive number of at most {MAX_PHOTONS:e}",
                    crate::error::shown(photons_i0)
                ),
            ));
        }
        if !(blur_px.is_finite() && (0.0..=MAX_BLUR_PX).contains(&blur_px)) {
            return Err(Error::invalid(
                "blur_px",
                format!(
                    "σ = {} px must be between 0 and {MAX_BLUR_PX}",
                    crate::error::shown(blur_px)
                ),
            ));
        }
        Ok(XrayModel {
            photons_i0,
            poisson: true,
            blur_px,
            seed,
            log,
        })
    }

    /// The same model without quantum noise (expected counts, then blur and log).
    pub fn noise_free(self) -> Self {
        XrayModel {
            poisson: false,
            ..self
        }
    }

    /// The image this model makes of `line_integral`.
    pub fn apply(&self, line_integral: &ImageF32) -> ImageF32 {
        let mut counts = expected_counts(line_integral, self.photons_i0);
        if self.poisson {
            counts = poisson_counts(&counts, self.seed);
        }
        if self.blur_px > 0.0 {
            counts = gaussian_blur(&counts, self.blur_px);
        }
        if self.log {
            let i0 = self.photons_i0;
            counts
                .data
                .par_iter_mut()
                .for_each(|n| *n = -(f64::from(*n).max(0.5) / i0).ln() as f32);
        }
        counts
    }
}

/// `I0 · exp(−L)` per pixel (computed in f64).
pub fn expected_counts(line_integral: &ImageF32, i0: f64) -> ImageF32 {
    ImageF32 {
        data: line_integral
            .data
            .par_iter()
            .map(|&l| (i0 * (-f64::from(l)).exp()) as f32)
            .collect(),
        ..*line_integral
    }
}

/// A Poisson draw per pixel with mean `expected` (a non-positive or non-finite mean gives 0). Row `v` is
/// drawn from its own PCG stream seeded by `(seed, v)`.
pub fn poisson_counts(expected: &ImageF32, seed: u64) -> ImageF32 {
    let w = expected.width as usize;
    let mut out = expected.clone();
    if w == 0 {
        return out;
    }
    out.data.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        let mut rng =
            Pcg64Mcg::seed_from_u64(seed ^ (v as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        for x in row.iter_mut() {
            let lambda = f64::from(*x);
            *x = match Poisson::new(lambda) {
                Ok(p) if lambda > 0.0 => p.sample(&mut rng) as f32,
                _ => 0.0,
            };
        }
    });
    out
}

/// The normalised 1-D Gaussian taps of standard deviation `sigma` px, from `−⌈3σ⌉` to `⌈3σ⌉`.
pub(crate) fn gaussian_taps(sigma: f64) -> Vec<f64> {
    let r = (3.0 * sigma).ceil() as i64;
    let taps: Vec<f64> = (-r..=r)
        .map(|k| (-(k * k) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = taps.iter().sum();
    taps.into_iter().map(|t| t / sum).collect()
}

/// Separable Gaussian blur of standard deviation `sigma` px with replicated borders.
pub fn gaussian_blur(img: &ImageF32, sigma: f64) -> ImageF32 {
    let (w, h) = (img.width as usize, img.height as usize);
    if sigma <= 0.0 || w == 0 || h == 0 {
        return img.clone();
    }
    let taps = gaussian_taps(sigma);
    let r = (taps.len() / 2) as isize;
    let clamp = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
    // Rows first, then columns (each output pixel accumulated in f64).
    let mut tmp = vec![0f32; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(v, out)| {
        let row = &img.data[v * w..(v + 1) * w];
        for (u, o) in out.iter_mut().enumerate() {
            let s: f64 = taps
                .iter()
                .enumerate()
                .map(|(k, t)| t * f64::from(row[clamp(u as isize + k as isize - r, w)]))
                .sum();
            *o = s as f32;
        }
    });
    // Columns a whole row at a time: output row v is Σ_k t_k · (row v + k − r of `tmp`), contiguous.
    let mut data = vec![0f32; w * h];
    data.par_chunks_mut(w).enumerate().for_each_init(
        || vec![0f64; w],
        |acc, (v, out)| {
            acc.iter_mut().for_each(|a| *a = 0.0);
            for (k, t) in taps.iter().enumerate() {
                let src = &tmp[clamp(v as isize + k as isize - r, h) * w..][..w];
                for (a, &x) in acc.iter_mut().zip(src) {
                    *a += t * f64::from(x);
                }
            }
            for (o, a) in out.iter_mut().zip(acc.iter()) {
                *o = *a as f32;
            }
        },
    );
    ImageF32 {
        width: img.width,
        height: img.height,
        data,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blur_keeps_the_sum_of_an_interior_impulse_and_its_variance_is_sigma_squared() {
        let mut img = ImageF32::zeros(41, 41);
        img.data[20 * 41 + 20] = 1.0;
        let b = gaussian_blur(&img, 2.0);
        let (mut sum, mut var) = (0.0, 0.0);
        for v in 0..41 {
            for u in 0..41 {
                let x = f64::from(b.get(u, v));
                sum += x;
                var += x * (f64::from(u) - 20.0).powi(2);
            }
        }
        assert!((sum - 1.0).abs() < 1e-6, "{sum}");
        // Truncation at 3σ removes ~1% of the second moment.
        assert!((var - 4.0).abs() < 0.1, "{var}");
    }

    #[test]
    fn noise_depends_on_the_seed_not_on_the_thread_count() {
        let img = ImageF32 {
            width: 64,
            height: 64,
            data: (0..64 * 64).map(|i| (i % 17) as f32 * 0.1).collect(),
        };
        let m = XrayModel::new(1e4, 1.0, 7, true).unwrap();
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| m.apply(&img))
        };
        let a = run(1);
        assert_eq!(a, run(3));
        let other = XrayModel { seed: 8, ..m }.apply(&img);
        assert_ne!(a, other);
    }

    #[test]
    fn invalid_parameters_name_their_field() {
        let e = XrayModel::new(0.0, 1.0, 0, false).unwrap_err().to_string();
        assert!(e.contains("photons"), "{e}");
        let e = XrayModel::new(1e4, -1.0, 0, false).unwrap_err().to_string();
        assert!(e.contains("blur_px"), "{e}");
    }
}
