//! Sparse Cholesky factorization of a [`BlockSparse`] system with fixed degrees of freedom,
//! through `faer` (fill-reducing AMD ordering, symbolic analysis once, numeric factorization
//! when the values change, allocation-free solves).

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::{LltError, LltRegularization};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymbolicCholeskyRaw, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::{Conj, MatMut, Par, Side};

use super::supernodal::SupernodalSolver;
use super::{BlockSparse, LinalgError};
use crate::Vec3;

const ENTRY_ZERO: u32 = u32::MAX;
const ENTRY_ONE: u32 = u32::MAX - 1;

/// `L L^T` factorization of a symmetric scalar matrix given by its upper triangle in
/// compressed columns: symbolic analysis once, numeric factorization when the values change,
/// allocation-free solves. The block and scalar front ends below fill its values.
struct UpperLlt {
    dim: usize,
    symbolic_a: SymbolicSparseColMat<usize>,
    a_values: Vec<f64>,
    symbolic: SymbolicCholesky<usize>,
    l_values: Vec<f64>,
    factored: bool,
    stack: MemBuffer,
    /// Our own substitution over a supernodal factor (`None`: `faer` chose a simplicial one,
    /// whose solve it then does).
    supernodal: Option<SupernodalSolver>,
}

impl UpperLlt {
    fn new(dim: usize, col_ptr: Vec<usize>, row_idx: Vec<usize>) -> Result<Self, LinalgError> {
        let nnz = row_idx.len();
        let symbolic_a = SymbolicSparseColMat::new_checked(dim, dim, col_ptr, None, row_idx);
        let symbolic = factorize_symbolic_cholesky(
            symbolic_a.as_ref(),
            Side::Upper,
            SymmetricOrdering::Amd,
            CholeskySymbolicParams {
                supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
                ..Default::default()
            },
        )
        .map_err(|e| LinalgError::Symbolic(format!("{e:?}")))?;
        let req = StackReq::any_of(&[
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(1, Par::Seq),
        ]);
        let stack = MemBuffer::try_new(req).map_err(|_| LinalgError::OutOfMemory)?;
        let supernodal = match symbolic.raw() {
            SymbolicCholeskyRaw::Supernodal(sn) => Some(SupernodalSolver::new(
                sn,
                symbolic.perm().map(|p| p.arrays().0),
                dim,
            )),
            SymbolicCholeskyRaw::Simplicial(_) => None,
        };
        Ok(UpperLlt {
            dim,
            symbolic_a,
            a_values: vec![0.0; nnz],
            l_values: vec![0.0; symbolic.len_val()],
            symbolic,
            factored: false,
            stack,
            supernodal,
        })
    }

    /// Factorizes the values now in `a_values`; errors name the scalar row.
    fn factorize(&mut self) -> Result<(), LinalgError> {
        if let Some(bad) = self.a_values.iter().position(|v| !v.is_finite()) {
            self.factored = false;
            return Err(LinalgError::NonFinite {
                dof: self.symbolic_a.row_idx()[bad],
            });
        }
        let a = SparseColMatRef::new(self.symbolic_a.as_ref(), &self.a_values);
        let result = self.symbolic.factorize_numeric_llt(
            &mut self.l_values,
            a,
            Side::Upper,
            LltRegularization::default(),
            Par::Seq,
            MemStack::new(&mut self.stack),
            Default::default(),
        );
        match result {
            Ok(_) => {
                self.factored = true;
                if let Some(sn) = &mut self.supernodal {
                    sn.refresh_pivots(&self.l_values);
                }
                Ok(())
            }
            Err(LltError::NonPositivePivot { index }) => {
                self.factored = false;
                let dof = match self.symbolic.perm() {
                    Some(p) => p.arrays().0[index],
                    None => index,
                };
                Err(LinalgError::NotPositiveDefinite { dof })
            }
        }
    }

    fn solve_in_place(&mut self, rhs: &mut [f64]) -> Result<(), LinalgError> {
        if !self.factored {
            return Err(LinalgError::NotFactored);
        }
        if let Some(sn) = &mut self.supernodal {
            assert_eq!(rhs.len(), self.dim, "one right-hand side entry per unknown");
            sn.solve_in_place(&self.l_values, rhs);
            return Ok(());
        }
        self.faer_solve_in_place(rhs);
        Ok(())
    }

