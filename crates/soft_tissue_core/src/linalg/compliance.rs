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
            let per_slot = 9 * nodes * std::mem::size_of::<f64>();
            let slots = (POOL_BYTES / per_slot.max(1)).clamp(MIN_SLOTS, MAX_SLOTS);
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

    /// The slot holding `node`'s columns, computing them with `solve(axis, column)` (which
    /// writes `A^-1 e_(node, axis)` into `column`) when they are not kept. Slots used in the
    /// current request (`protect` holds their slot numbers) are never taken for another node.
    pub fn slot(
        &mut self,
        node: usize,
        protect: &[u32],
        solve: &mut dyn FnMut(usize, &mut [Vec3]),
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
        for axis in 0..3 {
            let start = (3 * s + axis) * n;
            solve(axis, &mut self.data[start..start + n]);
        }
        self.computed += 1;
        self.node_of[s] = node as u32;
        self.slot_of[node] = s as u32;
        self.used[s] = self.clock;
        s as u32
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
        let mut solve = |axis: usize, col: &mut [Vec3]| {
            calls += 1;
            for (i, v) in col.iter_mut().enumerate() {
                *v = Vec3::new(axis as f64, i as f64, 1.0);
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
}
