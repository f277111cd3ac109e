//! A compact (μ/μ_w, λ)-CMA-ES (Hansen, "The CMA Evolution Strategy: A Tutorial", 2016, with the
//! tutorial's default parameters), the derivative-free global stage of intensity registration.
//!
//! Each generation samples `x_i = m + σ B D z_i` (`C = B D² Bᵀ` by Jacobi, [`crate::math::symmetric_eigen`]),
//! evaluates the population in parallel, recombines the best μ with log weights, and adapts the evolution
//! paths, `C` (rank-one and rank-μ updates) and `σ` (cumulative step-size adaptation). Stopping rules,
//! whichever comes first: `max_generations`; `σ · √λ_max(C) < tol_x` (the search distribution is smaller
//! than `tol_x` in every direction); the best cost of the last 10 generations and the current
//! generation's costs spanning less than `tol_fun`.

use rayon::prelude::*;

use crate::Result;
use crate::math::symmetric_eigen;
use crate::registration::SplitMix64;

/// Settings of [`minimize`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CmaesOptions {
    /// Initial step size (same units as the parameters).
    pub sigma0: f64,
    /// Population size; `None` = `4 + ⌊3 ln n⌋`.
    pub lambda: Option<usize>,
    pub max_generations: usize,
    pub tol_x: f64,
    pub tol_fun: f64,
    pub seed: u64,
}

/// Outcome of [`minimize`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CmaesResult<const N: usize> {
    pub best: [f64; N],
    pub best_cost: f64,
    pub generations: usize,
    pub evaluations: usize,
    /// Which rule stopped it: `max_generations`, `tol_x` or `tol_fun`.
    pub stop: &'static str,
}

