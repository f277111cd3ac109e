//! Zhang's closed form (Zhang 2000, §3.1): a homography per plate image (normalised DLT), then the
//! image of the absolute conic `B = K⁻ᵀ K⁻¹` from `v₁₂ᵀ b = 0`, `(v₁₁ − v₂₂)ᵀ b = 0`, and K from B —
//! the start OpenCV's `calibrateCamera` refines (with `CALIB_USE_INTRINSIC_GUESS`). Pixels are first
//! mapped to `[−1, 1]` by the detector's size, which keeps `V` well conditioned.

use glam::{DMat3, DVec3};
use nalgebra::{DMatrix, Matrix3, Vector3};

use super::acquisition::CalibrationImage;
use super::bundle::Geometry;
use crate::geometry::{Intrinsics, RigidTransform};

/// The homography mapping plate points `(X, Y, 1)` to (normalised) pixels, or `None` if degenerate.
fn homography(plate: &[(f64, f64)], px: &[(f64, f64)]) -> Option<Matrix3<f64>> {
    let norm = |p: &[(f64, f64)]| {
        let n = p.len() as f64;
        let (cx, cy) = p
            .iter()
            .fold((0.0, 0.0), |a, q| (a.0 + q.0 / n, a.1 + q.1 / n));
        let d = p
            .iter()
            .map(|q| ((q.0 - cx).powi(2) + (q.1 - cy).powi(2)).sqrt())
            .sum::<f64>()
            / n;
        let s = std::f64::consts::SQRT_2 / d.max(1e-300);
        Matrix3::new(s, 0.0, -s * cx, 0.0, s, -s * cy, 0.0, 0.0, 1.0)
    };
    let (t1, t2) = (norm(plate), norm(px));
    let mut a = DMatrix::<f64>::zeros(2 * plate.len(), 9);
    for (i, (x, u)) in plate.iter().zip(px).enumerate() {
        let p = t1 * Vector3::new(x.0, x.1, 1.0);
        let q = t2 * Vector3::new(u.0, u.1, 1.0);
        let (u, v) = (q.x / q.z, q.y / q.z);
        for c in 0..3 {
            a[(2 * i, c)] = p[c];
            a[(2 * i, 6 + c)] = -u * p[c];
            a[(2 * i + 1, 3 + c)] = p[c];
            a[(2 * i + 1, 6 + c)] = -v * p[c];
        }
    }
    let h = null_vector(a)?;
    let hn = Matrix3::from_fn(|r, c| h[3 * r + c]);
    Some(t2.try_inverse()? * hn * t1)
}

/// The right singular vector of the smallest singular value.
fn null_vector(a: DMatrix<f64>) -> Option<Vec<f64>> {
    let svd = a.svd(false, true);
    let vt = svd.v_t?;
    let (i, _) = svd
        .singular_values
        .iter()
        .enumerate()
        .min_by(|x, y| x.1.total_cmp(y.1))?;
    Some(vt.row(i).iter().copied().collect())
}

/// `v_ij` of Zhang's paper for columns i, j of H.
fn v(h: &Matrix3<f64>, i: usize, j: usize) -> [f64; 6] {
    let (hi, hj) = (h.column(i), h.column(j));
    [
        hi[0] * hj[0],
        hi[0] * hj[1] + hi[1] * hj[0],
        hi[1] * hj[1],
        hi[2] * hj[0] + hi[0] * hj[2],
        hi[2] * hj[1] + hi[1] * hj[2],
        hi[2] * hj[2],
    ]
}

/// Zhang's closed-form K (with skew) from plate images (plate points in z = 0), or `None` when the
/// poses do not determine it (fewer than 3 images, near-parallel planes, noise past the closed form).
pub fn closed_form(
    images: &[CalibrationImage],
    bbs: &[DVec3],
    width: u32,
    height: u32,
) -> Option<Intrinsics> {
    closed_form_with_homographies(images, bbs, width, height).map(|(k, _)| k)
}

