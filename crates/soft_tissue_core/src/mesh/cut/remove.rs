//! Removing tetrahedra: tissue an electrode vaporized leaves the mesh (the same topology
//! change as a cut: a new mesh with the origin of every node, the faces it opened marked as
//! cut sides, and the cut history carried).

use super::{CutError, CutHistory, CutMesh, NodeOrigin, face_key};
use crate::mesh::TetMesh;

/// Why tetrahedra could not be removed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RemoveError {
    /// A tetrahedron index is out of range.
    #[error("tetrahedron {tet} out of range (mesh has {tets})")]
    BadTet {
        /// Index given.
        tet: usize,
        /// Tetrahedra of the mesh.
        tets: usize,
    },
    /// Nothing would be left.
    #[error("removing {0} tetrahedra would leave nothing")]
    Everything(usize),
    /// The boundary left would have an edge outside exactly two triangles (where it had
    /// none before).
    #[error("removing them would leave a boundary edge outside two triangles")]
    NotManifold,
    /// A ball to carve is not finite or has no size.
    #[error("ball {index}: {reason}")]
    BadBall {
        /// Index of the ball.
        index: usize,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// Following a ball's sphere would take more than [`super::MAX_CARVE_TETS`] new
    /// tetrahedra (a ball far finer than the mesh).
    #[error("a ball of radius {radius:e} would need more than {added} tetrahedra")]
    TooFine {
        /// Radius of the ball.
        radius: f64,
        /// Tetrahedra when refused.
        added: usize,
    },
    /// The mesh left failed to build.
    #[error(transparent)]
    Cut(#[from] CutError),
}

/// `mesh` without the tetrahedra `remove` (indices; repeats allowed), and without the nodes
/// only they used. `history` (that of the cuts before, if any) is carried; the faces the
/// removal opens are marked as cut sides. Refused where nothing would be left, or where the
/// boundary would have an edge outside two triangles and had none before.
pub fn remove_tets(
    mesh: &TetMesh,
    history: Option<&CutHistory>,
    remove: &[u32],
) -> Result<CutMesh, RemoveError> {
    let tets = mesh.tets();
    let mut gone = vec![false; tets.len()];
    for &t in remove {
        let t = t as usize;
        if t >= tets.len() {
            return Err(RemoveError::BadTet {
                tet: t,
                tets: tets.len(),
            });
        }
        gone[t] = true;
    }
    let removed = gone.iter().filter(|&&g| g).count();
    if removed == tets.len() {
        return Err(RemoveError::Everything(removed));
    }
    let history =
        history.filter(|h| h.sides.len() == tets.len() && h.on_blade.len() == mesh.node_count());
    // Faces of kept tetrahedra shared with a removed one become boundary: cut sides.
    let mut faces: std::collections::HashMap<[u32; 3], usize> = std::collections::HashMap::new();
    for (t, tet) in tets.iter().enumerate() {
        if gone[t] {
            for corner in 0..4 {
                faces.insert(face_key(tet, corner), t);
            }
        }
    }
    let mut new_index = vec![u32::MAX; mesh.node_count()];
    let mut node_origin = Vec::new();
    let mut kept = Vec::with_capacity(tets.len() - removed);
    let mut tet_origin = Vec::with_capacity(tets.len() - removed);
    let mut sides = Vec::with_capacity(tets.len() - removed);
    for (t, tet) in tets.iter().enumerate() {
        if gone[t] {
            continue;
        }
        let mut side = history.map_or([false; 4], |h| h.sides[t]);
        for (corner, s) in side.iter_mut().enumerate() {
            if faces.contains_key(&face_key(tet, corner)) {
                *s = true;
            }
        }
        let mapped = tet.map(|v| {
            let v = v as usize;
            if new_index[v] == u32::MAX {
                new_index[v] = node_origin.len() as u32;
                node_origin.push(NodeOrigin::node(v as u32));
            }
            new_index[v] as usize
        });
        kept.push(mapped);
        tet_origin.push(t as u32);
        sides.push(side);
    }
    let positions: Vec<_> = node_origin
        .iter()
        .map(|o| mesh.positions()[o.nodes[0] as usize])
        .collect();
    let on_blade = node_origin
        .iter()
        .map(|o| history.map_or(0, |h| h.on_blade[o.nodes[0] as usize]))
        .collect();
    let out = TetMesh::new(positions, kept).map_err(CutError::from)?;
    let before_closed = manifold(mesh.surface().triangles());
    if before_closed && !manifold(out.surface().triangles()) {
        return Err(RemoveError::NotManifold);
    }
    let surface = out.surface();
    let cut_faces = surface
        .triangle_tets()
        .iter()
        .enumerate()
        .filter(|&(_, &(t, corner))| sides[t as usize][corner as usize])
        .map(|(k, _)| surface.triangles()[k])
        .collect();
    Ok(CutMesh {
        mesh: out,
        node_origin,
        tet_origin,
        cut_faces,
        history: CutHistory { sides, on_blade },
        bisected: 0,
        separated: removed,
        taken_back: 0,
        smallest_volume_ratio: 1.0,
    })
}

/// Every edge of `triangles` in exactly two of them (a closed, edge-manifold surface).
pub(crate) fn manifold(triangles: &[[u32; 3]]) -> bool {
    let mut edges: Vec<(u32, u32)> = triangles
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| (a.min(b), a.max(b)))
        .collect();
    edges.sort_unstable();
    edges.chunk_by(|a, b| a == b).all(|run| run.len() == 2)
}
