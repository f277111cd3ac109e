//! The projection matrix of one image of a 3-D phantom by the normalised direct linear transform
//! (Hartley & Zisserman, Alg. 7.1), and its RQ decomposition `P = λ K [R | t]` into intrinsics (with
//! skew) and pose.

use glam::{DMat3, DVec2, DVec3};
use nalgebra::{DMatrix, Matrix3, Matrix3x4};

use super::phantom::{Spread, spread};
use crate::geometry::{Intrinsics, RigidTransform};
use crate::{Error, Result};

/// Similarity normalising 2-D points: centroid to the origin, mean distance √2.
fn normalise_2d(x: &[DVec2]) -> Matrix3<f64> {
    let c = x.iter().fold(DVec2::ZERO, |a, p| a + *p) / x.len() as f64;
    let d = x.iter().map(|p| (*p - c).length()).sum::<f64>() / x.len() as f64;
    let s = std::f64::consts::SQRT_2 / d.max(1e-300);
    Matrix3::new(s, 0.0, -s * c.x, 0.0, s, -s * c.y, 0.0, 0.0, 1.0)
}

/// Similarity normalising 3-D points: centroid to the origin, mean distance √3 (a 4×4 as rows).
fn normalise_3d(x: &[DVec3]) -> nalgebra::Matrix4<f64> {
    let c = x.iter().fold(DVec3::ZERO, |a, p| a + *p) / x.len() as f64;
    let d = x.iter().map(|p| (*p - c).length()).sum::<f64>() / x.len() as f64;
    let s = 3f64.sqrt() / d.max(1e-300);
    nalgebra::Matrix4::new(
        s,
        0.0,
        0.0,
        -s * c.x,
        0.0,
        s,
        0.0,
        -s * c.y,
        0.0,
        0.0,
        s,
        -s * c.z,
        0.0,
        0.0,
        0.0,
        1.0,
    )
}

/// The 3×4 projection matrix mapping `world` to `pixels` (at least 6 non-coplanar correspondences),
/// scaled to unit Frobenius norm.
pub fn dlt(world: &[DVec3], pixels: &[DVec2]) -> Result<Matrix3x4<f64>> {
    if world.len() != pixels.len() || world.len() < 6 {
        return Err(Error::invalid(
            "phantom",
            format!(
                "a projection matrix (11 unknowns) needs at least 6 BBs in an image, got {}",
                world.len().min(pixels.len())
            ),
        ));
    }
    if spread(world) != Spread::Volume {
        return Err(Error::invalid(
            "phantom",
            "the BBs seen in an image are coplanar (or collinear): a projection-matrix calibration \
             needs BBs spanning 3-D (use the plate method for a planar phantom)",
        ));
    }
    let t2 = normalise_2d(pixels);
    let t3 = normalise_3d(world);
    let mut a = DMatrix::<f64>::zeros(2 * world.len(), 12);
    for (i, (xw, xp)) in world.iter().zip(pixels).enumerate() {
        let xh = t3 * nalgebra::Vector4::new(xw.x, xw.y, xw.z, 1.0);
        let ph = t2 * nalgebra::Vector3::new(xp.x, xp.y, 1.0);
        let (u, v, w) = (ph.x / ph.z, ph.y / ph.z, 1.0);
        for c in 0..4 {
            // Row 1: w Xᵀ p2 − v Xᵀ p3 = 0 is replaced by the usual pair
            // [Xᵀ, 0, −u Xᵀ] p = 0 and [0, Xᵀ, −v Xᵀ] p = 0.
            a[(2 * i, c)] = w * xh[c];
            a[(2 * i, 8 + c)] = -u * xh[c];
            a[(2 * i + 1, 4 + c)] = w * xh[c];
            a[(2 * i + 1, 8 + c)] = -v * xh[c];
        }
    }
    let svd = a.svd(false, true);
    let vt = svd
        .v_t
        .ok_or_else(|| Error::Internal("DLT: SVD without V".into()))?;
    let (imin, _) = svd
        .singular_values
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .ok_or_else(|| Error::Internal("DLT: empty SVD".into()))?;
    let p = vt.row(imin);
    let pn = Matrix3x4::from_fn(|r, c| p[4 * r + c]);
    let t2_inv = t2
        .try_inverse()
        .ok_or_else(|| Error::Numerical("DLT: degenerate image points".into()))?;
    let full = t2_inv * pn * t3;
    let norm = full.norm();
    if !(norm.is_finite() && norm > 0.0) {
        return Err(Error::Numerical("DLT: no projection matrix".into()));
    }
    Ok(full / norm)
}