/// Zhang's start of the whole geometry: the closed-form K with its skew set to `skew`, and each image's
/// plate → camera pose from its homography (Zhang 2000, §3.1: `r₁ = λK⁻¹h₁`, `r₂ = λK⁻¹h₂`,
/// `r₃ = r₁ × r₂`, `t = λK⁻¹h₃`, the rotation made orthonormal by SVD; the sign puts the plate in front).
pub fn initial_geometry(
    images: &[CalibrationImage],
    bbs: &[DVec3],
    width: u32,
    height: u32,
    skew: f64,
) -> Option<Geometry> {
    let (mut k, hs) = closed_form_with_homographies(images, bbs, width, height)?;
    k.skew = skew;
    let km = Matrix3::new(k.fx, k.skew, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0);
    let k_inv = km.try_inverse()?;
    let mut poses = Vec::with_capacity(hs.len());
    for h in hs {
        let (a1, a2, a3) = (
            k_inv * h.column(0),
            k_inv * h.column(1),
            k_inv * h.column(2),
        );
        let mut lambda = 1.0 / a1.norm();
        if (lambda * a3).z < 0.0 {
            lambda = -lambda;
        }
        let (r1, r2) = (lambda * a1, lambda * a2);
        let q = Matrix3::from_columns(&[r1, r2, r1.cross(&r2)]);
        let svd = q.svd(true, true);
        let (u, vt) = (svd.u?, svd.v_t?);
        let r = u * vt;
        if r.determinant() < 0.0 {
            return None;
        }
        let t = lambda * a3;
        let rot = DMat3::from_cols_array(&[
            r[(0, 0)],
            r[(1, 0)],
            r[(2, 0)],
            r[(0, 1)],
            r[(1, 1)],
            r[(2, 1)],
            r[(0, 2)],
            r[(1, 2)],
            r[(2, 2)],
        ]);
        if !rot.is_finite() || !t.iter().all(|x| x.is_finite()) {
            return None;
        }
        poses.push(RigidTransform::new(rot, DVec3::new(t.x, t.y, t.z)));
    }
    Some(Geometry { k, poses })
}

/// The closed-form K and each image's pixel homography.
fn closed_form_with_homographies(
    images: &[CalibrationImage],
    bbs: &[DVec3],
    width: u32,
    height: u32,
) -> Option<(Intrinsics, Vec<Matrix3<f64>>)> {
    if images.len() < 3 {
        return None;
    }
    // Pixels → [−1, 1]: N = [[2/w, 0, −1], [0, 2/h, −1], [0, 0, 1]] (about pixel corners).
    let (sw, sh) = (2.0 / f64::from(width), 2.0 / f64::from(height));
    let n_inv = Matrix3::new(
        1.0 / sw,
        0.0,
        1.0 / sw - 0.5,
        0.0,
        1.0 / sh,
        1.0 / sh - 0.5,
        0.0,
        0.0,
        1.0,
    );
    let mut vm = DMatrix::<f64>::zeros(2 * images.len(), 6);
    let mut hs = Vec::with_capacity(images.len());
    for (m, im) in images.iter().enumerate() {
        let plate: Vec<(f64, f64)> = im
            .observed
            .iter()
            .map(|&(i, _)| (bbs[i].x, bbs[i].y))
            .collect();
        let px: Vec<(f64, f64)> = im
            .observed
            .iter()
            .map(|&(_, x)| ((x.x + 0.5) * sw - 1.0, (x.y + 0.5) * sh - 1.0))
            .collect();
        let h = homography(&plate, &px)?;
        hs.push(n_inv * h);
        let (v12, v11, v22) = (v(&h, 0, 1), v(&h, 0, 0), v(&h, 1, 1));
        for c in 0..6 {
            vm[(2 * m, c)] = v12[c];
            vm[(2 * m + 1, c)] = v11[c] - v22[c];
        }
    }
    let mut b = null_vector(vm)?;
    if b[0] < 0.0 {
        b.iter_mut().for_each(|x| *x = -*x);
    }
    let [b11, b12, b22, b13, b23, b33] = [b[0], b[1], b[2], b[3], b[4], b[5]];
    let den = b11 * b22 - b12 * b12;
    let v0 = (b12 * b13 - b11 * b23) / den;
    let lambda = b33 - (b13 * b13 + v0 * (b12 * b13 - b11 * b23)) / b11;
    let alpha = (lambda / b11).sqrt();
    let beta = (lambda * b11 / den).sqrt();
    let gamma = -b12 * alpha * alpha * beta / lambda;
    let u0 = gamma * v0 / beta - b13 * alpha * alpha / lambda;
    let kn = Matrix3::new(alpha, gamma, u0, 0.0, beta, v0, 0.0, 0.0, 1.0);
    let k = n_inv * kn;
    let out = Intrinsics {
        fx: k[(0, 0)],
        fy: k[(1, 1)],
        skew: k[(0, 1)],
        cx: k[(0, 2)],
        cy: k[(1, 2)],
        width,
        height,
    };
    out.validate().ok().map(|_| (out, hs))
}
