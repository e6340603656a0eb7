//! Boundary conditions shared by the precise solvers: fixed degrees of freedom (Dirichlet) and
//! soft anchors (a zero-length spring from a node to a target, by default its rest position).

use serde::{Deserialize, Serialize};

use crate::Vec3;

/// Which nodes are held, and how.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Boundary {
    /// Fixed nodes with the axes that are held (`[true; 3]` for a fully fixed node). A fixed
    /// component keeps its current position; move it kinematically by setting the position.
    pub fixed: Vec<(usize, [bool; 3])>,
    /// Soft anchors: node and spring stiffness (force / length) towards the node's target.
    pub anchors: Vec<(usize, f64)>,
}

/// A boundary condition that does not fit the body.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BoundaryError {
    /// A node index is out of range.
    #[error("{what} names node {node}, but the body has {nodes} nodes")]
    NodeOutOfRange {
        /// `"fixed"` or `"anchor"`.
        what: &'static str,
        /// The index given.
        node: usize,
        /// Number of nodes.
        nodes: usize,
    },
    /// An anchor stiffness is negative or not finite.
    #[error("anchor on node {node} has stiffness {stiffness}; it must be finite and >= 0")]
    BadStiffness {
        /// The node.
        node: usize,
        /// The stiffness given.
        stiffness: f64,
    },
}

impl Boundary {
    /// No constraint: the body floats freely.
    pub fn free() -> Self {
        Boundary::default()
    }

    /// Fully fixes the given nodes.
    pub fn fixed_nodes(nodes: impl IntoIterator<Item = usize>) -> Self {
        Boundary {
            fixed: nodes.into_iter().map(|n| (n, [true; 3])).collect(),
            anchors: Vec::new(),
        }
    }

    /// Fully fixes the nodes whose coordinate along `axis` lies within `fraction` of the
    /// body's extent from its minimum (e.g. the bottom 10 % of an organ resting on a table).
    /// At least the lowest node is fixed.
    pub fn fixed_below(positions: &[Vec3], axis: usize, fraction: f64) -> Self {
        let lo = positions
            .iter()
            .map(|p| p[axis])
            .fold(f64::INFINITY, f64::min);
        let hi = positions
            .iter()
            .map(|p| p[axis])
            .fold(f64::NEG_INFINITY, f64::max);
        let cut = lo + fraction.max(0.0) * (hi - lo);
        let mut nodes: Vec<usize> = (0..positions.len())
            .filter(|&i| positions[i][axis] <= cut)
            .collect();
        if nodes.is_empty()
            && let Some(i) = (0..positions.len())
                .min_by(|&a, &b| positions[a][axis].total_cmp(&positions[b][axis]))
        {
            nodes.push(i);
        }
        Boundary::fixed_nodes(nodes)
    }

    /// Anchors every node to its rest position with the given stiffness.
    pub fn anchored(nodes: usize, stiffness: f64) -> Self {
        Boundary {
            fixed: Vec::new(),
            anchors: (0..nodes).map(|n| (n, stiffness)).collect(),
        }
    }

    /// Whether anything removes the rigid motions (some fixed node or anchor).
    pub fn is_constrained(&self) -> bool {
        self.fixed.iter().any(|(_, f)| f.iter().any(|&a| a))
            || self.anchors.iter().any(|&(_, k)| k > 0.0)
    }

    /// Per-node fixed masks and anchor stiffnesses for a body of `nodes` nodes (repeated
    /// entries combine: masks are or-ed, stiffnesses added).
    pub fn resolve(&self, nodes: usize) -> Result<(Vec<[bool; 3]>, Vec<f64>), BoundaryError> {
        let mut fixed = vec![[false; 3]; nodes];
        let mut anchors = vec![0.0; nodes];
        for &(n, mask) in &self.fixed {
            if n >= nodes {
                return Err(BoundaryError::NodeOutOfRange {
                    what: "fixed",
                    node: n,
                    nodes,
                });
            }
            for a in 0..3 {
                fixed[n][a] |= mask[a];
            }
        }
        for &(n, k) in &self.anchors {
            if n >= nodes {
                return Err(BoundaryError::NodeOutOfRange {
                    what: "anchor",
                    node: n,
                    nodes,
                });
            }
            if !(k.is_finite() && k >= 0.0) {
                return Err(BoundaryError::BadStiffness {
                    node: n,
                    stiffness: k,
                });
            }
            anchors[n] += k;
        }
        Ok((fixed, anchors))
    }
}
