//! Symmetric block-sparse matrices with 3x3 blocks (one block per node pair).
//!
//! Both triangles are stored so a product is one pass over rows. The pattern is fixed when the
//! matrix is built (from the pairs of nodes that interact: tetrahedron edges, springs); values
//! are re-assembled in place each step through precomputed block indices (the scatter map), so
//! nothing allocates in a step.

use nalgebra::Matrix3;

use crate::Vec3;

/// A square matrix of `n x n` blocks of 3x3, with a fixed symmetric pattern and the diagonal
/// always present.
#[derive(Debug, Clone)]
pub struct BlockSparse {
    row_ptr: Vec<usize>,
    cols: Vec<u32>,
    diag: Vec<usize>,
    /// For each stored block `(i, j)`, the storage index of `(j, i)`.
    transpose: Vec<u32>,
    blocks: Vec<Matrix3<f64>>,
}

impl BlockSparse {
    /// A zero matrix over `n` nodes whose pattern holds the diagonal and both `(a, b)` and
    /// `(b, a)` for every pair. Repeated pairs and pairs `(a, a)` are allowed.
    ///
    /// # Panics
    /// If a pair names a node `>= n` (callers pass validated mesh indices).
    pub fn from_pairs(n: usize, pairs: impl IntoIterator<Item = [usize; 2]>) -> Self {
        let mut rows: Vec<Vec<u32>> = (0..n).map(|i| vec![i as u32]).collect();
        for [a, b] in pairs {
            assert!(a < n && b < n, "pair ({a}, {b}) out of range for {n} nodes");
            if a != b {
                rows[a].push(b as u32);
                rows[b].push(a as u32);
            }
        }
        let mut row_ptr = Vec::with_capacity(n + 1);
        let mut cols = Vec::new();
        let mut diag = Vec::with_capacity(n);
        row_ptr.push(0);
        for (i, row) in rows.iter_mut().enumerate() {
            row.sort_unstable();
            row.dedup();
            let start = cols.len();
            let d = row.binary_search(&(i as u32)).expect("diagonal present");
            diag.push(start + d);
            cols.extend_from_slice(row);
            row_ptr.push(cols.len());
        }
        let nnz = cols.len();
        let mut m = BlockSparse {
            row_ptr,
            cols,
            diag,
            transpose: Vec::new(),
            blocks: vec![Matrix3::zeros(); nnz],
        };
        m.transpose = (0..n)
            .flat_map(|i| (m.row_ptr[i]..m.row_ptr[i + 1]).map(move |k| (i, k)))
            .map(|(i, k)| {
                m.block_index(m.cols[k] as usize, i)
                    .expect("symmetric pattern") as u32
            })
            .collect();
        m
    }

    /// Number of block rows (nodes).
    pub fn nodes(&self) -> usize {
        self.diag.len()
    }

    /// Number of stored blocks (both triangles and the diagonal).
    pub fn stored_blocks(&self) -> usize {
        self.cols.len()
    }

    /// Index of block `(i, j)` in the storage, if it is in the pattern.
    pub fn block_index(&self, i: usize, j: usize) -> Option<usize> {
        let row = &self.cols[self.row_ptr[i]..self.row_ptr[i + 1]];
        row.binary_search(&(j as u32))
            .ok()
            .map(|k| self.row_ptr[i] + k)
    }

    /// Index of diagonal block `i`.
    pub fn diag_index(&self, i: usize) -> usize {
        self.diag[i]
    }

    /// Block columns and storage range of row `i`.
    pub fn row(&self, i: usize) -> (&[u32], std::ops::Range<usize>) {
        let r = self.row_ptr[i]..self.row_ptr[i + 1];
        (&self.cols[r.clone()], r)
    }

    /// The stored blocks.
    pub fn blocks(&self) -> &[Matrix3<f64>] {
        &self.blocks
    }

    /// The stored blocks, to assemble into.
    pub fn blocks_mut(&mut self) -> &mut [Matrix3<f64>] {
        &mut self.blocks
    }

    /// Sets every value to zero, keeping the pattern.
    pub fn set_zero(&mut self) {
        self.blocks.fill(Matrix3::zeros());
    }

