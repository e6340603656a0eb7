//! An implicit-integration linear system `A x = b` with fixed degrees of freedom, solved either
//! directly (by the held Cholesky factorization) or by conjugate gradients preconditioned with
//! a factorization of a nearby matrix (the rest state), warm-started by the caller.

use serde::{Deserialize, Serialize};

use super::{BlockSparse, LinalgError, SparseCholesky};
use crate::Vec3;

/// What one conjugate-gradient solve did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct CgStats {
    /// Iterations taken (each one product with `A` and one preconditioner solve).
    pub iterations: u32,
    /// Final `|b - A x| / |b|` (0 when `b` is zero).
    pub relative_residual: f64,
    /// Whether the tolerance was reached within the iteration cap.
    pub converged: bool,
}

/// A solve that stopped at its iteration cap above its tolerance, where convergence was
/// required (see [`CgStats::require_converged`]).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error(
    "the implicit solve did not converge: relative residual {residual:e} after {iterations} iterations (tolerance {tolerance:e})"
)]
pub struct NotConverged {
    /// Iterations taken (the cap).
    pub iterations: u32,
    /// Final relative residual.
    pub residual: f64,
    /// The tolerance asked for.
    pub tolerance: f64,
}

impl CgStats {
    /// `self` when the solve converged, else the [`NotConverged`] error (`tolerance` is the
    /// one the solve was given).
    pub fn require_converged(self, tolerance: f64) -> Result<Self, NotConverged> {
        if self.converged {
            Ok(self)
        } else {
            Err(NotConverged {
                iterations: self.iterations,
                residual: self.relative_residual,
                tolerance,
            })
        }
    }
}

/// A symmetric positive definite system over nodes with 3 unknowns each: the matrix (whose
/// values the owner re-assembles in place), the fixed unknowns, a Cholesky factorization used
/// as preconditioner or direct solver, and the workspaces of the iteration.
#[derive(Debug)]
pub struct ImplicitSystem {
    /// The system matrix; assemble into it, keeping its pattern.
    pub matrix: BlockSparse,
    fixed: Vec<[bool; 3]>,
    factor: SparseCholesky,
    r: Vec<Vec3>,
    z: Vec<Vec3>,
    p: Vec<Vec3>,
    q: Vec<Vec3>,
    /// The preconditioner's frame (see [`ImplicitSystem::set_preconditioner_frame`]).
    frame: Option<nalgebra::Matrix3<f64>>,
    turned: Vec<Vec3>,
    any_fixed: bool,
}

impl ImplicitSystem {
    /// Takes `matrix` with its current values, the fixed unknowns per node, and factorizes it.
    pub fn new(matrix: BlockSparse, fixed: Vec<[bool; 3]>) -> Result<Self, LinalgError> {
        let n = matrix.nodes();
        assert_eq!(fixed.len(), n, "one fixed mask per node");
        let flags: Vec<bool> = fixed.iter().flatten().copied().collect();
        let mut factor = SparseCholesky::new(&matrix, &flags)?;
        factor.factorize(&matrix)?;
        let any_fixed = fixed.iter().any(|f| f.iter().any(|&a| a));
        Ok(ImplicitSystem {
            matrix,
            fixed,
            factor,
            r: vec![Vec3::zeros(); n],
            z: vec![Vec3::zeros(); n],
            p: vec![Vec3::zeros(); n],
            q: vec![Vec3::zeros(); n],
            frame: None,
            turned: vec![Vec3::zeros(); n],
            any_fixed,
        })
    }

    /// Number of nodes.
    pub fn nodes(&self) -> usize {
        self.fixed.len()
    }

    /// Stored entries of the Cholesky factor.
    pub fn factor_nnz(&self) -> usize {
        self.factor.factor_nnz()
    }

    /// The fixed unknowns per node.
    pub fn fixed(&self) -> &[[bool; 3]] {
        &self.fixed
    }

    /// Factorizes the current matrix values (no allocation; the pattern is unchanged).
    pub fn refactor(&mut self) -> Result<(), LinalgError> {
        self.factor.factorize(&self.matrix)
    }

    /// Zeroes the fixed components of `v`.
    pub fn project(&self, v: &mut [Vec3]) {
        for (vi, f) in v.iter_mut().zip(&self.fixed) {
            for a in 0..3 {
                if f[a] {
                    vi[a] = 0.0;
                }
            }
        }
    }

    /// `y = A x` restricted to the free unknowns (fixed components of `y` are zero).
    pub fn apply(&self, x: &[Vec3], y: &mut [Vec3]) {
        self.matrix.mul(x, y);
        self.project(y);
    }

