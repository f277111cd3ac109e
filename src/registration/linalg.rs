//! Small dense linear algebra for the solvers: symmetric eigen-decomposition (cyclic Jacobi) and a
//! Cholesky solve. Sizes are fixed and tiny (3×3, 4×4, 6×6), so plain arrays beat a general library.

/// Eigen-decomposition of a symmetric `N×N` matrix by the cyclic Jacobi method (Golub & Van Loan §8.5).
///
/// Returns `(eigenvalues, eigenvectors)` with `eigenvectors[k]` the unit eigenvector of
/// `eigenvalues[k]`, sorted by ascending eigenvalue. Jacobi is accurate to a few ulps of the largest
/// eigenvalue, which the triangulation and Horn's method rely on.
pub fn symmetric_eigen<const N: usize>(m: [[f64; N]; N]) -> ([f64; N], [[f64; N]; N]) {
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
    (values, vectors)
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

/// Solves `A x = b` for a symmetric positive-definite `A` by Cholesky factorisation `A = L Lᵀ`.
/// Returns `None` when `A` is not (numerically) positive definite.
pub fn cholesky_solve<const N: usize>(a: &[[f64; N]; N], b: &[f64; N]) -> Option<[f64; N]> {
    let mut l = [[0.0; N]; N];
    for i in 0..N {
        for j in 0..=i {
            let s: f64 = (0..j).map(|k| l[i][k] * l[j][k]).sum();
            if i == j {
                let d = a[i][i] - s;
                if !(d > 0.0 && d.is_finite()) {
                    return None;
                }
                l[i][i] = d.sqrt();
            } else {
                l[i][j] = (a[i][j] - s) / l[j][j];
            }
        }
    }
    let mut y = [0.0; N];
    for i in 0..N {
        let s: f64 = (0..i).map(|k| l[i][k] * y[k]).sum();
        y[i] = (b[i] - s) / l[i][i];
    }
    let mut x = [0.0; N];
    for i in (0..N).rev() {
        let s: f64 = (i + 1..N).map(|k| l[k][i] * x[k]).sum();
        x[i] = (y[i] - s) / l[i][i];
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eigen_reconstructs_matrix() {
        let m = [
            [4.0, 1.0, -2.0, 0.5],
            [1.0, 3.0, 0.0, 1.0],
            [-2.0, 0.0, 5.0, -1.0],
            [0.5, 1.0, -1.0, 2.0],
        ];
        let (w, v) = symmetric_eigen(m);
        for i in 0..4 {
            for j in 0..4 {
                let r: f64 = (0..4).map(|k| w[k] * v[k][i] * v[k][j]).sum();
                assert!((r - m[i][j]).abs() < 1e-12, "{i},{j}: {r}");
            }
        }
        assert!(w.windows(2).all(|p| p[0] <= p[1]));
    }

    #[test]
    fn cholesky_solves_spd() {
        let a = [[4.0, 2.0, 0.6], [2.0, 5.0, 1.0], [0.6, 1.0, 3.0]];
        let x = [1.0, -2.0, 0.5];
        let b: [f64; 3] = std::array::from_fn(|i| (0..3).map(|k| a[i][k] * x[k]).sum());
        let got = cholesky_solve(&a, &b).unwrap();
        for i in 0..3 {
            assert!((got[i] - x[i]).abs() < 1e-12);
        }
        assert!(cholesky_solve(&[[1.0, 2.0], [2.0, 1.0]], &[1.0, 1.0]).is_none());
    }
}
