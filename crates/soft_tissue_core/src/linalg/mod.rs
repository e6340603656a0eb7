//! Sparse linear algebra for the implicit solvers: block-sparse 3x3 matrices with a fixed
//! pattern, a sparse Cholesky factorization (`faer`), and preconditioned conjugate gradients.

mod bsr;
mod cholesky;
pub mod compliance;
mod pcg;
mod supernodal;

pub use bsr::BlockSparse;
pub use cholesky::{ScalarCholesky, SparseCholesky};
pub use compliance::ColumnCache;
pub use pcg::{CgStats, ImplicitSystem, NotConverged};

/// `a * b + c`, fused where the calling kernel is compiled for FMA (the vector kernels of the
/// substitution and the corotational element loop; without FMA `mul_add` would be a library
/// call).
#[inline(always)]
pub(crate) fn madd<const FMA: bool>(a: f64, b: f64, c: f64) -> f64 {
    if FMA { a.mul_add(b, c) } else { a * b + c }
}

/// Set by [`set_portable_kernels`]: the kernels skip their AVX2/AVX-512 + FMA variants.
static PORTABLE: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Forces the portable kernels (separate multiply and add, no AVX2/AVX-512 variants) for the
/// whole process when `on`, or lets each kernel pick the widest variant the CPU has (the
/// default). The three kernels with CPU-dependent variants (the corotational element loop,
/// the Cholesky substitution and the cage's Green-coordinate deformation) read this at each
/// call, so set it before stepping, not while another thread steps.
///
/// The fused variants round `a * b + c` once where the portable ones round twice, so results
/// on a CPU with FMA and on one without differ in the last bits; forcing the portable
/// kernels reproduces, on any x86-64 CPU, what a CPU without FMA computes.
pub fn set_portable_kernels(on: bool) {
    PORTABLE.store(on, std::sync::atomic::Ordering::Relaxed);
}

/// Whether [`set_portable_kernels`] forced the portable kernels.
pub fn portable_kernels() -> bool {
    PORTABLE.load(std::sync::atomic::Ordering::Relaxed)
}

/// Which kernel variant runs: AVX-512 + FMA, AVX2 + FMA, or portable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum KernelVariant {
    /// 512-bit vectors with fused multiply-add.
    #[cfg(target_arch = "x86_64")]
    Avx512,
    /// 256-bit vectors with fused multiply-add.
    #[cfg(target_arch = "x86_64")]
    Avx2,
    /// Separate multiply and add, whatever the compiler vectorizes for the base target.
    Portable,
}

/// The widest variant this CPU runs, unless [`set_portable_kernels`] forced the portable one.
#[inline]
pub(crate) fn kernel_variant() -> KernelVariant {
    if portable_kernels() {
        return KernelVariant::Portable;
    }
    #[cfg(target_arch = "x86_64")]
    {
        if is_x86_feature_detected!("avx512f") && is_x86_feature_detected!("fma") {
            return KernelVariant::Avx512;
        }
        if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
            return KernelVariant::Avx2;
        }
    }
    KernelVariant::Portable
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