/// `P = λ K [R | t]` decomposed by RQ: K upper triangular with a positive diagonal and `K[2][2] = 1`,
/// R a rotation (det +1), t the translation. Returns the intrinsics (detector size `width × height`)
/// and the pose.
pub fn decompose(
    p: &Matrix3x4<f64>,
    width: u32,
    height: u32,
) -> Result<(Intrinsics, RigidTransform)> {
    let mut p = *p;
    let m: Matrix3<f64> = p.fixed_view::<3, 3>(0, 0).into_owned();
    if m.determinant() < 0.0 {
        p = -p;
    }
    let m: Matrix3<f64> = p.fixed_view::<3, 3>(0, 0).into_owned();
    let (k, r) = rq(&m)?;
    let lambda = k[(2, 2)];
    let k = k / lambda;
    let kinv = k
        .try_inverse()
        .ok_or_else(|| Error::Numerical("RQ: singular K".into()))?;
    let t = kinv * p.column(3) / lambda;
    let intrinsics = Intrinsics::from_matrix(
        [
            [k[(0, 0)], k[(0, 1)], k[(0, 2)]],
            [0.0, k[(1, 1)], k[(1, 2)]],
            [0.0, 0.0, 1.0],
        ],
        width,
        height,
    )
    .map_err(|e| Error::Numerical(format!("the DLT's K is not a camera: {e}")))?;
    let rotation = DMat3::from_cols(
        DVec3::new(r[(0, 0)], r[(1, 0)], r[(2, 0)]),
        DVec3::new(r[(0, 1)], r[(1, 1)], r[(2, 1)]),
        DVec3::new(r[(0, 2)], r[(1, 2)], r[(2, 2)]),
    );
    Ok((
        intrinsics,
        RigidTransform::new(rotation, DVec3::new(t.x, t.y, t.z)),
    ))
}

/// `M = K R` with K upper triangular (positive diagonal) and R orthonormal, from the QR decomposition
/// of `(E M)ᵀ`, `E` the exchange matrix.
fn rq(m: &Matrix3<f64>) -> Result<(Matrix3<f64>, Matrix3<f64>)> {
    let e = Matrix3::new(0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0);
    let qr = (e * m).transpose().qr();
    let (q, r) = (qr.q(), qr.r());
    // E M = Rᵀ Qᵀ, so M = (E Rᵀ E)(E Qᵀ): upper triangular times orthonormal.
    let mut k = e * r.transpose() * e;
    let mut rot = e * q.transpose();
    for i in 0..3 {
        if k[(i, i)] < 0.0 {
            // K D, D R with D = diag(±1): the product is unchanged.
            for row in 0..3 {
                k[(row, i)] = -k[(row, i)];
            }
            for col in 0..3 {
                rot[(i, col)] = -rot[(i, col)];
            }
        }
    }
    if !k.iter().all(|v| v.is_finite()) || k[(2, 2)] <= 0.0 {
        return Err(Error::Numerical("RQ: degenerate projection matrix".into()));
    }
    if rot.determinant() < 0.0 {
        return Err(Error::Numerical(
            "RQ: the projection matrix maps to a mirrored camera".into(),
        ));
    }
    Ok((k, rot))
}
