//! Local refinement: Levenberg–Marquardt on the normalised residual of a level's [`Objective`] with a
//! forward-difference Jacobian, kept up to date between differences by Broyden's rank-one updates.
//!
//! An iteration forms the Jacobian by differences (the six poses `p + h e_k`, rendered in parallel).
//! Each trial step solves `(JᵀJ + λ diag(JᵀJ)) δ = −Jᵀr` (Marquardt 1963) and renders the one pose
//! `p + δ`; λ ÷ 10 after an accepted step, × 10 after a rejected one. With `broyden` the Jacobian is then
//! corrected along `δ` by the secant it measured (Broyden 1965: `J += (r(p+δ) − r(p) − Jδ) δᵀ / δᵀδ`,
//! accepted or not) and the iteration goes on from the new pose with it — one render per step instead of
//! seven, the secant version of LM of Madsen, Nielsen & Tingleff (2004, §3.4) — until [`MAX_SECANTS`]
//! updates, a rejected step, or a stopping rule end it; without, every accepted step ends the iteration
//! (classical LM).
//!
//! Stopping rules, whichever comes first: the cost falls below `abs_tol`; an accepted step decreases the
//! cost by less than `rel_tol` of it, or is shorter than `step_tol` (mm-equivalent parameters, see
//! [`super::objective`]) — a step on secant updates that meets one of these is checked on a fresh
//! Jacobian first, as short steps along stale secants are no sign of an optimum; λ exceeds 10¹⁰ (no
//! descent direction left); `max_iterations` Jacobians. When no damping descends (the difference step
//! fell into a kink of the piecewise-linear DRR), the Jacobian is recomputed with a step 4× wider, up to
//! 64 h, before it stops.

use rayon::prelude::*;

use super::objective::{Evaluation, Objective, Residual};
use crate::Result;
use crate::math::cholesky_solve;

/// Settings of [`refine`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmOptions {
    /// Forward-difference step (mm-equivalent).
    pub h: f64,
    /// Most iterations: Jacobians formed by differences (six renders each), with the trial steps
    /// (one render each) taken on each of them and, with Broyden updates, on its secant updates.
    pub max_iterations: usize,
    pub rel_tol: f64,
    pub step_tol: f64,
    pub abs_tol: f64,
    /// Update the Jacobian by Broyden's secants between differences (see the module docs).
    pub broyden: bool,
}

/// Outcome of [`refine`].
#[derive(Debug, Clone, PartialEq)]
pub struct LmResult {
    pub p: [f64; 6],
    pub eval: Evaluation,
    /// Iterations taken (see [`LmOptions::max_iterations`]).
    pub iterations: usize,
    /// Stopped by a tolerance rather than the iteration cap.
    pub converged: bool,
    /// Which rule stopped it.
    pub stop: &'static str,
}

/// The Jacobian of the stacked residual, one row of six partial derivatives per residual: in host
/// memory, or on the GPU beside its residuals.
struct Jacobian {
    rows: Rows,
    /// Secant updates since it was formed by differences.
    updates: usize,
}

enum Rows {
    Host(Vec<[f64; 6]>),
    #[cfg(feature = "gpu")]
    Device(super::device::DeviceJacobian),
}

/// Secant updates after which the Jacobian is formed by differences again (Madsen et al. refresh it
/// too: the secants only correct it along the steps taken, and on a flat valley floor those become
/// short and nearly parallel; without the refresh the box-and-sphere problem of the CLI test crept to
/// the iteration cap).
const MAX_SECANTS: usize = 10;

/// Rows per parallel chunk of the Jacobian's products.
const CHUNK: usize = 4096;

impl Jacobian {
    /// Forward differences of step `h` at `p` (residual `r`): six renders, in parallel on the CPU, in one
    /// submission on the GPU.
    fn by_differences(obj: &Objective, p: &[f64; 6], r: &Residual, h: f64) -> Result<Self> {
        let rows = match r {
            Residual::Host(r) => Rows::Host(host_differences(obj, p, r, h)?),
            #[cfg(feature = "gpu")]
            Residual::Device(r) => Rows::Device(obj.device_jacobian(p, r, h)?),
        };
        Ok(Jacobian { rows, updates: 0 })
    }

