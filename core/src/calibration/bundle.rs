//! Levenberg–Marquardt refinement of one shared `K` (skew free or fixed) and each image's phantom →
//! camera pose on the reprojection error, its analytic Jacobian, and the first-order covariance
//! `σ² (JᵀJ)⁻¹` of the estimate.
//!
//! Parameters: `fx, fy, cx, cy` (then `s` when skew is free), then per image a left increment
//! `(δω, δt)` of its pose, `R ← exp([δω]×) R`, `t ← t + δt`, so `∂p/∂δω = −[R X]×`, `∂p/∂δt = I` for
//! the camera-frame point `p = R X + t`. Damping follows Marquardt: `(JᵀJ + λ diag JᵀJ) δ = Jᵀ r`.

use glam::{DMat3, DVec2, DVec3};
use nalgebra::{DMatrix, DVector};

use super::acquisition::CalibrationImage;
use crate::geometry::{Intrinsics, RigidTransform, View, rotation_exp};
use crate::{Error, Result};

/// The unknowns of a calibration: one K and a pose per image.
#[derive(Debug, Clone, PartialEq)]
pub struct Geometry {
    pub k: Intrinsics,
    /// Phantom → camera, one per image.
    pub poses: Vec<RigidTransform>,
}

/// Whether the skew `s = K[0][1]` is estimated or held at its starting value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Skew {
    Free,
    Fixed,
}

impl Skew {
    fn n(self) -> usize {
        match self {
            Skew::Free => 5,
            Skew::Fixed => 4,
        }
    }
}

/// Number of unknowns.
pub fn unknowns(skew: Skew, images: usize) -> usize {
    skew.n() + 6 * images
}

/// Number of residuals (two per observed BB).
pub fn residual_count(images: &[CalibrationImage]) -> usize {
    2 * images.iter().map(|im| im.observed.len()).sum::<usize>()
}

fn view_of(g: &Geometry, j: usize) -> View {
    View::new("", g.k, g.poses[j])
}

/// Residuals `observed − projected`, image by image, u then v.
pub fn residuals(g: &Geometry, images: &[CalibrationImage], bbs: &[DVec3]) -> DVector<f64> {
    let mut r = Vec::with_capacity(residual_count(images));
    for (j, im) in images.iter().enumerate() {
        let v = view_of(g, j);
        for &(i, x) in &im.observed {
            let d = x - v.project(bbs[i]);
            r.push(d.x);
            r.push(d.y);
        }
    }
    DVector::from_vec(r)
}

/// Root-mean-square reprojection error per coordinate, `sqrt(Σ r² / n)` over the `n` residuals (px).
pub fn rms(g: &Geometry, images: &[CalibrationImage], bbs: &[DVec3]) -> f64 {
    let r = residuals(g, images, bbs);
    (r.norm_squared() / r.len().max(1) as f64).sqrt()
}

/// One observed BB's two Jacobian rows (u, then v): the K part (`fx, fy, cx, cy, s`; the `s` entry is
/// used only when the skew is free) and the pose part (`δω, δt`).
fn point_rows(k: &Intrinsics, pose: &RigidTransform, x: DVec3) -> [([f64; 5], [f64; 6]); 2] {
    let q = pose.rotation * x;
    let p = q + pose.translation;
    let iz = 1.0 / p.z;
    let (xn, yn) = (p.x * iz, p.y * iz);
    let du = DVec3::new(
        k.fx * iz,
        k.skew * iz,
        -(k.fx * p.x + k.skew * p.y) * iz * iz,
    );
    let dv = DVec3::new(0.0, k.fy * iz, -k.fy * p.y * iz * iz);
    // a · (−[q]× δω) = (q × a) · δω.
    let pose_row = |a: DVec3| {
        let w = q.cross(a);
        [w.x, w.y, w.z, a.x, a.y, a.z]
    };
    [
        ([xn, 0.0, 1.0, 0.0, yn], pose_row(du)),
        ([0.0, yn, 0.0, 1.0, 0.0], pose_row(dv)),
    ]
}

/// The Jacobian `∂ projected / ∂ parameters` (rows as in [`residuals`]).
pub fn jacobian(
    g: &Geometry,
    images: &[CalibrationImage],
    bbs: &[DVec3],
    skew: Skew,
) -> DMatrix<f64> {
    let nk = skew.n();
    let mut j = DMatrix::zeros(residual_count(images), unknowns(skew, images.len()));
    let mut row = 0;
    for (m, im) in images.iter().enumerate() {
        let col = nk + 6 * m;
        for &(i, _) in &im.observed {
            for (kr, pr) in point_rows(&g.k, &g.poses[m], bbs[i]) {
                for c in 0..nk {
                    j[(row, c)] = kr[c];
                }
                for c in 0..6 {
                    j[(row, col + c)] = pr[c];
                }
                row += 1;
            }
        }
    }
    j
}