    /// Turns the preconditioner of [`ImplicitSystem::solve_cg`] by `frame` (`R A R^T` in
    /// place of the factored `A`): for a body whose matrix is its rest matrix turned as a
    /// whole (a free body that tumbled), the turned factor is the exact inverse again, where
    /// the rest factor alone would leave the iteration crawling. Ignored for a system with
    /// fixed unknowns (their axes are the world's). `None`: the factor as it is.
    pub fn set_preconditioner_frame(&mut self, frame: Option<nalgebra::Matrix3<f64>>) {
        self.frame = frame;
    }

    fn precondition(&mut self, r: &[Vec3], z: &mut [Vec3]) -> Result<(), LinalgError> {
        match self.frame {
            Some(rot) if !self.any_fixed => {
                let rt = rot.transpose();
                for (t, ri) in self.turned.iter_mut().zip(r) {
                    *t = rt * ri;
                }
                self.factor.solve_nodes(&self.turned, z)?;
                for zi in z.iter_mut() {
                    *zi = rot * *zi;
                }
                Ok(())
            }
            _ => self.factor.solve_nodes(r, z),
        }
    }

    /// Solves with the held factorization only: exact when it was made from the current
    /// matrix values. `b`'s fixed components are ignored; `x`'s are zero on return.
    pub fn solve_direct(&mut self, b: &[Vec3], x: &mut [Vec3]) -> Result<(), LinalgError> {
        self.factor.solve_nodes(b, x)
    }

    /// The held factorization's inverse applied to unit forces on `nodes`, per axis (see
    /// [`SparseCholesky::solve_unit_nodes`](super::SparseCholesky::solve_unit_nodes)).
    pub fn solve_unit_nodes(
        &mut self,
        nodes: &[u32],
        out: [&mut [Vec3]; 3],
    ) -> Result<(), LinalgError> {
        self.factor.solve_unit_nodes(nodes, out)
    }

    /// Preconditioned conjugate gradients from the initial guess in `x`, until
    /// `|b - A x| <= tolerance |b|` or `max_iterations`. Fixed components of `b` are ignored and
    /// those of `x` set to zero.
    pub fn solve_cg(
        &mut self,
        b: &[Vec3],
        x: &mut [Vec3],
        tolerance: f64,
        max_iterations: u32,
    ) -> Result<CgStats, LinalgError> {
        let mut r = std::mem::take(&mut self.r);
        let mut z = std::mem::take(&mut self.z);
        let mut p = std::mem::take(&mut self.p);
        let mut q = std::mem::take(&mut self.q);
        let out = self.cg_inner(
            b,
            x,
            tolerance,
            max_iterations,
            &mut r,
            &mut z,
            &mut p,
            &mut q,
        );
        self.r = r;
        self.z = z;
        self.p = p;
        self.q = q;
        out
    }

    #[allow(clippy::too_many_arguments)]
    fn cg_inner(
        &mut self,
        b: &[Vec3],
        x: &mut [Vec3],
        tolerance: f64,
        max_iterations: u32,
        r: &mut [Vec3],
        z: &mut [Vec3],
        p: &mut [Vec3],
        q: &mut [Vec3],
    ) -> Result<CgStats, LinalgError> {
        self.project(x);
        r.copy_from_slice(b);
        self.project(r);
        let b_norm = norm(r);
        if b_norm == 0.0 {
            x.fill(Vec3::zeros());
            return Ok(CgStats {
                iterations: 0,
                relative_residual: 0.0,
                converged: true,
            });
        }
        // r = b - A x
        self.apply(x, q);
        for (ri, qi) in r.iter_mut().zip(q.iter()) {
            *ri -= qi;
        }
        let target = tolerance * b_norm;
        let mut r_norm = norm(r);
        let mut iterations = 0;
        if r_norm > target && max_iterations > 0 {
            self.precondition(r, z)?;
            p.copy_from_slice(z);
            let mut rz = dot(r, z);
            while iterations < max_iterations {
                self.apply(p, q);
                let pq = dot(p, q);
                if pq.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) || !rz.is_finite() {
                    // Breakdown (the matrix lost definiteness or the values are not finite):
                    // stop with the current iterate, reported as not converged.
                    break;
                }
                let alpha = rz / pq;
                for i in 0..x.len() {
                    x[i] += alpha * p[i];
                    r[i] -= alpha * q[i];
                }
                iterations += 1;
                r_norm = norm(r);
                if r_norm <= target {
                    break;
                }
                self.precondition(r, z)?;
                let rz_new = dot(r, z);
                let beta = rz_new / rz;
                rz = rz_new;
                for i in 0..p.len() {
                    p[i] = z[i] + beta * p[i];
                }
            }
        }
        let relative_residual = r_norm / b_norm;
        Ok(CgStats {
            iterations,
            relative_residual,
            converged: r_norm <= target,
        })
    }
}

/// Dot product of two node vectors.
pub(crate) fn dot(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
}

/// Euclidean norm of a node vector.
pub(crate) fn norm(a: &[Vec3]) -> f64 {
    dot(a, a).sqrt()
}