    /// `JᵀJ` and `−Jᵀr`.
    #[cfg_attr(not(feature = "gpu"), allow(unused_variables))]
    fn normal_equations(&self, obj: &Objective, r: &Residual) -> Result<([[f64; 6]; 6], [f64; 6])> {
        match (&self.rows, r) {
            (Rows::Host(rows), Residual::Host(r)) => Ok(host_normal_equations(rows, r)),
            #[cfg(feature = "gpu")]
            (Rows::Device(j), Residual::Device(r)) => obj.device()?.normal_equations(j, r),
            #[cfg(feature = "gpu")]
            _ => Err(mixed()),
        }
    }

    /// Broyden's update along `delta`, which changed the residual from `r` to `rq`.
    #[cfg_attr(not(feature = "gpu"), allow(unused_variables))]
    fn secant_update(
        &mut self,
        obj: &Objective,
        delta: &[f64; 6],
        r: &Residual,
        rq: &Residual,
    ) -> Result<()> {
        match (&mut self.rows, r, rq) {
            (Rows::Host(rows), Residual::Host(r), Residual::Host(rq)) => {
                host_secant_update(rows, delta, r, rq)
            }
            #[cfg(feature = "gpu")]
            (Rows::Device(j), Residual::Device(r), Residual::Device(rq)) => {
                obj.device()?.secant_update(j, delta, r, rq)?
            }
            #[cfg(feature = "gpu")]
            _ => return Err(mixed()),
        }
        self.updates += 1;
        Ok(())
    }
}

#[cfg(feature = "gpu")]
fn mixed() -> crate::Error {
    crate::Error::Internal("a Jacobian and a residual in different memories".into())
}

/// Forward differences of step `h` at `p` (residual `r`): six renders in parallel.
fn host_differences(obj: &Objective, p: &[f64; 6], r: &[f64], h: f64) -> Result<Vec<[f64; 6]>> {
    let cols: Vec<Vec<f64>> = (0..6)
        .into_par_iter()
        .map(|k| {
            let mut q = *p;
            q[k] += h;
            let mut rk = Vec::new();
            obj.evaluate(&q, Some(&mut rk))?;
            Ok(rk)
        })
        .collect::<Result<_>>()?;
    let mut rows = vec![[0.0; 6]; r.len()];
    rows.par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(c, chunk)| {
            let i0 = c * CHUNK;
            for (j, row) in chunk.iter_mut().enumerate() {
                let i = i0 + j;
                for k in 0..6 {
                    row[k] = (cols[k][i] - r[i]) / h;
                }
            }
        });
    Ok(rows)
}

/// `JᵀJ` and `−Jᵀr`: partial sums per chunk in parallel, added in chunk order, so the result does
/// not depend on how the threads shared the work (resumed studies are byte-identical).
fn host_normal_equations(rows: &[[f64; 6]], r: &[f64]) -> ([[f64; 6]; 6], [f64; 6]) {
    let parts: Vec<[f64; 27]> = rows
        .par_chunks(CHUNK)
        .zip(r.par_chunks(CHUNK))
        .map(|(rows, r)| {
            let mut a = [0.0f64; 27];
            for (j, &x) in rows.iter().zip(r) {
                let mut n = 0;
                for p in 0..6 {
                    for q in p..6 {
                        a[n] += j[p] * j[q];
                        n += 1;
                    }
                    a[21 + p] -= j[p] * x;
                }
            }
            a
        })
        .collect();
    let mut acc = [0.0f64; 27];
    for part in &parts {
        for (x, y) in acc.iter_mut().zip(part) {
            *x += y;
        }
    }
    // `acc` holds the upper triangle row by row: entry (p, q ≥ p) at p·(11 − p)/2 + q.
    let jtj = std::array::from_fn(|p| {
        std::array::from_fn(|q| {
            let (a, b) = (p.min(q), p.max(q));
            acc[a * (11 - a) / 2 + b]
        })
    });
    (jtj, std::array::from_fn(|p| acc[21 + p]))
}