/// `JᵀJ` and `Jᵀr` accumulated point by point (each row touches only K and one pose, so this costs a
/// small fraction of forming the dense `J`), with `r = observed − projected`.
fn normal_equations(
    g: &Geometry,
    images: &[CalibrationImage],
    bbs: &[DVec3],
    skew: Skew,
    r: &DVector<f64>,
) -> (DMatrix<f64>, DVector<f64>) {
    let nk = skew.n();
    let n = unknowns(skew, images.len());
    let mut jtj = DMatrix::zeros(n, n);
    let mut jtr = DVector::zeros(n);
    let mut row = 0;
    let mut idx = [0usize; 11];
    let mut val = [0.0f64; 11];
    for (m, im) in images.iter().enumerate() {
        let col = nk + 6 * m;
        for &(i, _) in &im.observed {
            for (kr, pr) in point_rows(&g.k, &g.poses[m], bbs[i]) {
                let len = nk + 6;
                for c in 0..nk {
                    (idx[c], val[c]) = (c, kr[c]);
                }
                for c in 0..6 {
                    (idx[nk + c], val[nk + c]) = (col + c, pr[c]);
                }
                let ri = r[row];
                for a in 0..len {
                    jtr[idx[a]] += val[a] * ri;
                    for b in 0..=a {
                        jtj[(idx[a], idx[b])] += val[a] * val[b];
                    }
                }
                row += 1;
            }
        }
    }
    // Mirror the lower triangle (every index pair above was visited with idx[a] ≥ idx[b]).
    for a in 0..n {
        for b in 0..a {
            jtj[(b, a)] = jtj[(a, b)];
        }
    }
    (jtj, jtr)
}

fn apply(g: &Geometry, delta: &DVector<f64>, skew: Skew) -> Result<Geometry> {
    let mut k = g.k;
    k.fx += delta[0];
    k.fy += delta[1];
    k.cx += delta[2];
    k.cy += delta[3];
    if skew == Skew::Free {
        k.skew += delta[4];
    }
    k.validate()?;
    let nk = skew.n();
    let poses = g
        .poses
        .iter()
        .enumerate()
        .map(|(m, p)| {
            let c = nk + 6 * m;
            let w = DVec3::new(delta[c], delta[c + 1], delta[c + 2]);
            let dt = DVec3::new(delta[c + 3], delta[c + 4], delta[c + 5]);
            let r: DMat3 = rotation_exp(w);
            RigidTransform::new(r * p.rotation, p.translation + dt)
        })
        .collect();
    Ok(Geometry { k, poses })
}

/// The outcome of a refinement.
#[derive(Debug, Clone, PartialEq)]
pub struct Refined {
    pub geometry: Geometry,
    /// RMS reprojection error per coordinate (px).
    pub rms_px: f64,
    pub iterations: usize,
}

/// Levenberg–Marquardt from `init` (at most `max_iterations`); stops when the relative cost decrease
/// falls below 1e-15 or a rejected step is below 1e-14 of the parameters.
pub fn refine(
    init: &Geometry,
    images: &[CalibrationImage],
    bbs: &[DVec3],
    skew: Skew,
    max_iterations: usize,
) -> Result<Refined> {
    let n = unknowns(skew, images.len());
    if residual_count(images) < n {
        return Err(Error::invalid(
            "phantom",
            format!(
                "{} residuals for {n} unknowns: too few BBs for the calibration",
                residual_count(images)
            ),
        ));
    }
    let mut g = init.clone();
    let mut r = residuals(&g, images, bbs);
    let mut f = r.norm_squared();
    if !f.is_finite() {
        return Err(Error::Numerical(
            "calibration: the initial reprojection error is not finite".into(),
        ));
    }
    let mut lambda = 1e-6;
    let mut iterations = 0;
    'outer: while iterations < max_iterations && f > 0.0 {
        iterations += 1;
        let (jtj, jtr) = normal_equations(&g, images, bbs, skew, &r);
        loop {
            let mut a = jtj.clone();
            for d in 0..n {
                a[(d, d)] += lambda * jtj[(d, d)].max(1e-300);
            }
            let Some(ch) = a.cholesky() else {
                lambda *= 10.0;
                if lambda > 1e16 {
                    return Err(Error::Numerical(
                        "calibration: the normal equations are singular (degenerate BB layout)"
                            .into(),
                    ));
                }
                continue;
            };
            let delta = ch.solve(&jtr);
            let candidate = apply(&g, &delta, skew);
            let (cand_r, f_new) = match &candidate {
                Ok(c) => {
                    let cr = residuals(c, images, bbs);
                    let fn_ = cr.norm_squared();
                    (Some(cr), fn_)
                }
                Err(_) => (None, f64::INFINITY),
            };
            let step = delta.rows(0, 4).abs().max() / g.k.fx.max(1.0)
                + (skew.n()..n).map(|i| delta[i].abs()).fold(0.0, f64::max) * 1e-3;
            if f_new.is_finite() && f_new <= f {
                let rel = (f - f_new) / f;
                g = candidate?;
                r = cand_r.unwrap_or(r);
                f = f_new;
                lambda = (lambda / 10.0).max(1e-15);
                if rel < 1e-15 {
                    break 'outer;
                }
                break;
            }
            if step < 1e-15 {
                break 'outer;
            }
            lambda *= 10.0;
            if lambda > 1e16 {
                break 'outer;
            }
        }
    }
    Ok(Refined {
        rms_px: (f / r.len().max(1) as f64).sqrt(),
        geometry: g,
        iterations,
    })
}

