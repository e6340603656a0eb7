//! Triangular solves with a supernodal Cholesky factor held by `faer`, written for the small
//! systems of one body (hundreds to a few thousand unknowns, supernodes a few columns wide).
//!
//! `faer`'s own solve goes through its general dense kernels for every supernode, which costs
//! more in dispatch than in arithmetic at these sizes. Here the supernode layout is read once
//! (start column, width, row pattern, offset of its column-major values) and the forward and
//! backward substitutions run as plain loops over contiguous columns: the dense part of a
//! supernode is an `axpy` per column forward and a dot product per column backward, with a
//! scatter or gather through its row pattern. The loops are compiled for AVX2 with FMA as well
//! as for the baseline and the widest the CPU supports is chosen at run time. The reciprocal
//! pivots are stored when the values change, so a solve divides nothing.

use faer::sparse::linalg::cholesky::supernodal::SymbolicSupernodalCholesky;

use super::madd;
use crate::Vec3;

/// One supernode: columns `start .. start + width` of `L`, stored column-major with
/// `width + pattern_len` rows from `value_offset`; its rows below the diagonal block are
/// `pattern[pattern_offset ..][.. pattern_len]`.
#[derive(Debug, Clone, Copy)]
struct Supernode {
    start: u32,
    width: u32,
    pattern_offset: u32,
    pattern_len: u32,
    value_offset: usize,
}

/// The layout of a supernodal factor and the workspace of its solves.
#[derive(Debug)]
pub(super) struct SupernodalSolver {
    nodes: Vec<Supernode>,
    pattern: Vec<u32>,
    /// `1 / L[j, j]` for every column, refreshed by [`SupernodalSolver::refresh_pivots`].
    inv_diag: Vec<f64>,
    /// Fill-reducing permutation: row `i` of the permuted system is row `perm[i]` of the
    /// original (`None`: identity).
    perm: Option<Vec<u32>>,
    /// Inverse of `perm`: the permuted row of each original row.
    inv_perm: Option<Vec<u32>>,
    x: Vec<f64>,
    tmp: Vec<f64>,
    /// Workspaces of [`SupernodalSolver::solve_unit_nodes`] (three right-hand sides side by
    /// side), sized at its first use.
    x3: Vec<[f64; 3]>,
    tmp3: Vec<[f64; 3]>,
}

impl SupernodalSolver {
    /// Reads the layout of `symbolic` (of dimension `dim`) and the forward permutation.
    pub(super) fn new(
        symbolic: &SymbolicSupernodalCholesky<usize>,
        perm: Option<&[usize]>,
        dim: usize,
    ) -> Self {
        let begin = symbolic.supernode_begin();
        let end = symbolic.supernode_end();
        let col_ptr_val = symbolic.col_ptr_for_val();
        let mut nodes = Vec::with_capacity(symbolic.n_supernodes());
        let mut pattern = Vec::new();
        let mut widest_pattern = 0;
        for s in 0..symbolic.n_supernodes() {
            let rows = symbolic.supernode(s).pattern();
            widest_pattern = widest_pattern.max(rows.len());
            nodes.push(Supernode {
                start: begin[s] as u32,
                width: (end[s] - begin[s]) as u32,
                pattern_offset: pattern.len() as u32,
                pattern_len: rows.len() as u32,
                value_offset: col_ptr_val[s],
            });
            pattern.extend(rows.iter().map(|&r| r as u32));
        }
        let inv_perm = perm.map(|p| {
            let mut inv = vec![0u32; p.len()];
            for (i, &pi) in p.iter().enumerate() {
                inv[pi] = i as u32;
            }
            inv
        });
        SupernodalSolver {
            nodes,
            pattern,
            inv_diag: vec![0.0; dim],
            perm: perm.map(|p| p.iter().map(|&i| i as u32).collect()),
            inv_perm,
            x: vec![0.0; dim],
            tmp: vec![0.0; widest_pattern],
            x3: Vec::new(),
            tmp3: Vec::new(),
        }
    }