/// Broyden's update of `rows` along `delta`, which changed the residual from `r` to `rq`.
fn host_secant_update(rows: &mut [[f64; 6]], delta: &[f64; 6], r: &[f64], rq: &[f64]) {
    let dd: f64 = delta.iter().map(|x| x * x).sum();
    if dd <= 0.0 {
        return;
    }
    let d = delta.map(|x| x / dd);
    rows.par_chunks_mut(CHUNK)
        .zip(r.par_chunks(CHUNK).zip(rq.par_chunks(CHUNK)))
        .for_each(|(rows, (r, rq))| {
            for (j, (a, b)) in rows.iter_mut().zip(r.iter().zip(rq)) {
                let jd: f64 = (0..6).map(|k| j[k] * delta[k]).sum();
                let u = b - a - jd;
                for k in 0..6 {
                    j[k] += u * d[k];
                }
            }
        });
}

/// Runs Levenberg–Marquardt on `obj` from `p0`.
pub fn refine(obj: &Objective, p0: [f64; 6], opts: &LmOptions) -> Result<LmResult> {
    let mut p = p0;
    let (mut eval, mut r) = obj.residual_at(&p)?;
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut h = opts.h;
    let mut jac: Option<Jacobian> = None;
    let stop = loop {
        if eval.cost <= opts.abs_tol {
            break "abs_tol";
        }
        let j = match jac.take() {
            Some(j) if j.updates == 0 || (opts.broyden && j.updates < MAX_SECANTS) => j,
            _ => {
                if iterations >= opts.max_iterations {
                    break "max_iterations";
                }
                iterations += 1;
                Jacobian::by_differences(obj, &p, &r, h)?
            }
        };
        let (jtj, jtr) = j.normal_equations(obj, &r)?;
        let mut m = jtj;
        for (k, row) in m.iter_mut().enumerate() {
            row[k] += lambda * jtj[k][k].max(1e-12);
        }
        let Some(delta) = cholesky_solve(&m, &jtr) else {
            lambda *= 10.0;
            if lambda > 1e10 {
                break "lambda";
            }
            jac = Some(j);
            continue;
        };
        let q: [f64; 6] = std::array::from_fn(|k| p[k] + delta[k]);
        let step_len = delta.iter().map(|x| x * x).sum::<f64>().sqrt();
        let (eq, rq) = obj.residual_at(&q)?;
        let was_fresh = j.updates == 0;
        let mut j = j;
        if opts.broyden && eq.cost.is_finite() {
            j.secant_update(obj, &delta, &r, &rq)?;
        }
        if eq.cost.is_finite() && eq.cost < eval.cost {
            let rel = (eval.cost - eq.cost) / eval.cost;
            (p, r, eval) = (q, rq, eq);
            lambda = (lambda / 10.0).max(1e-9);
            h = opts.h;
            let rule = if step_len < opts.step_tol {
                Some("step_tol")
            } else if rel < opts.rel_tol {
                Some("rel_tol")
            } else {
                None
            };
            match rule {
                // A rule met by a step on secant updates is checked on a fresh Jacobian.
                Some(_) if !was_fresh => jac = None,
                Some(rule) => break rule,
                None => jac = opts.broyden.then_some(j),
            }
            continue;
        }
        if !was_fresh {
            // The secants may have drifted: differences again before damping harder.
            jac = None;
            continue;
        }
        lambda *= 10.0;
        if step_len < opts.step_tol || lambda > 1e10 {
            // No damping descends on a fresh Jacobian: widen the difference step.
            if h >= 64.0 * opts.h {
                break if lambda > 1e10 { "lambda" } else { "step_tol" };
            }
            h *= 4.0;
            lambda = 1e-3;
            jac = None;
            continue;
        }
        // Damp harder on the same Jacobian (with its one secant from the rejected step, which is
        // still a measured difference), counted as fresh so another rejection damps again.
        jac = Some(Jacobian { updates: 0, ..j });
    };
    Ok(LmResult {
        p,
        eval,
        iterations,
        converged: stop != "max_iterations",
        stop,
    })
}
