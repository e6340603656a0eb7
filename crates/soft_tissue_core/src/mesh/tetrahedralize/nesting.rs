//! Nesting of a surface's closed pieces: which faces inward (a cavity), which lies inside
//! the union (dropped), read from the file's orientation.

use super::bounds;
use super::repair::signed_volume;
use crate::Vec3;
use crate::mesh::surface_tree::SurfaceTree;

/// A piece of the surface joined across manifold edges, faced outward.
pub(super) struct Piece {
    pub(super) members: Vec<usize>,
    /// Whether every edge of it has two triangles.
    closed: bool,
    pub(super) volume: f64,
    lo: Vec3,
    hi: Vec3,
    /// Whether the file had it facing outward (most of its area not turned).
    outward_in_file: bool,
}

impl Piece {
    pub(super) fn new(
        members: Vec<usize>,
        closed: bool,
        triangles: &[[u32; 3]],
        positions: &[Vec3],
        flip: &[bool],
        centre: &Vec3,
    ) -> Piece {
        let volume = members
            .iter()
            .map(|&k| signed_volume(&triangles[k], positions, centre))
            .sum();
        let corners: Vec<Vec3> = members
            .iter()
            .flat_map(|&k| triangles[k].map(|v| positions[v as usize]))
            .collect();
        let (lo, hi) = bounds(&corners);
        let (mut kept, mut turned) = (0.0, 0.0);
        for &k in &members {
            let [a, b, c] = triangles[k].map(|v| positions[v as usize]);
            let area = (b - a).cross(&(c - a)).norm();
            if flip[k] {
                turned += area;
            } else {
                kept += area;
            }
        }
        Piece {
            members,
            closed,
            volume,
            lo,
            hi,
            outward_in_file: kept >= turned,
        }
    }
}

/// Which way a piece of the surface faces once nesting is read.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Facing {
    Outward,
    /// A cavity.
    Inward,
    /// Inside a piece that faces the same way: inside the union, no part of its boundary.
    Inner,
}

/// Which way each piece faces. A closed piece lies inside another when the other's box
/// holds its box and the other's winding number exceeds one half at the centroids of (up
/// to) eight of its triangles; the smallest such is around it. Open pieces face outward. A piece around nothing faces outward. One inside another
/// faces the other way from it where the file turned the two apart: a hollow organ's inner
/// wall (written facing inward, as segmentations write it) is a cavity, and a stone inside
/// the cavity is solid again. Where the file turned them alike (a tumour written as a second
/// outward surface inside its organ), the inner one lies inside the union: not a boundary.
pub(super) fn nesting(pieces: &[Piece], triangles: &[[u32; 3]], positions: &[Vec3]) -> Vec<Facing> {
    let mut facing = vec![Facing::Outward; pieces.len()];
    if pieces.iter().filter(|p| p.closed).count() < 2 {
        return facing;
    }
    let mut order: Vec<usize> = (0..pieces.len()).filter(|&c| pieces[c].closed).collect();
    order.sort_by(|&a, &b| {
        pieces[b]
            .volume
            .total_cmp(&pieces[a].volume)
            .then(a.cmp(&b))
    });
    // Each piece's own triangles, a tree over them (built where a smaller piece may be
    // inside), and whether it ends up facing outward.
    let own: Vec<Vec<[u32; 3]>> = pieces
        .iter()
        .map(|p| match p.closed {
            true => p.members.iter().map(|&k| triangles[k]).collect(),
            false => Vec::new(),
        })
        .collect();
    let mut trees: Vec<Option<SurfaceTree<'_>>> = (0..pieces.len()).map(|_| None).collect();
    let mut outward = vec![true; pieces.len()];
    for (rank, &c) in order.iter().enumerate() {
        let piece = &pieces[c];
        let probes: Vec<Vec3> = piece
            .members
            .iter()
            .step_by(piece.members.len().div_ceil(8))
            .map(|&k| {
                triangles[k]
                    .iter()
                    .map(|&v| positions[v as usize])
                    .sum::<Vec3>()
                    / 3.0
            })
            .collect();
        // The smallest larger piece around this one: the last in volume order that holds it.
        let around = order[..rank].iter().rev().copied().find(|&a| {
            let other = &pieces[a];
            let boxed = (0..3).all(|i| other.lo[i] <= piece.lo[i] && piece.hi[i] <= other.hi[i]);
            boxed && {
                // (Every piece faces outward here: the cavities turn after.)
                let tree = trees[a].get_or_insert_with(|| SurfaceTree::new(positions, &own[a]));
                probes.iter().all(|p| tree.winding_number(p) > 0.5)
            }
        });
        if let Some(a) = around {
            if piece.outward_in_file == pieces[a].outward_in_file {
                facing[c] = Facing::Inner;
                // (What lies inside it is inside the union too: it faces as its outer one.)
                outward[c] = outward[a];
            } else {
                outward[c] = !outward[a];
                if !outward[c] {
                    facing[c] = Facing::Inward;
                }
            }
        }
    }
    facing
}