    /// Sets the diagonal and upper-triangle blocks (`j >= i`) to zero.
    pub fn set_upper_zero(&mut self) {
        for i in 0..self.nodes() {
            for k in self.diag[i]..self.row_ptr[i + 1] {
                self.blocks[k] = Matrix3::zeros();
            }
        }
    }

    /// Copies every upper-triangle block `(i, j)`, `j > i`, transposed into `(j, i)`, so a
    /// matrix assembled in its upper triangle only becomes the full symmetric matrix.
    pub fn mirror_upper(&mut self) {
        for i in 0..self.nodes() {
            for k in self.diag[i] + 1..self.row_ptr[i + 1] {
                let t = self.transpose[k] as usize;
                self.blocks[t] = self.blocks[k].transpose();
            }
        }
    }

    /// Copies block `k` transposed into its mirror `(j, i)` (nothing for a diagonal block).
    pub fn mirror_block(&mut self, k: usize) {
        let t = self.transpose[k] as usize;
        if t != k {
            self.blocks[t] = self.blocks[k].transpose();
        }
    }

    /// Copies the values of a matrix with the same pattern.
    ///
    /// # Panics
    /// If the patterns differ in size.
    pub fn copy_values_from(&mut self, other: &BlockSparse) {
        self.blocks.copy_from_slice(&other.blocks);
    }

    /// `y = A x`.
    pub fn mul(&self, x: &[Vec3], y: &mut [Vec3]) {
        for (i, yi) in y.iter_mut().enumerate().take(self.nodes()) {
            *yi = self.row_product(i, x);
        }
    }

    /// `y += s A x`.
    pub fn mul_add(&self, s: f64, x: &[Vec3], y: &mut [Vec3]) {
        for (i, yi) in y.iter_mut().enumerate().take(self.nodes()) {
            *yi += s * self.row_product(i, x);
        }
    }

    /// Block row `i` times `x`, with two running sums (even and odd blocks) so consecutive
    /// blocks do not wait on each other's additions.
    #[inline(always)]
    fn row_product(&self, i: usize, x: &[Vec3]) -> Vec3 {
        let range = self.row_ptr[i]..self.row_ptr[i + 1];
        let blocks = &self.blocks[range.clone()];
        let cols = &self.cols[range];
        let (mut a0, mut a1) = (Vec3::zeros(), Vec3::zeros());
        let pairs = blocks.chunks_exact(2).zip(cols.chunks_exact(2));
        for (b, c) in pairs {
            a0 += b[0] * x[c[0] as usize];
            a1 += b[1] * x[c[1] as usize];
        }
        if blocks.len() % 2 == 1 {
            let k = blocks.len() - 1;
            a0 += blocks[k] * x[cols[k] as usize];
        }
        a0 + a1
    }

    /// Largest absolute difference between `A` and `A^T` (a check for assembly code).
    pub fn asymmetry(&self) -> f64 {
        let mut worst = 0.0f64;
        for i in 0..self.nodes() {
            for k in self.row_ptr[i]..self.row_ptr[i + 1] {
                let j = self.cols[k] as usize;
                let kt = self.block_index(j, i).expect("symmetric pattern");
                worst = worst.max((self.blocks[k] - self.blocks[kt].transpose()).abs().max());
            }
        }
        worst
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn product_matches_dense() {
        let mut a = BlockSparse::from_pairs(3, [[0, 1], [1, 2], [1, 0]]);
        assert_eq!(a.stored_blocks(), 7);
        let k01 = a.block_index(0, 1).unwrap();
        let k10 = a.block_index(1, 0).unwrap();
        let m = Matrix3::new(1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0);
        a.blocks_mut()[k01] = m;
        a.blocks_mut()[k10] = m.transpose();
        let d2 = a.diag_index(2);
        a.blocks_mut()[d2] = Matrix3::identity() * 2.0;
        assert!(a.block_index(0, 2).is_none());
        let x = [
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.0, 0.0, 1.0),
        ];
        let mut y = [Vec3::zeros(); 3];
        a.mul(&x, &mut y);
        assert_eq!(y[0], m * x[1]);
        assert_eq!(y[1], m.transpose() * x[0]);
        assert_eq!(y[2], Vec3::new(0.0, 0.0, 2.0));
        assert_eq!(a.asymmetry(), 0.0);
    }
}
