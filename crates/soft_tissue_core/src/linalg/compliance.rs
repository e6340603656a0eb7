//! Columns of a constant system's inverse, kept for the nodes contact touches.
//!
//! A body's contact compliance is `h^2 A^-1` on its contact nodes. For a system factorized
//! once (the rest system of the linear and corotational FEM models and of the implicit MSD,
//! the prefactored model's matrix) a column `A^-1 e` costs one substitution and stays valid
//! as long as the factor does, so the columns of the nodes a contact touched are kept, as
//! SOFA keeps its precomputed compliance (Saupin, Duriez and Cotin, ISBMS 2008), but only
//! for the nodes that touched: a pool of slots that grows as contact reaches new nodes (one
//! allocation per new slot, an event like a first touch), bounded in bytes, the least
//! recently used slot reused when it is full.
//!
//! The nodes left without columns in a request (more contact nodes than the pool holds, on
//! a large body pressed over a wide patch) are not taken as free: one more pass over the
//! factor gives the body's response to a unit force on all of them together, per axis
//! ([`crate::linalg::SparseCholesky::solve_unit_nodes`]), and each takes its own row of that
//! response as its compliance, lumped ([`assemble_blocks`]). For one node that is its exact
//! block; for a patch pressed as a whole (a face meeting a table) each node's lumped block
//! moves it as the patch moves under the sum of the forces, which is what the contact
//! solve needs to close the gaps of the patch together. The blocks between a node with
//! columns and one without are exact (by symmetry, from the kept column).

use nalgebra::Matrix3;

use crate::Vec3;

/// Bytes the column pool of one body may take (a slot holds the three columns of a node:
/// `9 n` numbers for `n` nodes), and the fewest and most slots whatever its size.
pub const POOL_BYTES: usize = 32 << 20;
const MIN_SLOTS: usize = 16;
const MAX_SLOTS: usize = 512;

/// Kept columns of `A^-1` (three per node, one per axis), by node.
#[derive(Debug, Default, Clone)]
pub struct ColumnCache {
    nodes: usize,
    /// Slot of each node (`u32::MAX`: none).
    slot_of: Vec<u32>,
    /// Node of each slot in use.
    node_of: Vec<u32>,
    /// Most slots.
    slots: usize,
    /// Last use of each slot (a counter).
    used: Vec<u64>,
    clock: u64,
    /// `3 n` vectors per slot in use: the columns for a unit force along x, y and z on the
    /// node.
    data: Vec<Vec3>,
    /// What the columns were made for (the caller's key: a step size, a model); columns
    /// made for another are dropped.
    key: u64,
    /// Columns computed so far (for diagnostics).
    computed: u64,
}

impl ColumnCache {
    /// Whether the pool exists (a body that never touched has none).
    pub fn is_ready(&self) -> bool {
        self.nodes > 0
    }

    /// Makes the pool for `nodes` nodes (empty; it grows with use), keyed by `key`: a
    /// different key forgets every column.
    pub fn prepare(&mut self, nodes: usize, key: u64) {
        if self.nodes != nodes {
            let slots = Self::capacity_for(nodes);
            *self = ColumnCache {
                nodes,
                slot_of: vec![u32::MAX; nodes],
                node_of: Vec::new(),
                slots,
                used: Vec::new(),
                clock: 0,
                data: Vec::new(),
                key,
                computed: 0,
            };
        }
        if self.key != key {
            self.forget();
            self.key = key;
        }
    }

    /// Drops every column (the system changed); the room stays.
    pub fn forget(&mut self) {
        self.slot_of.fill(u32::MAX);
        self.node_of.fill(u32::MAX);
        self.used.fill(0);
    }

    /// Columns computed since the pool was made.
    pub fn computed(&self) -> u64 {
        self.computed
    }

    /// The slot holding `node`'s columns, computing them with `solve(columns)` (which writes
    /// `A^-1 e_(node, a)` into `columns[a]`) when they are not kept. Slots used in the
    /// current request (`protect` holds their slot numbers) are never taken for another node.
    pub fn slot(
        &mut self,
        node: usize,
        protect: &[u32],
        solve: &mut dyn FnMut([&mut [Vec3]; 3]),
    ) -> u32 {
        self.clock += 1;
        let s = self.slot_of[node];
        if s != u32::MAX {
            self.used[s as usize] = self.clock;
            return s;
        }
        // A new slot while there is room, else a free one or the least recently used one not
        // protected.
        let s = if self.node_of.len() < self.slots {
            self.node_of.push(u32::MAX);
            self.used.push(0);
            self.data
                .resize(self.data.len() + 3 * self.nodes, Vec3::zeros());
            self.node_of.len() - 1
        } else {
            (0..self.node_of.len())
                .filter(|s| !protect.contains(&(*s as u32)))
                .min_by_key(|&s| {
                    if self.node_of[s] == u32::MAX {
                        0
                    } else {
                        self.used[s] + 1
                    }
                })
                .expect("the pool holds more slots than one request protects")
        };
        if self.node_of[s] != u32::MAX {
            self.slot_of[self.node_of[s] as usize] = u32::MAX;
        }
        let n = self.nodes;
        let (x, rest) = self.data[3 * s * n..3 * (s + 1) * n].split_at_mut(n);
        let (y, z) = rest.split_at_mut(n);
        solve([x, y, z]);
        self.computed += 1;
        self.node_of[s] = node as u32;
        self.slot_of[node] = s as u32;
        self.used[s] = self.clock;
        s as u32
    }