    /// `faer`'s own solve (for simplicial factors, and to check ours against).
    fn faer_solve_in_place(&mut self, rhs: &mut [f64]) {
        let llt = LltRef::new(&self.symbolic, &self.l_values);
        let rhs = MatMut::from_column_major_slice_mut(rhs, self.dim, 1);
        llt.solve_in_place_with_conj(Conj::No, rhs, Par::Seq, MemStack::new(&mut self.stack));
    }
}

/// `L L^T` factorization of the scalar matrix behind a [`BlockSparse`], where the rows and
/// columns of fixed degrees of freedom are replaced by the identity (so a right-hand side that
/// is zero there gives a solution that is zero there).
pub struct SparseCholesky {
    /// For each stored upper-triangle entry: the flat index `9 * block + (a + 3 b)` into the
    /// block storage, or a sentinel for a fixed entry (zero, or one on the diagonal).
    source: Vec<u32>,
    llt: UpperLlt,
    /// Fixed flag per unknown.
    fixed: Vec<bool>,
    /// Workspace of [`SparseCholesky::solve_nodes`] when `faer` solves.
    flat: Vec<f64>,
}

impl std::fmt::Debug for SparseCholesky {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SparseCholesky")
            .field("dim", &self.llt.dim)
            .field("a_nnz", &self.llt.a_values.len())
            .field("l_nnz", &self.llt.l_values.len())
            .finish()
    }
}

