//! Small dense linear algebra shared by the stages: the symmetric eigen-decomposition and the Cholesky
//! solve. Sizes are fixed and tiny (3×3, 4×4, 6×6), so plain arrays beat a general library.
//!
//! Matrices are row-major `[[f64; N]; N]` (`m[i][j]` is row `i`, column `j`). This module depends on
//! nothing else in the crate; `anatomy`, `geometry` and `registration` build on it.

mod cholesky;
mod eigen;

pub use cholesky::cholesky_solve;
pub use eigen::{SymmetricEigen, symmetric_eigen};
