//! Sparse linear algebra for the implicit solvers: block-sparse 3x3 matrices with a fixed
//! pattern, a sparse Cholesky factorization (`faer`), and preconditioned conjugate gradients.

mod bsr;
mod cholesky;
mod pcg;
mod supernodal;

pub use bsr::BlockSparse;
pub use cholesky::{ScalarCholesky, SparseCholesky};
pub use pcg::{CgStats, ImplicitSystem};

/// `a * b + c`, fused where the calling kernel is compiled for FMA (the vector kernels of the
/// substitution and the corotational element loop; without FMA `mul_add` would be a library
/// call).
#[inline(always)]
pub(crate) fn madd<const FMA: bool>(a: f64, b: f64, c: f64) -> f64 {
    if FMA { a.mul_add(b, c) } else { a * b + c }
}

/// A failure of the linear algebra, naming the degree of freedom (`3 * node + axis`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LinalgError {
    /// The matrix is not positive definite: a pivot was zero or negative.
    #[error(
        "matrix not positive definite at degree of freedom {dof} (node {}, axis {}): the body may lack constraints against rigid motion, or a parameter is non-physical",
        dof / 3, dof % 3
    )]
    NotPositiveDefinite {
        /// Degree of freedom whose pivot failed.
        dof: usize,
    },
    /// A matrix entry is NaN or infinite.
    #[error("matrix entry for degree of freedom {dof} (node {}, axis {}) is not finite", dof / 3, dof % 3)]
    NonFinite {
        /// Degree of freedom (row) of the entry.
        dof: usize,
    },
    /// A solve was attempted before a successful factorization.
    #[error("no factorization is held (the last one failed or none was made)")]
    NotFactored,
    /// The symbolic analysis failed.
    #[error("symbolic analysis failed: {0}")]
    Symbolic(String),
    /// The workspace could not be allocated.
    #[error("out of memory allocating the factorization workspace")]
    OutOfMemory,
}