impl SparseCholesky {
    /// Symbolic analysis of the pattern of `matrix` with `fixed[dof]` marking the eliminated
    /// degrees of freedom (`3 * node + axis`).
    ///
    /// # Panics
    /// If `fixed.len() != 3 * matrix.nodes()`.
    pub fn new(matrix: &BlockSparse, fixed: &[bool]) -> Result<Self, LinalgError> {
        let n = matrix.nodes();
        let dim = 3 * n;
        assert_eq!(fixed.len(), dim, "one fixed flag per degree of freedom");
        // Upper triangle by column: for scalar column c = 3j + b, rows r = 3i + a <= c with
        // block (i, j) stored. The block row i of column j is block column i of row j (the
        // pattern is symmetric), so walk row j of the block matrix.
        let mut col_ptr = Vec::with_capacity(dim + 1);
        let mut row_idx = Vec::new();
        let mut source = Vec::new();
        col_ptr.push(0usize);
        for j in 0..n {
            let (cols, range) = matrix.row(j);
            for b in 0..3 {
                let c = 3 * j + b;
                for (&i, _k) in cols.iter().zip(range.clone()) {
                    let i = i as usize;
                    if i > j {
                        break;
                    }
                    // Block (i, j) is the transpose of block (j, i) = storage k of row j; use
                    // block (i, j) itself for clarity.
                    let kij = matrix.block_index(i, j).expect("symmetric pattern");
                    for a in 0..3 {
                        let r = 3 * i + a;
                        if r > c {
                            continue;
                        }
                        row_idx.push(r);
                        source.push(if fixed[r] || fixed[c] {
                            if r == c { ENTRY_ONE } else { ENTRY_ZERO }
                        } else {
                            (9 * kij + a + 3 * b) as u32
                        });
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        Ok(SparseCholesky {
            llt: UpperLlt::new(dim, col_ptr, row_idx)?,
            source,
            fixed: fixed.to_vec(),
            flat: vec![0.0; dim],
        })
    }

    /// Number of scalar unknowns.
    pub fn dim(&self) -> usize {
        self.llt.dim
    }

    /// Number of stored entries of the factor `L`.
    pub fn factor_nnz(&self) -> usize {
        self.llt.l_values.len()
    }

    /// Numeric factorization of the current values of `matrix` (same pattern as at
    /// construction). On failure the previous factorization is discarded.
    pub fn factorize(&mut self, matrix: &BlockSparse) -> Result<(), LinalgError> {
        let blocks = matrix.blocks();
        for (v, &s) in self.llt.a_values.iter_mut().zip(&self.source) {
            *v = match s {
                ENTRY_ZERO => 0.0,
                ENTRY_ONE => 1.0,
                s => {
                    let s = s as usize;
                    blocks[s / 9][s % 9]
                }
            };
        }
        self.llt.factorize()
    }

    /// Solves `A x = rhs` in place. Does nothing but return an error when no factorization is
    /// held.
    ///
    /// # Panics
    /// If `rhs.len() != self.dim()`.
    pub fn solve_in_place(&mut self, rhs: &mut [f64]) -> Result<(), LinalgError> {
        self.llt.solve_in_place(rhs)
    }

    /// Solves `A x = b` for node vectors (unknown `3 i + a` is component `a` of node `i`);
    /// fixed components of `b` are ignored and those of `x` set to zero. No allocation.
    ///
    /// # Panics
    /// If `b` or `x` does not have `dim() / 3` nodes.
    pub fn solve_nodes(&mut self, b: &[Vec3], x: &mut [Vec3]) -> Result<(), LinalgError> {
        assert!(
            3 * b.len() == self.llt.dim && 3 * x.len() == self.llt.dim,
            "one node vector per three unknowns"
        );
        if !self.llt.factored {
            return Err(LinalgError::NotFactored);
        }
        if let Some(sn) = &mut self.llt.supernodal {
            sn.solve_nodes(&self.llt.l_values, &self.fixed, b, x);
            return Ok(());
        }
        for (d, v) in self.flat.iter_mut().enumerate() {
            *v = if self.fixed[d] { 0.0 } else { b[d / 3][d % 3] };
        }
        self.llt.faer_solve_in_place(&mut self.flat);
        for (d, v) in self.flat.iter().enumerate() {
            x[d / 3][d % 3] = if self.fixed[d] { 0.0 } else { *v };
        }
        Ok(())
    }
}

impl SparseCholesky {
    /// `out[a] = A^-1 sum_k e_(3 k + a)` over the nodes `k` in `nodes`: for one node, its
    /// three columns of `A^-1`; for several, the sums of theirs (the response to a unit force
    /// along axis `a` on each of them). Zero on fixed unknowns; a fixed unit is left out. With
    /// a supernodal factor the forward substitution visits only the supernodes the unit
    /// right-hand sides reach, for the three at once (the numbers equal three solves' to
    /// rounding); otherwise three ordinary solves. No allocation once warm.
    ///
    /// # Panics
    /// If a column of `out` does not have `dim() / 3` nodes, or a node is out of range.
    pub fn solve_unit_nodes(
        &mut self,
        nodes: &[u32],
        out: [&mut [Vec3]; 3],
    ) -> Result<(), LinalgError> {
        assert!(
            out.iter().all(|c| 3 * c.len() == self.llt.dim)
                && nodes.iter().all(|&k| 3 * (k as usize) < self.llt.dim),
            "one node vector per three unknowns"
        );
        if !self.llt.factored {
            return Err(LinalgError::NotFactored);
        }
        if let Some(sn) = &mut self.llt.supernodal {
            sn.solve_unit_nodes(&self.llt.l_values, &self.fixed, nodes, out);
            return Ok(());
        }
        for (a, column) in out.into_iter().enumerate() {
            self.flat.fill(0.0);
            for &k in nodes {
                let d = 3 * k as usize + a;
                if !self.fixed[d] {
                    self.flat[d] += 1.0;
                }
            }
            self.llt.faer_solve_in_place(&mut self.flat);
            for (d, v) in self.flat.iter().enumerate() {
                column[d / 3][d % 3] = if self.fixed[d] { 0.0 } else { *v };
            }
        }
        Ok(())
    }
}

/// `L L^T` factorization of a symmetric scalar sparse matrix assembled from entries, with
/// fixed unknowns replaced by identity rows and columns (as [`SparseCholesky`] does for
/// blocks). Used by the heat solver. Errors name the scalar unknown in `dof`.
pub struct ScalarCholesky {
    llt: UpperLlt,
}

impl std::fmt::Debug for ScalarCholesky {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ScalarCholesky")
            .field("dim", &self.llt.dim)
            .field("l_nnz", &self.llt.l_values.len())
            .finish()
    }
}

impl ScalarCholesky {
    /// Assembles and factorizes the `dim x dim` symmetric matrix summed from `entries`
    /// (`(row, column, value)`, duplicates add). Only the upper triangle is read: entries with
    /// `row > column` are skipped, so a full symmetric assembly can be passed as it is. The
    /// rows and columns of `fixed` unknowns are replaced by the identity.
    ///
    /// # Panics
    /// If `fixed.len() != dim` or an entry index is `>= dim`.
    pub fn new(
        dim: usize,
        entries: impl IntoIterator<Item = (usize, usize, f64)>,
        fixed: &[bool],
    ) -> Result<Self, LinalgError> {
        assert_eq!(fixed.len(), dim, "one fixed flag per unknown");
        let mut columns: Vec<std::collections::BTreeMap<usize, f64>> =
            vec![Default::default(); dim];
        for (r, c, v) in entries {
            assert!(
                r < dim && c < dim,
                "entry ({r}, {c}) outside a {dim} x {dim} matrix"
            );
            if r > c || fixed[r] || fixed[c] {
                continue;
            }
            *columns[c].entry(r).or_insert(0.0) += v;
        }
        for (i, &f) in fixed.iter().enumerate() {
            if f {
                columns[i].insert(i, 1.0);
            } else {
                columns[i].entry(i).or_insert(0.0);
            }
        }
        let mut col_ptr = Vec::with_capacity(dim + 1);
        let mut row_idx = Vec::new();
        let mut values = Vec::new();
        col_ptr.push(0);
        for col in &columns {
            for (&r, &v) in col {
                row_idx.push(r);
                values.push(v);
            }
            col_ptr.push(row_idx.len());
        }
        let mut llt = UpperLlt::new(dim, col_ptr, row_idx)?;
        llt.a_values.copy_from_slice(&values);
        llt.factorize()?;
        Ok(ScalarCholesky { llt })
    }

    /// Number of unknowns.
    pub fn dim(&self) -> usize {
        self.llt.dim
    }

    /// Number of stored entries of the factor `L`.
    pub fn factor_nnz(&self) -> usize {
        self.llt.l_values.len()
    }

    /// Solves `A x = rhs` in place (no allocation).
    ///
    /// # Panics
    /// If `rhs.len() != self.dim()`.
    pub fn solve_in_place(&mut self, rhs: &mut [f64]) -> Result<(), LinalgError> {
        self.llt.solve_in_place(rhs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    /// A symmetric positive definite scalar matrix with the sparsity of a 3D grid Laplacian
    /// (7-point stencil, `side^3` unknowns) plus a diagonal shift, and pseudo-random weights.
    fn grid_entries(side: usize) -> (usize, Vec<(usize, usize, f64)>) {
        let n = side * side * side;
        let id = |i: usize, j: usize, k: usize| (k * side + j) * side + i;
        let mut seed = 12345u64;
        let mut rand = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut entries = Vec::new();
        for k in 0..side {
            for j in 0..side {
                for i in 0..side {
                    let a = id(i, j, k);
                    entries.push((a, a, 0.1));
                    for (di, dj, dk) in [(1, 0, 0), (0, 1, 0), (0, 0, 1)] {
                        let (ni, nj, nk) = (i + di, j + dj, k + dk);
                        if ni < side && nj < side && nk < side {
                            let b = id(ni, nj, nk);
                            let w = 0.5 + rand();
                            entries.push((a, a, w));
                            entries.push((b, b, w));
                            entries.push((a.min(b), a.max(b), -w));
                        }
                    }
                }
            }
        }
        (n, entries)
    }

    /// Our supernodal substitution gives what `faer`'s solve gives (both solve the same
    /// factor; they differ only in summation order, so to a few ulps of the solution), and
    /// the solution satisfies the system to rounding.
    #[test]
    fn own_supernodal_solve_matches_faer() {
        let (n, entries) = grid_entries(12);
        let mut fixed = vec![false; n];
        fixed[5] = true;
        fixed[700] = true;
        let mut chol = ScalarCholesky::new(n, entries.clone(), &fixed).unwrap();
        let sn = chol
            .llt
            .supernodal
            .as_ref()
            .expect("a 3D grid gets a supernodal factor");
        assert!(sn.supernodes() < n, "supernodes merge columns");
        let b: Vec<f64> = (0..n)
            .map(|i| ((i * 37) % 101) as f64 / 50.0 - 1.0)
            .collect();
        let mut ours = b.clone();
        chol.solve_in_place(&mut ours).unwrap();
        let mut theirs = b.clone();
        chol.llt.faer_solve_in_place(&mut theirs);
        let scale = theirs.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (i, (a, t)) in ours.iter().zip(&theirs).enumerate() {
            assert!((a - t).abs() <= 1e-12 * scale, "unknown {i}: {a} vs {t}");
        }
        // Residual of the original system on the free unknowns; fixed ones are identity rows.
        let mut ax = vec![0.0; n];
        for &(r, c, v) in &entries {
            if fixed[r] || fixed[c] {
                continue;
            }
            ax[r] += v * ours[c];
            if r != c {
                ax[c] += v * ours[r];
            }
        }
        for i in 0..n {
            let expect = if fixed[i] { ours[i] } else { ax[i] };
            assert!(
                (expect - b[i]).abs() < 1e-10,
                "row {i}: {expect} vs {}",
                b[i]
            );
        }
    }

    /// The three unit columns of a node, computed by substitutions that skip the supernodes
    /// the right-hand side has not reached, equal three ordinary solves to rounding, with
    /// fixed unknowns zero and a fixed unknown's own column zero.
    #[test]
    fn unit_node_columns_equal_three_solves() {
        let side = 7;
        let n = side * side * side;
        let id = |i: usize, j: usize, k: usize| (k * side + j) * side + i;
        let mut pairs = Vec::new();
        for k in 0..side {
            for j in 0..side {
                for i in 0..side {
                    for (di, dj, dk) in [(1, 0, 0), (0, 1, 0), (0, 0, 1)] {
                        if i + di < side && j + dj < side && k + dk < side {
                            pairs.push([id(i, j, k), id(i + di, j + dj, k + dk)]);
                        }
                    }
                }
            }
        }
        let mut m = BlockSparse::from_pairs(n, pairs);
        // Each edge a spring-like block (coupled axes), plus a mass on the diagonal.
        for i in 0..n {
            let (cols, range) = m.row(i);
            let cols = cols.to_vec();
            for (&j, k) in cols.iter().zip(range) {
                let j = j as usize;
                if j == i {
                    continue;
                }
                let (lo, hi) = (i.min(j), i.max(j));
                let d = Vec3::new(1.0 + (lo % 3) as f64, 0.5, 0.25 + (hi % 2) as f64).normalize();
                let b = -(d * d.transpose()) - Matrix3::identity() * 0.1;
                m.blocks_mut()[k] = b;
                let di = m.diag_index(i);
                m.blocks_mut()[di] -= b;
            }
            let di = m.diag_index(i);
            m.blocks_mut()[di] += Matrix3::identity() * 0.05;
        }
        let mut fixed = vec![false; 3 * n];
        fixed[3 * 17 + 1] = true;
        fixed[3 * 200] = true;
        let mut chol = SparseCholesky::new(&m, &fixed).unwrap();
        chol.factorize(&m).unwrap();
        assert!(
            chol.llt.supernodal.is_some(),
            "a 3D grid gets a supernodal factor"
        );
        for node in [0, 17, 200, n / 2, n - 1] {
            let mut cols = vec![vec![Vec3::zeros(); n]; 3];
            {
                let [a, b, c] = &mut cols[..] else {
                    unreachable!()
                };
                chol.solve_unit_nodes(&[node as u32], [a, b, c]).unwrap();
            }
            for (axis, col) in cols.iter().enumerate() {
                let mut rhs = vec![Vec3::zeros(); n];
                rhs[node][axis] = 1.0;
                let mut want = vec![Vec3::zeros(); n];
                chol.solve_nodes(&rhs, &mut want).unwrap();
                let scale = want.iter().fold(1e-300f64, |s, v| s.max(v.amax()));
                for (i, (g, w)) in col.iter().zip(&want).enumerate() {
                    assert!(
                        (g - w).amax() <= 1e-12 * scale,
                        "node {node} axis {axis} row {i}: {g:?} vs {w:?}"
                    );
                }
                if fixed[3 * node + axis] {
                    assert!(col.iter().all(|v| *v == Vec3::zeros()));
                } else {
                    assert!(
                        col[node][axis] > 0.0,
                        "a positive definite system's own entry"
                    );
                }
                assert_eq!(col[17][1], 0.0);
                assert_eq!(col[200][0], 0.0);
            }
        }
    }
}