    /// The slots a pool for a system of `nodes` nodes has.
    pub fn capacity_for(nodes: usize) -> usize {
        let per_slot = 9 * nodes * std::mem::size_of::<f64>();
        (POOL_BYTES / per_slot.max(1)).clamp(MIN_SLOTS, MAX_SLOTS)
    }

    /// Most slots (one request may protect all but none beyond).
    pub fn capacity(&self) -> usize {
        self.slots
    }

    /// Column `axis` of `node`, if kept (all nodes' entries).
    pub fn column(&self, node: usize, axis: usize) -> Option<&[Vec3]> {
        let s = *self.slot_of.get(node)?;
        (s != u32::MAX).then(|| {
            let start = (3 * s as usize + axis) * self.nodes;
            &self.data[start..start + self.nodes]
        })
    }

    /// The 3x3 block `(A^-1)_(row, node of slot)`: column `a` is the response of `row` to a
    /// unit force along axis `a` on the slot's node.
    pub fn block(&self, slot: u32, row: usize) -> nalgebra::Matrix3<f64> {
        let n = self.nodes;
        let base = 3 * slot as usize * n;
        nalgebra::Matrix3::from_columns(&[
            self.data[base + row],
            self.data[base + n + row],
            self.data[base + 2 * n + row],
        ])
    }
}

/// The nodes of a request left without columns (`slots[i] == u32::MAX`), into `out`.
pub fn without_columns(nodes: &[u32], slots: &[u32], out: &mut Vec<u32>) {
    out.clear();
    out.extend(
        nodes
            .iter()
            .zip(slots)
            .filter(|(_, s)| **s == u32::MAX)
            .map(|(k, _)| *k),
    );
}