/// Minimises `f` from `x0` (see the module documentation). `f` is evaluated in parallel within a
/// generation; a non-finite cost ranks last.
pub fn minimize<const N: usize>(
    f: impl Fn(&[f64; N]) -> Result<f64> + Sync,
    x0: [f64; N],
    opts: &CmaesOptions,
) -> Result<CmaesResult<N>> {
    let n = N as f64;
    let lambda = opts
        .lambda
        .unwrap_or(4 + (3.0 * n.ln()).floor() as usize)
        .max(4);
    let mu = lambda / 2;
    let raw: Vec<f64> = (1..=mu)
        .map(|i| (mu as f64 + 0.5).ln() - (i as f64).ln())
        .collect();
    let wsum: f64 = raw.iter().sum();
    let w: Vec<f64> = raw.iter().map(|x| x / wsum).collect();
    let mu_eff = 1.0 / w.iter().map(|x| x * x).sum::<f64>();
    let c_sigma = (mu_eff + 2.0) / (n + mu_eff + 5.0);
    let d_sigma = 1.0 + 2.0 * (((mu_eff - 1.0) / (n + 1.0)).sqrt() - 1.0).max(0.0) + c_sigma;
    let c_c = (4.0 + mu_eff / n) / (n + 4.0 + 2.0 * mu_eff / n);
    let c1 = 2.0 / ((n + 1.3).powi(2) + mu_eff);
    let c_mu = (1.0 - c1).min(2.0 * (mu_eff - 2.0 + 1.0 / mu_eff) / ((n + 2.0).powi(2) + mu_eff));
    let chi_n = n.sqrt() * (1.0 - 1.0 / (4.0 * n) + 1.0 / (21.0 * n * n));

    let mut rng = SplitMix64::new(opts.seed);
    let mut m = x0;
    let mut sigma = opts.sigma0;
    let mut c = [[0.0; N]; N];
    for (i, row) in c.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    let (mut p_sigma, mut p_c) = ([0.0; N], [0.0; N]);
    let mut best = (x0, f(&x0)?);
    let mut evaluations = 1;
    let mut history: Vec<f64> = Vec::new();
    let mut generations = 0;
    let stop = loop {
        if generations >= opts.max_generations {
            break "max_generations";
        }
        generations += 1;
        let eig = symmetric_eigen(c);
        let d: [f64; N] = eig.values.map(|v| v.max(1e-300).sqrt());
        let b = eig.vectors; // rows are eigenvectors
        // y = B D z (B's columns are eigenvectors: y = Σ_k d_k z_k v_k).
        let ys: Vec<[f64; N]> = (0..lambda)
            .map(|_| {
                let mut y = [0.0; N];
                for k in 0..N {
                    let zk = rng.normal() * d[k];
                    for (yi, bki) in y.iter_mut().zip(&b[k]) {
                        *yi += zk * bki;
                    }
                }
                y
            })
            .collect();
        let xs: Vec<[f64; N]> = ys
            .iter()
            .map(|y| std::array::from_fn(|i| m[i] + sigma * y[i]))
            .collect();
        let costs: Vec<f64> = xs.par_iter().map(&f).collect::<Result<_>>()?;
        evaluations += lambda;
        let mut order: Vec<usize> = (0..lambda).collect();
        let key = |i: usize| {
            if costs[i].is_finite() {
                costs[i]
            } else {
                f64::INFINITY
            }
        };
        order.sort_by(|&a, &b| key(a).total_cmp(&key(b)));
        if key(order[0]) < best.1 {
            best = (xs[order[0]], costs[order[0]]);
        }
        // Recombination.
        let mut y_w = [0.0; N];
        for (wi, &i) in w.iter().zip(&order) {
            for k in 0..N {
                y_w[k] += wi * ys[i][k];
            }
        }
        for k in 0..N {
            m[k] += sigma * y_w[k];
        }
        // C^{-1/2} y_w = B D⁻¹ Bᵀ y_w.
        let mut inv_sqrt = [0.0; N];
        for k in 0..N {
            let proj: f64 = (0..N).map(|i| b[k][i] * y_w[i]).sum::<f64>() / d[k];
            for i in 0..N {
                inv_sqrt[i] += proj * b[k][i];
            }
        }
        let cs = (c_sigma * (2.0 - c_sigma) * mu_eff).sqrt();
        for k in 0..N {
            p_sigma[k] = (1.0 - c_sigma) * p_sigma[k] + cs * inv_sqrt[k];
        }
        let ps_norm = p_sigma.iter().map(|x| x * x).sum::<f64>().sqrt();
        let h_sigma = ps_norm / (1.0 - (1.0 - c_sigma).powi(2 * generations as i32)).sqrt()
            < (1.4 + 2.0 / (n + 1.0)) * chi_n;
        let hs = if h_sigma { 1.0 } else { 0.0 };
        let cc = (c_c * (2.0 - c_c) * mu_eff).sqrt();
        for k in 0..N {
            p_c[k] = (1.0 - c_c) * p_c[k] + hs * cc * y_w[k];
        }
        let keep = 1.0 - c1 - c_mu + (1.0 - hs) * c1 * c_c * (2.0 - c_c);
        for i in 0..N {
            for j in 0..N {
                let rank_mu: f64 = w
                    .iter()
                    .zip(&order)
                    .map(|(wk, &s)| wk * ys[s][i] * ys[s][j])
                    .sum();
                c[i][j] = keep * c[i][j] + c1 * p_c[i] * p_c[j] + c_mu * rank_mu;
            }
        }
        sigma *= ((c_sigma / d_sigma) * (ps_norm / chi_n - 1.0)).exp();

        let gen_best = key(order[0]);
        history.push(gen_best);
        let max_sd = sigma * d.iter().copied().fold(0.0, f64::max);
        if max_sd < opts.tol_x {
            break "tol_x";
        }
        if history.len() >= 10 {
            let recent = &history[history.len() - 10..];
            let lo = recent.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = recent.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let span_gen = key(order[lambda - 1]).min(1e300) - gen_best;
            if hi - lo < opts.tol_fun && span_gen < opts.tol_fun {
                break "tol_fun";
            }
        }
    };
    Ok(CmaesResult {
        best: best.0,
        best_cost: best.1,
        generations,
        evaluations,
        stop,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_minimum_of_a_rotated_ill_conditioned_quadratic_and_of_rosenbrock() {
        let opts = CmaesOptions {
            sigma0: 1.0,
            lambda: None,
            max_generations: 2000,
            tol_x: 1e-9,
            tol_fun: 1e-18,
            seed: 3,
        };
        let target = [1.0, -2.0, 0.5, 3.0, 0.0, -1.0];
        let ellipsoid = |x: &[f64; 6]| -> Result<f64> {
            // Axis scales 1 … 1e3 in a rotated frame (pairs mixed).
            let mut s = 0.0;
            for k in 0..3 {
                let (a, b) = (x[2 * k] - target[2 * k], x[2 * k + 1] - target[2 * k + 1]);
                let (u, v) = ((a + b) / 2f64.sqrt(), (a - b) / 2f64.sqrt());
                s += 10f64.powi(k as i32) * u * u + 10f64.powi(k as i32 + 3) * v * v;
            }
            Ok(s)
        };
        let r = minimize(ellipsoid, [0.0; 6], &opts).unwrap();
        for (a, b) in r.best.iter().zip(target) {
            assert!((a - b).abs() < 1e-5, "{:?}", r.best);
        }
        let rosen = |x: &[f64; 4]| -> Result<f64> {
            Ok((0..3)
                .map(|i| 100.0 * (x[i + 1] - x[i] * x[i]).powi(2) + (1.0 - x[i]).powi(2))
                .sum())
        };
        let r = minimize(rosen, [-1.0, 1.0, -1.0, 1.0], &opts).unwrap();
        assert!(
            r.best.iter().all(|v| (v - 1.0).abs() < 1e-4),
            "{:?}",
            r.best
        );
    }
}
