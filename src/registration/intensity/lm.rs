//! Local refinement: Levenberg–Marquardt on the normalised residual of a level's [`Objective`] with a
//! forward-difference Jacobian.
//!
//! Each iteration renders the six poses `p + h e_k` (in parallel), forms `JᵀJ` and `Jᵀr`, and
//! solves `(JᵀJ + λ diag(JᵀJ)) δ = −Jᵀr` (Marquardt 1963; λ ÷ 10 after an accepted step, × 10 after a
//! rejected one). Stopping rules, whichever comes first: the cost falls below `abs_tol`; an accepted step
//! decreases the cost by less than `rel_tol` of it; the step is shorter than `step_tol` (mm-equivalent
//! parameters, see [`super::objective`]); λ exceeds 10¹⁰ (no descent direction left); `max_iterations`.
//! When no damping descends (the difference step fell into a kink of the piecewise-linear DRR), the
//! Jacobian is recomputed with a step 4× wider, up to 64 h, before it stops.

use rayon::prelude::*;

use super::objective::{Evaluation, Objective};
use crate::Result;
use crate::math::cholesky_solve;

/// Settings of [`refine`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmOptions {
    /// Forward-difference step (mm-equivalent).
    pub h: f64,
    pub max_iterations: usize,
    pub rel_tol: f64,
    pub step_tol: f64,
    pub abs_tol: f64,
}

/// Outcome of [`refine`].
#[derive(Debug, Clone, PartialEq)]
pub struct LmResult {
    pub p: [f64; 6],
    pub eval: Evaluation,
    pub iterations: usize,
    /// Stopped by a tolerance rather than the iteration cap.
    pub converged: bool,
    /// Which rule stopped it.
    pub stop: &'static str,
}

/// Runs Levenberg–Marquardt on `obj` from `p0`.
pub fn refine(obj: &Objective, p0: [f64; 6], opts: &LmOptions) -> Result<LmResult> {
    let mut p = p0;
    let mut r = Vec::new();
    let mut eval = obj.evaluate(&p, Some(&mut r))?;
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut h = opts.h;
    let stop = 'outer: loop {
        if eval.cost <= opts.abs_tol {
            break "abs_tol";
        }
        if iterations >= opts.max_iterations {
            break "max_iterations";
        }
        iterations += 1;
        let cols: Vec<Vec<f64>> = (0..6)
            .into_par_iter()
            .map(|k| {
                let mut q = p;
                q[k] += h;
                let mut rk = Vec::new();
                obj.evaluate(&q, Some(&mut rk))?;
                Ok(rk.iter().zip(&r).map(|(a, b)| (a - b) / h).collect())
            })
            .collect::<Result<_>>()?;
        let mut jtj = [[0.0; 6]; 6];
        let mut jtr = [0.0; 6];
        for a in 0..6 {
            jtr[a] = -cols[a].iter().zip(&r).map(|(j, x)| j * x).sum::<f64>();
            for b in a..6 {
                let v: f64 = cols[a].iter().zip(&cols[b]).map(|(x, y)| x * y).sum();
                jtj[a][b] = v;
                jtj[b][a] = v;
            }
        }
        // Damping loop: `Some(stop)` ends the refinement, `None` recomputes the Jacobian.
        let stuck = loop {
            let mut m = jtj;
            for (k, row) in m.iter_mut().enumerate() {
                row[k] += lambda * jtj[k][k].max(1e-12);
            }
            let Some(delta) = cholesky_solve(&m, &jtr) else {
                lambda *= 10.0;
                if lambda > 1e10 {
                    break true;
                }
                continue;
            };
            let q: [f64; 6] = std::array::from_fn(|k| p[k] + delta[k]);
            let step_len = delta.iter().map(|x| x * x).sum::<f64>().sqrt();
            let mut rq = Vec::new();
            let eq = obj.evaluate(&q, Some(&mut rq))?;
            if eq.cost.is_finite() && eq.cost < eval.cost {
                let rel = (eval.cost - eq.cost) / eval.cost;
                (p, r, eval) = (q, rq, eq);
                lambda = (lambda / 10.0).max(1e-9);
                h = opts.h;
                if step_len < opts.step_tol {
                    break 'outer "step_tol";
                }
                if rel < opts.rel_tol {
                    break 'outer "rel_tol";
                }
                break false;
            }
            lambda *= 10.0;
            if step_len < opts.step_tol || lambda > 1e10 {
                break true;
            }
        };
        if stuck {
            if h >= 64.0 * opts.h {
                break if lambda > 1e10 { "lambda" } else { "step_tol" };
            }
            h *= 4.0;
            lambda = 1e-3;
        }
    };
    Ok(LmResult {
        p,
        eval,
        iterations,
        converged: stop != "max_iterations",
        stop,
    })
}