    /// Number of supernodes.
    #[cfg(test)]
    pub(super) fn supernodes(&self) -> usize {
        self.nodes.len()
    }

    /// Stores the reciprocal pivots of the factor `values` (call after every factorization).
    pub(super) fn refresh_pivots(&mut self, values: &[f64]) {
        for n in &self.nodes {
            let ld = (n.width + n.pattern_len) as usize;
            for k in 0..n.width as usize {
                self.inv_diag[n.start as usize + k] = 1.0 / values[n.value_offset + k * ld + k];
            }
        }
    }

    /// Solves `L L^T x = rhs` in place with the factor `values`.
    pub(super) fn solve_in_place(&mut self, values: &[f64], rhs: &mut [f64]) {
        match &self.perm {
            Some(p) => {
                for (xi, &pi) in self.x.iter_mut().zip(p) {
                    *xi = rhs[pi as usize];
                }
            }
            None => self.x.copy_from_slice(rhs),
        }
        self.substitute(values);
        match &self.perm {
            Some(p) => {
                for (xi, &pi) in self.x.iter().zip(p) {
                    rhs[pi as usize] = *xi;
                }
            }
            None => rhs.copy_from_slice(&self.x),
        }
    }

    /// Solves `L L^T x = b` for node vectors (unknown `3 i + a` is component `a` of node
    /// `i`), with the unknowns flagged in `fixed` read and written as zero: the permutation
    /// and the projection in the same pass as the copies.
    pub(super) fn solve_nodes(
        &mut self,
        values: &[f64],
        fixed: &[bool],
        b: &[Vec3],
        x: &mut [Vec3],
    ) {
        match &self.perm {
            Some(p) => {
                for (xi, &pi) in self.x.iter_mut().zip(p) {
                    let d = pi as usize;
                    *xi = if fixed[d] { 0.0 } else { b[d / 3][d % 3] };
                }
            }
            None => {
                for (d, xi) in self.x.iter_mut().enumerate() {
                    *xi = if fixed[d] { 0.0 } else { b[d / 3][d % 3] };
                }
            }
        }
        self.substitute(values);
        match &self.perm {
            Some(p) => {
                for (xi, &pi) in self.x.iter().zip(p) {
                    let d = pi as usize;
                    x[d / 3][d % 3] = if fixed[d] { 0.0 } else { *xi };
                }
            }
            None => {
                for (d, xi) in self.x.iter().enumerate() {
                    x[d / 3][d % 3] = if fixed[d] { 0.0 } else { *xi };
                }
            }
        }
    }

