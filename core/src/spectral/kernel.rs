//! The per-pixel energy sum in f32 lanes: `L = −ln Σ_b w_b · exp(−Σ_c t_cb · a_c)`, evaluated as a
//! log-sum-exp (`y_b = Σ_c t_cb a_c − ln w_b`, `m = min_b y_b`, `L = m − ln Σ_b exp(m − y_b)`), so that
//! a pixel behind metal whose every bin underflows still has a finite line integral, with an exp that
//! vectorises (Cephes' `expf` polynomial, ≤ 2 ulp) over 8 bins at a time. Machines with AVX2 run the same
//! code compiled for it; no fused multiply-adds are used, so every path gives the same bits.
//!
//! [`super::SpectralModel::line_integral`] is the f64 reference it is tested against.

/// Bins per lane group.
const LANES: usize = 8;

/// The model's tables in the kernel's layout: bins padded to a multiple of [`LANES`].
#[derive(Debug, Clone)]
pub struct EnergyKernel {
    channels: usize,
    padded: usize,
    /// `t[c * padded + b]`; 0 in the padding.
    table: Vec<f32>,
    /// `−ln w_b`; a large value in the padding and for bins of weight 0 (their terms vanish).
    neg_log_w: Vec<f32>,
}

/// Where a term counts as nothing: `exp(−87) ≈ 1.6e−38`, below f32's resolution of any sum holding 1.
const CLAMP: f32 = 87.0;

impl EnergyKernel {
    /// The kernel of per-bin weights (summing to 1) and the channel table `table[c * bins + b]`.
    pub fn new(weights: &[f64], table: &[f64]) -> Self {
        let bins = weights.len();
        let channels = table.len() / bins.max(1);
        let padded = bins.div_ceil(LANES) * LANES;
        let mut t = vec![0f32; channels * padded];
        for c in 0..channels {
            for b in 0..bins {
                t[c * padded + b] = table[c * bins + b] as f32;
            }
        }
        let mut neg_log_w = vec![1e30f32; padded];
        for (b, &w) in weights.iter().enumerate() {
            if w > 0.0 {
                neg_log_w[b] = -(w.ln()) as f32;
            }
        }
        EnergyKernel {
            channels,
            padded,
            table: t,
            neg_log_w,
        }
    }

    /// The layout the GPU's energy sum reads (`render/gpu/energy.wgsl`): channels, bins per channel
    /// (padded), the table `t[c · padded + b]` and `−ln w_b`.
    #[cfg_attr(not(feature = "gpu"), allow(dead_code))]
    pub(crate) fn layout(&self) -> (usize, usize, &[f32], &[f32]) {
        (self.channels, self.padded, &self.table, &self.neg_log_w)
    }

    /// A scratch buffer for [`Self::line_integral`].
    pub fn scratch(&self) -> Vec<f32> {
        vec![0.0; self.padded]
    }

    /// The polychromatic line integral of channel values `a` (0 when all are 0).
    pub fn line_integral(&self, a: &[f32], y: &mut [f32]) -> f32 {
        if a.iter().all(|&x| x == 0.0) {
            return 0.0;
        }
        #[cfg(target_arch = "x86_64")]
        {
            if std::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU has AVX2, checked just above.
                return unsafe { self.line_integral_avx2(a, y) };
            }
        }
        self.line_integral_generic(a, y)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn line_integral_avx2(&self, a: &[f32], y: &mut [f32]) -> f32 {
        self.line_integral_generic(a, y)
    }

    #[inline(always)]
    fn line_integral_generic(&self, a: &[f32], y: &mut [f32]) -> f32 {
        let p = self.padded;
        y.copy_from_slice(&self.neg_log_w);
        for (c, &ac) in a.iter().enumerate().take(self.channels) {
            if ac != 0.0 {
                let row = &self.table[c * p..(c + 1) * p];
                for (yb, &t) in y.iter_mut().zip(row) {
                    *yb += t * ac;
                }
            }
        }
        let mut m = [f32::INFINITY; LANES];
        for chunk in y.chunks_exact(LANES) {
            for l in 0..LANES {
                m[l] = m[l].min(chunk[l]);
            }
        }
        let m = m.iter().copied().fold(f32::INFINITY, f32::min);
        let mut acc = [0f32; LANES];
        for chunk in y.chunks_exact(LANES) {
            for l in 0..LANES {
                acc[l] += exp_neg(chunk[l] - m);
            }
        }
        let sum: f32 = acc.iter().sum();
        m - sum.ln()
    }
}

