//! A mesh's connected pieces as meshes of their own: what a cut that came loose becomes.

use super::{MeshError, TetMesh};

/// One connected piece of a mesh.
#[derive(Debug, Clone)]
pub struct Piece {
    /// The piece, its nodes and tetrahedra in the order they have in the whole mesh.
    pub mesh: TetMesh,
    /// The node of the whole mesh each node of the piece is.
    pub nodes: Vec<u32>,
    /// The tetrahedron of the whole mesh each tetrahedron of the piece is.
    pub tets: Vec<u32>,
}

/// The pieces of `mesh` (connected through shared nodes), in the order of their first
/// tetrahedron. Unreferenced nodes belong to none. A mesh of one piece gives one piece
/// equal to it, without its unreferenced nodes.
pub fn pieces(mesh: &TetMesh) -> Result<Vec<Piece>, MeshError> {
    let component = mesh.node_components();
    // Pieces numbered by their first tetrahedron, so the order does not depend on how the
    // components were numbered.
    let mut number = vec![u32::MAX; mesh.component_count()];
    let mut count = 0u32;
    let mut tet_piece = Vec::with_capacity(mesh.tet_count());
    for t in mesh.tets() {
        let c = component[t[0] as usize] as usize;
        if number[c] == u32::MAX {
            number[c] = count;
            count += 1;
        }
        tet_piece.push(number[c]);
    }
    let mut local = vec![u32::MAX; mesh.node_count()];
    let mut out = Vec::with_capacity(count as usize);
    for p in 0..count {
        let mut nodes = Vec::new();
        let mut tets = Vec::new();
        let mut corners = Vec::new();
        for (t, tet) in mesh.tets().iter().enumerate() {
            if tet_piece[t] != p {
                continue;
            }
            tets.push(t as u32);
            corners.push(tet.map(|v| {
                if local[v as usize] == u32::MAX {
                    local[v as usize] = nodes.len() as u32;
                    nodes.push(v);
                }
                local[v as usize] as usize
            }));
        }
        let positions = nodes
            .iter()
            .map(|&v| mesh.positions()[v as usize])
            .collect();
        out.push(Piece {
            mesh: TetMesh::new(positions, corners)?,
            nodes,
            tets,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Vec3;

    #[test]
    fn two_tetrahedra_apart_are_two_pieces_and_keep_their_nodes() {
        let mut p = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(0.0, 0.0, 1.0),
        ];
        let shifted: Vec<Vec3> = p.iter().map(|x| x + Vec3::new(5.0, 0.0, 0.0)).collect();
        p.extend(shifted);
        p.push(Vec3::new(9.0, 9.0, 9.0)); // unused
        let mesh = TetMesh::new(p, vec![[4, 5, 6, 7], [0, 1, 2, 3]]).unwrap();
        let parts = pieces(&mesh).unwrap();
        assert_eq!(parts.len(), 2);
        assert_eq!(parts[0].nodes, vec![4, 5, 6, 7]);
        assert_eq!(parts[1].tets, vec![1]);
        for piece in &parts {
            for (k, &v) in piece.nodes.iter().enumerate() {
                assert_eq!(piece.mesh.positions()[k], mesh.positions()[v as usize]);
            }
            assert!((piece.mesh.volume() - 1.0 / 6.0).abs() < 1e-12);
        }
    }
}
