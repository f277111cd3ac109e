//! Symmetric eigen-decomposition by the cyclic Jacobi method.

use glam::{DMat3, DVec3};

/// The eigen-decomposition `A = Σₖ λₖ vₖ vₖᵀ` of a symmetric `N×N` matrix.
///
/// Order: `values` ascending; `vectors[k]` is the unit eigenvector of `values[k]` (the eigenvectors are
/// the *rows* of `vectors`, so `vectors[0]` belongs to the smallest eigenvalue). The vectors are
/// orthonormal; each is determined up to sign, and within a repeated eigenvalue up to a rotation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SymmetricEigen<const N: usize> {
    /// Eigenvalues `λ₀ ≤ λ₁ ≤ … ≤ λ_{N−1}`.
    pub values: [f64; N],
    /// `vectors[k]` is the unit eigenvector `vₖ` of `values[k]`.
    pub vectors: [[f64; N]; N],
}

impl SymmetricEigen<3> {
    /// The eigenvectors as the columns of a matrix (column `k` is `vectors[k]`, ascending eigenvalue).
    pub fn vector_columns(&self) -> DMat3 {
        let [a, b, c] = self.vectors.map(DVec3::from);
        DMat3::from_cols(a, b, c)
    }
}

/// Eigen-decomposition of a symmetric `N×N` matrix `m` (row-major; only symmetry is assumed, so a
/// symmetric glam `DMat3` may be passed as `to_cols_array_2d()`) by the cyclic Jacobi method
/// (Golub & Van Loan §8.5), sorted by ascending eigenvalue (see [`SymmetricEigen`]).
///
/// Jacobi is accurate to a few ulps of the largest eigenvalue, which the triangulation and Horn's
/// method rely on.
pub fn symmetric_eigen<const N: usize>(m: [[f64; N]; N]) -> SymmetricEigen<N> {
    let mut a = m;
    let mut v = [[0.0; N]; N];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _sweep in 0..64 {
        let off: f64 = (0..N)
            .flat_map(|i| (0..N).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        let diag: f64 = (0..N).map(|i| a[i][i] * a[i][i]).sum();
        if off <= 1e-32 * diag || off == 0.0 {
            break;
        }
        for p in 0..N {
            for q in p + 1..N {
                jacobi_rotate(&mut a, &mut v, p, q);
            }
        }
    }
    let mut order: [usize; N] = std::array::from_fn(|i| i);
    order.sort_by(|&i, &j| a[i][i].total_cmp(&a[j][j]));
    let values = std::array::from_fn(|k| a[order[k]][order[k]]);
    // Column `order[k]` of V is the k-th eigenvector.
    let vectors = std::array::from_fn(|k| std::array::from_fn(|r| v[r][order[k]]));
    SymmetricEigen { values, vectors }
}

/// One Jacobi rotation zeroing `a[p][q]` (the symmetric Schur decomposition of the 2×2 block).
fn jacobi_rotate<const N: usize>(a: &mut [[f64; N]; N], v: &mut [[f64; N]; N], p: usize, q: usize) {
    let apq = a[p][q];
    if apq == 0.0 {
        return;
    }
    let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
    let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
    let t = if theta == 0.0 { 1.0 } else { t };
    let c = 1.0 / (t * t + 1.0).sqrt();
    let s = t * c;
    for row in a.iter_mut() {
        let (akp, akq) = (row[p], row[q]);
        row[p] = c * akp - s * akq;
        row[q] = s * akp + c * akq;
    }
    let (row_p, row_q) = (a[p], a[q]);
    for k in 0..N {
        a[p][k] = c * row_p[k] - s * row_q[k];
        a[q][k] = s * row_p[k] + c * row_q[k];
    }
    for row in v.iter_mut() {
        let vkp = row[p];
        let vkq = row[q];
        row[p] = c * vkp - s * vkq;
        row[q] = s * vkp + c * vkq;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Checks `A vₖ = λₖ vₖ`, `VᵀV = I` and ascending order, all against the input matrix.
    fn check<const N: usize>(m: [[f64; N]; N], tol: f64) -> SymmetricEigen<N> {
        let e = symmetric_eigen(m);
        for k in 0..N {
            let v = e.vectors[k];
            for i in 0..N {
                let av: f64 = (0..N).map(|j| m[i][j] * v[j]).sum();
                assert!(
                    (av - e.values[k] * v[i]).abs() < tol,
                    "A v{k} ≠ λ v{k} at {i}"
                );
            }
            for l in 0..N {
                let dot: f64 = (0..N).map(|i| v[i] * e.vectors[l][i]).sum();
                let want = if k == l { 1.0 } else { 0.0 };
                assert!((dot - want).abs() < tol, "v{k}·v{l} = {dot}");
            }
        }
        assert!(e.values.windows(2).all(|p| p[0] <= p[1]), "{:?}", e.values);
        e
    }

    #[test]
    fn eigen_reconstructs_matrix() {
        let m = [
            [4.0, 1.0, -2.0, 0.5],
            [1.0, 3.0, 0.0, 1.0],
            [-2.0, 0.0, 5.0, -1.0],
            [0.5, 1.0, -1.0, 2.0],
        ];
        let e = check(m, 1e-12);
        // A = Σₖ λₖ vₖ vₖᵀ.
        for (i, row) in m.iter().enumerate() {
            for (j, &mij) in row.iter().enumerate() {
                let r: f64 = (0..4)
                    .map(|k| e.values[k] * e.vectors[k][i] * e.vectors[k][j])
                    .sum();
                assert!((r - mij).abs() < 1e-12, "{i},{j}: {r}");
            }
        }
    }

    #[test]
    fn second_difference_matrix_has_its_textbook_eigenpairs() {
        // tridiag(−1, 2, −1) of size 3: λ = 2 − √2, 2, 2 + √2 with v ∝ (1, √2, 1), (1, 0, −1), (1, −√2, 1).
        let r2 = std::f64::consts::SQRT_2;
        let e = check(
            [[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 2.0]],
            1e-14,
        );
        let want_values = [2.0 - r2, 2.0, 2.0 + r2];
        let want_vectors = [
            DVec3::new(0.5, r2 / 2.0, 0.5),
            DVec3::new(r2 / 2.0, 0.0, -r2 / 2.0),
            DVec3::new(0.5, -r2 / 2.0, 0.5),
        ];
        let cols = e.vector_columns();
        for k in 0..3 {
            assert!((e.values[k] - want_values[k]).abs() < 1e-14);
            // Up to sign.
            let v = cols.col(k);
            assert!(v.dot(want_vectors[k]).abs() > 1.0 - 1e-14, "{k}: {v:?}");
            assert_eq!(v, DVec3::from(e.vectors[k]));
        }
    }

    #[test]
    fn rotated_diagonal_and_repeated_eigenvalues() {
        let r = DMat3::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
        let m = r * DMat3::from_diagonal(DVec3::new(5.0, 2.0, 1.0)) * r.transpose();
        let e = check(m.to_cols_array_2d(), 1e-12);
        for (k, want) in [1.0, 2.0, 5.0].into_iter().enumerate() {
            assert!((e.values[k] - want).abs() < 1e-12);
        }
        // The eigenvector of 5 is the rotated x axis.
        assert!(e.vector_columns().col(2).dot(r.x_axis).abs() > 1.0 - 1e-12);
        // A repeated eigenvalue still yields an orthonormal basis.
        let e = check([[3.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, -1.0]], 1e-15);
        assert_eq!(e.values, [-1.0, 3.0, 3.0]);
    }
}