/// Writes the compliance blocks between `nodes` (row-major, `nodes.len()^2` blocks, the
/// lower triangle the transpose of the upper): `scale` times the blocks of `A^-1`, turned by `rotations[i] * block * rotations[j]^T` when
/// `rotations` is given (the warped compliance of a corotational body). `slots[i]` is the
/// slot of node `i` in `cache`, or `u32::MAX` when it has no columns: then `lumped[a]` must
/// hold `A^-1` applied to unit forces along axis `a` on every node without columns
/// together, whose rows give those nodes their (lumped) diagonal blocks, and the blocks
/// between two of them are zero (see the module docs). A lumped block that is not positive
/// definite on its free axes (a response that is no compliance) is replaced by
/// `alone(node)`.
#[allow(clippy::too_many_arguments)]
pub fn assemble_blocks(
    cache: &ColumnCache,
    slots: &[u32],
    nodes: &[u32],
    lumped: &[Vec<Vec3>; 3],
    scale: f64,
    rotations: Option<&[Matrix3<f64>]>,
    alone: &dyn Fn(u32) -> Matrix3<f64>,
    out: &mut [Matrix3<f64>],
) {
    let m = nodes.len();
    // The compliance is symmetric: each block above the diagonal is computed, the one below
    // is its transpose.
    for (j, &kj) in nodes.iter().enumerate() {
        for (i, &ki) in nodes.iter().enumerate().take(j + 1) {
            let (si, sj) = (slots[i], slots[j]);
            let block = if sj != u32::MAX {
                cache.block(sj, ki as usize) * scale
            } else if si != u32::MAX {
                // (A^-1)_(i j) = ((A^-1)_(j i))^T, and the kept column of i holds row j.
                cache.block(si, kj as usize).transpose() * scale
            } else if i == j {
                let k = kj as usize;
                let b = Matrix3::from_columns(&[lumped[0][k], lumped[1][k], lumped[2][k]]);
                let b = (b + b.transpose()) * (0.5 * scale);
                // Positive definite on the free axes (a fixed axis has a zero row and
                // column): a compliance.
                let mut test = b;
                for a in 0..3 {
                    if b.row(a).iter().all(|v| *v == 0.0) {
                        test[(a, a)] = 1.0;
                    }
                }
                let compliance = b.iter().all(|v| v.is_finite()) && test.cholesky().is_some();
                if compliance { b } else { alone(kj) }
            } else {
                Matrix3::zeros()
            };
            let turned = match rotations {
                Some(r) => r[i] * block * r[j].transpose(),
                None => block,
            };
            out[i * m + j] = turned;
            if i != j {
                out[j * m + i] = turned.transpose();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Columns are computed once per node and evicted least recently used first; a changed
    /// key forgets them.
    #[test]
    fn columns_are_kept_and_evicted_by_use() {
        let mut c = ColumnCache::default();
        c.prepare(4, 7);
        let cap = c.capacity();
        assert!(cap >= 4);
        let mut calls = 0;
        let mut solve = |cols: [&mut [Vec3]; 3]| {
            calls += 1;
            for (axis, col) in cols.into_iter().enumerate() {
                for (i, v) in col.iter_mut().enumerate() {
                    *v = Vec3::new(axis as f64, i as f64, 1.0);
                }
            }
        };
        let s0 = c.slot(0, &[], &mut solve);
        let again = c.slot(0, &[], &mut solve);
        assert_eq!(s0, again);
        assert_eq!(c.computed(), 1);
        let b = c.block(s0, 2);
        assert_eq!(b.column(1).into_owned(), Vec3::new(1.0, 2.0, 1.0));
        c.prepare(4, 8);
        c.slot(0, &[], &mut solve);
        assert_eq!(c.computed(), 2, "a new key recomputes");
    }

    /// The blocks `assemble_blocks` writes: exact where one side has columns (by symmetry
    /// when only the row's node has them), the exact block for a lone node without columns,
    /// and for several without columns each one's row of their summed response (the
    /// compliance of the patch pressed as a whole), checked against the inverse of the
    /// assembled matrix.
    #[test]
    fn blocks_are_exact_or_lumped_from_the_factor() {
        use crate::linalg::{BlockSparse, SparseCholesky};
        let n = 6;
        let mut m = BlockSparse::from_pairs(n, (0..n - 1).map(|i| [i, i + 1]));
        for i in 0..n - 1 {
            let d = Vec3::new(1.0, 0.3 * i as f64, 0.5).normalize();
            let b = d * d.transpose() + Matrix3::identity() * 0.2;
            for (r, c, v) in [(i, i + 1, -b), (i + 1, i, -b), (i, i, b), (i + 1, i + 1, b)] {
                let k = m.block_index(r, c).unwrap();
                m.blocks_mut()[k] += v;
            }
        }
        for i in 0..n {
            let k = m.diag_index(i);
            m.blocks_mut()[k] += Matrix3::identity() * 0.1;
        }
        let mut chol = SparseCholesky::new(&m, &vec![false; 3 * n]).unwrap();
        chol.factorize(&m).unwrap();
        // The dense inverse, block (i, j).
        let mut dense = nalgebra::DMatrix::<f64>::zeros(3 * n, 3 * n);
        for i in 0..n {
            let (cols, range) = m.row(i);
            for (&j, k) in cols.iter().zip(range) {
                let b = m.blocks()[k];
                for a in 0..3 {
                    for c in 0..3 {
                        dense[(3 * i + a, 3 * j as usize + c)] = b[(a, c)];
                    }
                }
            }
        }
        let inv = dense.try_inverse().unwrap();
        let block = |i: usize, j: usize| -> Matrix3<f64> {
            Matrix3::from_fn(|a, c| inv[(3 * i + a, 3 * j + c)])
        };
        let mut cache = ColumnCache::default();
        cache.prepare(n, 1);
        let nodes = [1u32, 2, 4, 5];
        let mut slots = Vec::new();
        for &k in &nodes[..2] {
            let s = cache.slot(k as usize, &slots, &mut |cols| {
                chol.solve_unit_nodes(&[k], cols).unwrap();
            });
            slots.push(s);
        }
        slots.extend([u32::MAX, u32::MAX]);
        let mut lumped: [Vec<Vec3>; 3] = std::array::from_fn(|_| vec![Vec3::zeros(); n]);
        {
            let [x, y, z] = &mut lumped;
            chol.solve_unit_nodes(&[4, 5], [x, y, z]).unwrap();
        }
        let rotations = [Matrix3::identity(); 4];
        let rotations = Some(&rotations[..]);
        let mut out = [Matrix3::zeros(); 16];
        let alone = |_: u32| Matrix3::identity() * 1e9;
        assemble_blocks(
            &cache, &slots, &nodes, &lumped, 2.0, rotations, &alone, &mut out,
        );
        let close = |a: Matrix3<f64>, b: Matrix3<f64>| (a - b).amax() <= 1e-10 * b.amax();
        for i in 0..4 {
            for j in 0..4 {
                let (ki, kj) = (nodes[i] as usize, nodes[j] as usize);
                let want = if i < 2 || j < 2 {
                    block(ki, kj) * 2.0
                } else if i == j {
                    let sum = block(ki, 4) + block(ki, 5);
                    (sum + sum.transpose()) * 0.5 * 2.0
                } else {
                    Matrix3::zeros()
                };
                assert!(
                    close(out[i * 4 + j], want)
                        || (want == Matrix3::zeros() && out[i * 4 + j] == want),
                    "block ({ki}, {kj}): {} vs {}",
                    out[i * 4 + j],
                    want
                );
            }
        }
        // A lone node without columns gets its exact block.
        {
            let [x, y, z] = &mut lumped;
            chol.solve_unit_nodes(&[4], [x, y, z]).unwrap();
        }
        let mut one = [Matrix3::zeros(); 1];
        assemble_blocks(
            &cache,
            &[u32::MAX],
            &[4],
            &lumped,
            1.0,
            None,
            &alone,
            &mut one,
        );
        assert!(close(one[0], block(4, 4)), "{} vs {}", one[0], block(4, 4));
    }
}