    /// `out[a] = A^-1 sum_k e_(3 k + a)` over the nodes `k` in `nodes` (for one node, its
    /// three columns of `A^-1`), zero on fixed unknowns (a fixed unit is left out). The
    /// forward substitution skips the supernodes the unit right-hand sides have not reached
    /// (all their entries still zero), so it touches only their paths to the root of the
    /// elimination tree, and the three right-hand sides share one pass over the factor. The
    /// numbers equal three separate solves' to rounding (the sums run in another order).
    #[allow(unsafe_code)]
    pub(super) fn solve_unit_nodes(
        &mut self,
        values: &[f64],
        fixed: &[bool],
        nodes: &[u32],
        out: [&mut [Vec3]; 3],
    ) {
        let dim = self.x.len();
        if self.x3.len() != dim {
            self.x3 = vec![[0.0; 3]; dim];
            self.tmp3 = vec![[0.0; 3]; self.tmp.len()];
        }
        self.x3.fill([0.0; 3]);
        let mut any = false;
        for &node in nodes {
            for a in 0..3 {
                let d = 3 * node as usize + a;
                if !fixed[d] {
                    let p = match &self.inv_perm {
                        Some(inv) => inv[d] as usize,
                        None => d,
                    };
                    self.x3[p][a] += 1.0;
                    any = true;
                }
            }
        }
        if any {
            let parts = Parts {
                nodes: &self.nodes,
                pattern: &self.pattern,
                inv_diag: &self.inv_diag,
                values,
            };
            let (x, tmp) = (&mut self.x3, &mut self.tmp3);
            match super::kernel_variant() {
                // SAFETY: `kernel_variant` saw the features `substitute3_avx512` is compiled for.
                #[cfg(target_arch = "x86_64")]
                super::KernelVariant::Avx512 => unsafe { substitute3_avx512(&parts, x, tmp) },
                // SAFETY: `kernel_variant` saw the features `substitute3_avx2` is compiled for.
                #[cfg(target_arch = "x86_64")]
                super::KernelVariant::Avx2 => unsafe { substitute3_avx2(&parts, x, tmp) },
                super::KernelVariant::Portable => substitute3::<false>(&parts, x, tmp),
            }
        }
        let [o0, o1, o2] = out;
        let mut write = |d: usize, v: [f64; 3]| {
            let keep = !fixed[d];
            o0[d / 3][d % 3] = if keep { v[0] } else { 0.0 };
            o1[d / 3][d % 3] = if keep { v[1] } else { 0.0 };
            o2[d / 3][d % 3] = if keep { v[2] } else { 0.0 };
        };
        match &self.perm {
            Some(p) => {
                for (v, &pi) in self.x3.iter().zip(p) {
                    write(pi as usize, *v);
                }
            }
            None => {
                for (d, v) in self.x3.iter().enumerate() {
                    write(d, *v);
                }
            }
        }
    }

    /// Forward and backward substitution of `self.x` in place.
    #[allow(unsafe_code)]
    fn substitute(&mut self, values: &[f64]) {
        let x = &mut self.x;
        let parts = Parts {
            nodes: &self.nodes,
            pattern: &self.pattern,
            inv_diag: &self.inv_diag,
            values,
        };
        match super::kernel_variant() {
            // SAFETY: `kernel_variant` saw the features `substitute_avx512` is compiled for.
            #[cfg(target_arch = "x86_64")]
            super::KernelVariant::Avx512 => unsafe { substitute_avx512(&parts, x, &mut self.tmp) },
            // SAFETY: `kernel_variant` saw the features `substitute_avx2` is compiled for.
            #[cfg(target_arch = "x86_64")]
            super::KernelVariant::Avx2 => unsafe { substitute_avx2(&parts, x, &mut self.tmp) },
            super::KernelVariant::Portable => substitute::<false>(&parts, x, &mut self.tmp),
        }
    }
}