/// The first-order covariance `σ² (JᵀJ)⁻¹` of every parameter at `g` (order as in [`jacobian`]).
pub fn covariance(
    g: &Geometry,
    images: &[CalibrationImage],
    bbs: &[DVec3],
    skew: Skew,
    sigma_px: f64,
) -> Result<DMatrix<f64>> {
    let j = jacobian(g, images, bbs, skew);
    let jtj = j.tr_mul(&j);
    let inv = jtj.cholesky().map(|c| c.inverse()).ok_or_else(|| {
        Error::Numerical("calibration: JᵀJ is singular (the parameters are not determined)".into())
    })?;
    Ok(inv * (sigma_px * sigma_px))
}

/// Root-mean-square distance of `observed` from the projection of `bbs` through `view` (px per coordinate).
pub fn view_rms(view: &View, observed: &[(usize, DVec2)], bbs: &[DVec3]) -> f64 {
    let s: f64 = observed
        .iter()
        .map(|&(i, x)| (x - view.project(bbs[i])).length_squared())
        .sum();
    (s / (2 * observed.len()).max(1) as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A skewed K, two poses and BBs off a plane, observed with offsets so that `r ≠ 0`.
    fn fixture() -> (Geometry, Vec<CalibrationImage>, Vec<DVec3>) {
        let k = Intrinsics {
            fx: 4400.0,
            fy: 4550.0,
            skew: 3.0,
            cx: 500.0,
            cy: 530.0,
            width: 1024,
            height: 1024,
        };
        let poses = vec![
            RigidTransform::new(
                rotation_exp(DVec3::new(0.1, -0.2, 0.05)),
                DVec3::new(5.0, -3.0, 950.0),
            ),
            RigidTransform::new(
                rotation_exp(DVec3::new(-0.3, 1.2, 0.1)),
                DVec3::new(-4.0, 2.0, 1010.0),
            ),
        ];
        let bbs: Vec<DVec3> = (0..24)
            .map(|i| {
                let a = f64::from(i) * 0.7;
                DVec3::new(40.0 * a.cos(), 40.0 * a.sin(), f64::from(i) * 3.0 - 30.0)
            })
            .collect();
        let g = Geometry { k, poses };
        let images = (0..2)
            .map(|m| {
                let v = view_of(&g, m);
                CalibrationImage {
                    view: format!("v{m}"),
                    phantom_to_camera: g.poses[m],
                    phantom_to_world: RigidTransform::IDENTITY,
                    observed: bbs
                        .iter()
                        .enumerate()
                        .map(|(i, &x)| (i, v.project(x) + DVec2::new(0.3 * (i % 3) as f64, -0.2)))
                        .collect(),
                }
            })
            .collect();
        (g, images, bbs)
    }

    #[test]
    fn jacobian_matches_central_differences() {
        let (g, images, bbs) = fixture();
        let j = jacobian(&g, &images, &bbs, Skew::Free);
        let n = unknowns(Skew::Free, images.len());
        for c in 0..n {
            let h = if c < 5 { 1e-3 } else { 1e-6 };
            let mut d = DVector::zeros(n);
            d[c] = h;
            let plus = residuals(&apply(&g, &d, Skew::Free).unwrap(), &images, &bbs);
            d[c] = -h;
            let minus = residuals(&apply(&g, &d, Skew::Free).unwrap(), &images, &bbs);
            // residual = observed − projected, so ∂projected = −∂residual.
            let fd = (minus - plus) / (2.0 * h);
            let err = (&fd - j.column(c)).abs().max();
            assert!(err <= 1e-5 * fd.abs().max().max(1.0), "column {c}: {err}");
        }
    }

    #[test]
    fn normal_equations_equal_the_dense_products() {
        let (g, images, bbs) = fixture();
        for skew in [Skew::Free, Skew::Fixed] {
            let r = residuals(&g, &images, &bbs);
            let j = jacobian(&g, &images, &bbs, skew);
            let (jtj, jtr) = normal_equations(&g, &images, &bbs, skew, &r);
            let scale = j.tr_mul(&j).abs().max();
            assert!((jtj - j.tr_mul(&j)).abs().max() <= 1e-12 * scale);
            assert!((jtr - j.tr_mul(&r)).abs().max() <= 1e-9 * j.tr_mul(&r).abs().max());
        }
    }
}
