//! Measuring a cut: volume, element shape, boundary, orphans, pieces.

use std::collections::HashMap;

use super::*;

/// Checks of a cut mesh against the mesh before it.
#[derive(Debug, Clone, PartialEq)]
pub struct CutCheck {
    /// Relative change of the total volume.
    pub volume_change: f64,
    /// Smallest tetrahedron volume over its parent's, signed, as cut
    /// ([`CutMesh::smallest_volume_ratio`]).
    pub smallest_volume_ratio: f64,
    /// Smallest dihedral angle of any tetrahedron, degrees.
    pub smallest_dihedral: f64,
    /// Edges of the boundary in other than two boundary triangles.
    pub non_manifold_edges: usize,
    /// Nodes in no tetrahedron.
    pub orphan_nodes: usize,
    /// Connected pieces.
    pub pieces: usize,
}

/// Measures a cut against the mesh before it (see [`CutCheck`]).
pub fn check(before: &TetMesh, after: &CutMesh) -> CutCheck {
    let m = &after.mesh;
    let p = m.positions();
    let smallest_volume_ratio = after.smallest_volume_ratio;
    let mut smallest_dihedral = f64::INFINITY;
    for tet in m.tets() {
        let mut corners = tet.map(|i| p[i as usize]);
        if tet_signed_volume(&corners) < 0.0 {
            corners.swap(0, 1);
        }
        for a in tet_dihedral_angles(&corners) {
            smallest_dihedral = smallest_dihedral.min(a);
        }
    }
    let mut used = vec![false; m.node_count()];
    for tet in m.tets() {
        for &v in tet {
            used[v as usize] = true;
        }
    }
    let non_manifold_edges = bad_edges(m.tets(), &vec![false; m.tet_count()]).len();
    CutCheck {
        volume_change: (m.volume() - before.volume()) / before.volume(),
        smallest_volume_ratio,
        smallest_dihedral,
        non_manifold_edges,
        orphan_nodes: used.iter().filter(|u| !**u).count(),
        pieces: m.component_count(),
    }
}

/// Edges of the boundary of the tetrahedra not `gone` that lie in other than two of its
/// triangles, sorted.
pub(super) fn bad_edges(tets: &[[u32; 4]], gone: &[bool]) -> Vec<(u32, u32)> {
    let mut faces: HashMap<[u32; 3], u32> = HashMap::new();
    for (t, tet) in tets.iter().enumerate() {
        if !gone[t] {
            for o in 0..4 {
                *faces.entry(face_key(tet, o)).or_insert(0) += 1;
            }
        }
    }
    let mut edges: Vec<(u32, u32)> = faces
        .iter()
        .filter(|&(_, &n)| n == 1)
        .flat_map(|(f, _)| [(f[0], f[1]), (f[1], f[2]), (f[0], f[2])])
        .collect();
    edges.sort_unstable();
    edges
        .chunk_by(|a, b| a == b)
        .filter(|run| run.len() != 2)
        .map(|run| run[0])
        .collect()
}