/// What a substitution reads.
struct Parts<'a> {
    nodes: &'a [Supernode],
    pattern: &'a [u32],
    inv_diag: &'a [f64],
    values: &'a [f64],
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
fn substitute_avx512(parts: &Parts, x: &mut [f64], tmp: &mut [f64]) {
    substitute::<true>(parts, x, tmp)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn substitute_avx2(parts: &Parts, x: &mut [f64], tmp: &mut [f64]) {
    substitute::<true>(parts, x, tmp)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,fma")]
fn substitute3_avx512(parts: &Parts, x: &mut [[f64; 3]], tmp: &mut [[f64; 3]]) {
    substitute3::<true>(parts, x, tmp)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn substitute3_avx2(parts: &Parts, x: &mut [[f64; 3]], tmp: &mut [[f64; 3]]) {
    substitute3::<true>(parts, x, tmp)
}

/// `c + a b` for three right-hand sides.
#[inline(always)]
fn madd3<const FMA: bool>(a: f64, b: [f64; 3], c: [f64; 3]) -> [f64; 3] {
    [
        madd::<FMA>(a, b[0], c[0]),
        madd::<FMA>(a, b[1], c[1]),
        madd::<FMA>(a, b[2], c[2]),
    ]
}

/// `sum a_i b_i` for three right-hand sides, with four running sums each.
#[inline(always)]
fn dot3<const FMA: bool>(a: &[f64], b: &[[f64; 3]]) -> [f64; 3] {
    let mut acc = [[0.0; 3]; 4];
    let (a4, b4) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ar, br) = (a4.remainder(), b4.remainder());
    for (ca, cb) in a4.zip(b4) {
        for l in 0..4 {
            acc[l] = madd3::<FMA>(ca[l], cb[l], acc[l]);
        }
    }
    let mut s = [0.0; 3];
    for c in 0..3 {
        s[c] = (acc[0][c] + acc[2][c]) + (acc[1][c] + acc[3][c]);
    }
    for (p, q) in ar.iter().zip(br) {
        s = madd3::<FMA>(*p, *q, s);
    }
    s
}

/// Forward then backward substitution of three right-hand sides side by side (one pass over
/// the factor for the three). The forward pass skips a supernode whose entries are all still
/// zero (it would change nothing), so for unit right-hand sides it visits only their paths
/// to the root of the elimination tree.
#[inline(always)]
fn substitute3<const FMA: bool>(parts: &Parts, x: &mut [[f64; 3]], tmp: &mut [[f64; 3]]) {
    let Parts {
        nodes,
        pattern,
        inv_diag,
        values,
    } = *parts;
    for n in nodes {
        let (s, w, h) = (n.start as usize, n.width as usize, n.pattern_len as usize);
        if x[s..s + w].iter().all(|v| *v == [0.0; 3]) {
            continue;
        }
        let ld = w + h;
        let v = &values[n.value_offset..n.value_offset + ld * w];
        let pat = &pattern[n.pattern_offset as usize..][..h];
        let xs = &mut x[s..s + w];
        let inv = &inv_diag[s..s + w];
        for k in 0..w {
            let (head, tail) = xs.split_at_mut(k + 1);
            let xk = head[k].map(|e| e * inv[k]);
            head[k] = xk;
            for (xi, c) in tail.iter_mut().zip(&v[k * ld + k + 1..k * ld + w]) {
                *xi = madd3::<FMA>(-c, xk, *xi);
            }
        }
        if h == 0 {
            continue;
        }
        let tmp = &mut tmp[..h];
        tmp.fill([0.0; 3]);
        for k in 0..w {
            let xk = x[s + k];
            for (t, a) in tmp.iter_mut().zip(&v[k * ld + w..k * ld + ld]) {
                *t = madd3::<FMA>(*a, xk, *t);
            }
        }
        for (t, &p) in tmp.iter().zip(pat) {
            let xp = &mut x[p as usize];
            for a in 0..3 {
                xp[a] -= t[a];
            }
        }
    }
    for n in nodes.iter().rev() {
        let (s, w, h) = (n.start as usize, n.width as usize, n.pattern_len as usize);
        let ld = w + h;
        let v = &values[n.value_offset..n.value_offset + ld * w];
        if h > 0 {
            let pat = &pattern[n.pattern_offset as usize..][..h];
            let tmp = &mut tmp[..h];
            for (t, &p) in tmp.iter_mut().zip(pat) {
                *t = x[p as usize];
            }
            for k in 0..w {
                let d = dot3::<FMA>(&v[k * ld + w..k * ld + ld], tmp);
                for a in 0..3 {
                    x[s + k][a] -= d[a];
                }
            }
        }
        let xs = &mut x[s..s + w];
        let inv = &inv_diag[s..s + w];
        for k in (0..w).rev() {
            let (head, tail) = xs.split_at_mut(k + 1);
            let d = dot3::<FMA>(&v[k * ld + k + 1..k * ld + w], tail);
            for a in 0..3 {
                head[k][a] = (head[k][a] - d[a]) * inv[k];
            }
        }
    }
}

/// Dot product with four running sums (so the compiler can keep them in one vector).
#[inline(always)]
fn dot<const FMA: bool>(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let (a4, b4) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ar, br) = (a4.remainder(), b4.remainder());
    for (ca, cb) in a4.zip(b4) {
        for l in 0..4 {
            acc[l] = madd::<FMA>(ca[l], cb[l], acc[l]);
        }
    }
    let mut s = (acc[0] + acc[2]) + (acc[1] + acc[3]);
    for (p, q) in ar.iter().zip(br) {
        s = madd::<FMA>(*p, *q, s);
    }
    s
}

/// Forward (`L y = b`) then backward (`L^T x = y`) substitution in the permuted numbering.
#[inline(always)]
fn substitute<const FMA: bool>(parts: &Parts, x: &mut [f64], tmp: &mut [f64]) {
    let Parts {
        nodes,
        pattern,
        inv_diag,
        values,
    } = *parts;
    for n in nodes {
        let (s, w, h) = (n.start as usize, n.width as usize, n.pattern_len as usize);
        let ld = w + h;
        let v = &values[n.value_offset..n.value_offset + ld * w];
        let pat = &pattern[n.pattern_offset as usize..][..h];
        let tmp = &mut tmp[..h];
        // Diagonal block: lower triangular, column by column.
        let xs = &mut x[s..s + w];
        let inv = &inv_diag[s..s + w];
        for k in 0..w {
            let (head, tail) = xs.split_at_mut(k + 1);
            let xk = head[k] * inv[k];
            head[k] = xk;
            for (xi, c) in tail.iter_mut().zip(&v[k * ld + k + 1..k * ld + w]) {
                *xi = madd::<FMA>(-c, xk, *xi);
            }
        }
        if h == 0 {
            continue;
        }
        // Below the diagonal block: tmp = L_bottom x_top, then scatter.
        tmp.fill(0.0);
        let mut k = 0;
        while k + 4 <= w {
            let xk = [x[s + k], x[s + k + 1], x[s + k + 2], x[s + k + 3]];
            let c = |j: usize| &v[(k + j) * ld + w..(k + j) * ld + ld];
            let (c0, c1, c2, c3) = (c(0), c(1), c(2), c(3));
            for ((((t, a), b), d), e) in tmp.iter_mut().zip(c0).zip(c1).zip(c2).zip(c3) {
                let u = madd::<FMA>(*a, xk[0], madd::<FMA>(*b, xk[1], *t));
                *t = madd::<FMA>(*d, xk[2], madd::<FMA>(*e, xk[3], u));
            }
            k += 4;
        }
        while k < w {
            let xk = x[s + k];
            for (t, a) in tmp.iter_mut().zip(&v[k * ld + w..k * ld + ld]) {
                *t = madd::<FMA>(*a, xk, *t);
            }
            k += 1;
        }
        for (t, &p) in tmp.iter().zip(pat) {
            x[p as usize] -= t;
        }
    }
    for n in nodes.iter().rev() {
        let (s, w, h) = (n.start as usize, n.width as usize, n.pattern_len as usize);
        let ld = w + h;
        let v = &values[n.value_offset..n.value_offset + ld * w];
        if h > 0 {
            let pat = &pattern[n.pattern_offset as usize..][..h];
            let tmp = &mut tmp[..h];
            for (t, &p) in tmp.iter_mut().zip(pat) {
                *t = x[p as usize];
            }
            for k in 0..w {
                x[s + k] -= dot::<FMA>(&v[k * ld + w..k * ld + ld], tmp);
            }
        }
        // Diagonal block transposed: upper triangular, last row first.
        let xs = &mut x[s..s + w];
        let inv = &inv_diag[s..s + w];
        for k in (0..w).rev() {
            let (head, tail) = xs.split_at_mut(k + 1);
            head[k] = (head[k] - dot::<FMA>(&v[k * ld + k + 1..k * ld + w], tail)) * inv[k];
        }
    }
}