/// `exp(−x)` for `x ≥ 0` (Cephes `expf`: range reduction by ln 2, a degree-6 polynomial, the power of
/// two from the exponent bits), `x` clamped to [`CLAMP`].
#[inline(always)]
fn exp_neg(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const C1: f32 = 0.693_359_4;
    const C2: f32 = -2.121_944_4e-4;
    const ROUND: f32 = 12_582_912.0; // 1.5 · 2^23: adding and subtracting it rounds to an integer
    let x = -(x.min(CLAMP));
    // `t` is ROUND + n exactly (n = round(x · log2 e), an integer in [−126, 0]), so its bits are ROUND's
    // plus n: the exponent is read off them in integer lanes (a float-to-int cast would not vectorise).
    let t = x * LOG2E + ROUND;
    let n = t - ROUND;
    let n_int = t.to_bits().wrapping_sub(ROUND.to_bits());
    let r = x - n * C1 - n * C2;
    let p = (((((1.987_569_1e-4 * r + 1.398_2e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
        + 1.666_666_5e-1)
        * r
        + 0.5)
        * r
        * r
        + r
        + 1.0;
    let scale = f32::from_bits(n_int.wrapping_add(127) << 23);
    p * scale
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_is_within_two_ulp_of_the_library_over_its_range() {
        let mut worst = 0f64;
        for i in 0..86_990 {
            let x = i as f32 * 1e-3;
            let got = f64::from(exp_neg(x));
            let want = (-f64::from(x)).exp();
            worst = worst.max((got / want - 1.0).abs());
        }
        assert!(worst < 2.5e-7, "{worst}");
        assert!(exp_neg(1e9) > 0.0 && exp_neg(1e9) < 2e-38);
    }

    #[test]
    fn matches_the_f64_energy_sum_and_stays_finite_behind_metal() {
        // The last case is far behind metal: every bin's exp(−x) underflows even f64 (x > 600). Three channels over 71 bins with weights and attenuation of realistic spread.
        let bins = 71;
        let raw: Vec<f64> = (0..bins)
            .map(|b| ((b as f64) * 0.21).sin().abs() + 0.05)
            .collect();
        let total: f64 = raw.iter().sum();
        let w: Vec<f64> = raw.iter().map(|x| x / total).collect();
        let table: Vec<f64> = (0..3 * bins)
            .map(|i| 0.02 + 3.0 / (1.0 + (i % bins) as f64).powi(2) * (1 + i / bins) as f64)
            .collect();
        let k = EnergyKernel::new(&w, &table);
        let mut y = k.scratch();
        // −ln Σ w exp(−x) in f64, shifted by the smallest exponent so that it stays finite.
        let reference = |a: &[f64]| {
            let x: Vec<f64> = (0..bins)
                .map(|b| (0..3).map(|c| table[c * bins + b] * a[c]).sum::<f64>())
                .collect();
            let m = x.iter().copied().fold(f64::INFINITY, f64::min);
            let s: f64 = (0..bins).map(|b| w[b] * (m - x[b]).exp()).sum();
            m - s.ln()
        };
        for a in [
            [0.0, 0.0, 0.3],
            [1.0, 2.0, 0.0],
            [10.0, 0.5, 40.0],
            [0.01, 0.0, 0.0],
            [1e4, 1e4, 1e4],
        ] {
            let got = f64::from(k.line_integral(&a.map(|x| x as f32), &mut y));
            let want = reference(&a);
            assert!(
                (got - want).abs() < 2e-6 * want.max(1.0),
                "{a:?}: {got} vs {want}"
            );
        }
        assert_eq!(k.line_integral(&[0.0; 3], &mut y), 0.0);
    }
}
