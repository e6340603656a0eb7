//! The derived topology of a mesh (edges, boundary surface, neighbours) and the errors for
//! duplicate tetrahedra and overfull faces, against reference definitions written here with one
//! plain global sort each: the mesh must give the same vectors in the same order, and the same
//! error naming the same elements, whatever the order of its tetrahedra and node ids.

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::mesh::{MeshError, NO_NEIGHBOR, TetMesh};

/// Face `i` of a tetrahedron is opposite corner `i`, listed with its normal pointing out.
const FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

/// Every face of every tetrahedron as (sorted nodes, tet, face), in ascending order.
fn reference_faces(tets: &[[u32; 4]]) -> Vec<([u32; 3], u32, u8)> {
    let mut all = Vec::new();
    for (t, tet) in tets.iter().enumerate() {
        for (f, face) in FACES.iter().enumerate() {
            let mut key = [tet[face[0]], tet[face[1]], tet[face[2]]];
            key.sort();
            all.push((key, t as u32, f as u8));
        }
    }
    all.sort();
    all
}

/// Runs of equal keys in the sorted face list.
fn face_runs(faces: &[([u32; 3], u32, u8)]) -> Vec<&[([u32; 3], u32, u8)]> {
    faces.chunk_by(|a, b| a.0 == b.0).collect()
}

fn reference_edges(tets: &[[u32; 4]]) -> Vec<[u32; 2]> {
    let mut all = Vec::new();
    for t in tets {
        for i in 0..4 {
            for j in i + 1..4 {
                all.push([t[i].min(t[j]), t[i].max(t[j])]);
            }
        }
    }
    all.sort();
    all.dedup();
    all
}

/// Boundary triangles (in tet, face order) and the (tet, face) each comes from.
fn reference_surface(tets: &[[u32; 4]]) -> (Vec<[u32; 3]>, Vec<(u32, u8)>) {
    let faces = reference_faces(tets);
    let mut boundary: Vec<(u32, u8)> = face_runs(&faces)
        .into_iter()
        .filter(|r| r.len() == 1)
        .map(|r| (r[0].1, r[0].2))
        .collect();
    boundary.sort();
    let triangles = boundary
        .iter()
        .map(|&(t, f)| FACES[f as usize].map(|c| tets[t as usize][c]))
        .collect();
    (triangles, boundary)
}

fn reference_neighbors(tets: &[[u32; 4]]) -> Vec<[u32; 4]> {
    let faces = reference_faces(tets);
    let mut n = vec![[NO_NEIGHBOR; 4]; tets.len()];
    for r in face_runs(&faces) {
        if let [a, b] = r {
            n[a.1 as usize][a.2 as usize] = b.1;
            n[b.1 as usize][b.2 as usize] = a.1;
        }
    }
    n
}

/// The error the mesh must report for these tetrahedra (orientation does not change it), if
/// any: the first duplicate tetrahedron, else the first face shared by more than two, each
/// first in the order of sorted node keys.
fn reference_error(tets: &[[u32; 4]]) -> Option<MeshError> {
    let mut keys: Vec<([u32; 4], usize)> = tets
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let mut k = *t;
            k.sort();
            (k, i)
        })
        .collect();
    keys.sort();
    for w in keys.windows(2) {
        if w[0].0 == w[1].0 {
            return Some(MeshError::DuplicateTet {
                tet: w[1].1,
                first: w[0].1,
                nodes: w[0].0.map(|n| n as usize),
            });
        }
    }
    let faces = reference_faces(tets);
    for r in face_runs(&faces) {
        if r.len() > 2 {
            return Some(MeshError::NonManifoldFace {
                face: r[0].0.map(|n| n as usize),
                count: r.len(),
                tets: r[..3].iter().map(|e| e.1 as usize).collect(),
            });
        }
    }
    None
}

fn assert_matches_reference(m: &TetMesh, what: &str) {
    let tets = m.tets();
    assert_eq!(m.edges(), reference_edges(tets).as_slice(), "{what}: edges");
    let (triangles, triangle_tets) = reference_surface(tets);
    assert_eq!(
        m.surface().triangles(),
        triangles.as_slice(),
        "{what}: surface triangles"
    );
    assert_eq!(
        m.surface().triangle_tets(),
        triangle_tets.as_slice(),
        "{what}: triangle tets"
    );
    assert_eq!(
        m.tet_neighbors(),
        reference_neighbors(tets).as_slice(),
        "{what}: neighbours"
    );
}

/// Fixed-seed linear congruential generator (Knuth's MMIX constants).
struct Lcg(u64);

impl Lcg {
    fn below(&mut self, n: usize) -> usize {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 33) % n as u64) as usize
    }

    fn shuffle<T>(&mut self, v: &mut [T]) {
        for i in (1..v.len()).rev() {
            let j = self.below(i + 1);
            v.swap(i, j);
        }
    }
}

/// The positions and tetrahedra of a generated block, its tetrahedra shuffled, its node ids
/// permuted and `unused` unreferenced nodes mixed in.
fn scrambled_block(cells: [usize; 3], unused: usize, seed: u64) -> (Vec<Vec3>, Vec<[usize; 4]>) {
    let m = block(Vec3::zeros(), Vec3::new(1.3, 0.9, 1.1), cells).unwrap();
    let n = m.node_count() + unused;
    let mut rng = Lcg(seed);
    let mut perm: Vec<usize> = (0..n).collect();
    rng.shuffle(&mut perm);
    let mut positions = vec![Vec3::new(7.0, 7.0, 7.0); n];
    for (old, p) in m.positions().iter().enumerate() {
        positions[perm[old]] = *p;
    }
    let mut tets: Vec<[usize; 4]> = m
        .tets()
        .iter()
        .map(|t| t.map(|v| perm[v as usize]))
        .collect();
    rng.shuffle(&mut tets);
    (positions, tets)
}

fn as_u32(tets: &[[usize; 4]]) -> Vec<[u32; 4]> {
    tets.iter().map(|t| t.map(|v| v as u32)).collect()
}

#[test]
fn generated_blocks_match_the_reference_order() {
    for cells in [[1, 1, 1], [2, 3, 1], [5, 4, 3], [12, 10, 9]] {
        let m = block(Vec3::zeros(), Vec3::new(2.0, 1.5, 1.0), cells).unwrap();
        assert!(m.tet_count() >= 5);
        assert_matches_reference(&m, &format!("block {cells:?}"));
    }
}

#[test]
fn shuffled_and_renumbered_block_matches_the_reference_order() {
    for (cells, unused, seed) in [
        ([6, 5, 4], 0, 1),
        ([9, 7, 8], 5, 0x5eed),
        ([3, 3, 3], 2, 99),
    ] {
        let (positions, tets) = scrambled_block(cells, unused, seed);
        let m = TetMesh::new(positions, tets).unwrap();
        assert_matches_reference(&m, &format!("scrambled block {cells:?}, seed {seed}"));
    }
}

#[test]
fn duplicate_tetrahedron_error_names_the_first_duplicate_in_key_order() {
    let (positions, mut tets) = scrambled_block([6, 5, 4], 3, 7);
    // Two duplicates, copied with their corners rotated, at different places in the list.
    let a = tets[17];
    let b = tets[301];
    tets.insert(40, [a[1], a[2], a[3], a[0]]);
    tets.push([b[2], b[3], b[0], b[1]]);
    tets.insert(5, b);
    let expected = reference_error(&as_u32(&tets)).unwrap();
    assert!(matches!(expected, MeshError::DuplicateTet { .. }));
    assert_eq!(TetMesh::new(positions, tets).unwrap_err(), expected);
}

#[test]
fn overfull_face_error_names_the_first_face_in_key_order() {
    let (mut positions, mut tets) = scrambled_block([5, 4, 4], 0, 3);
    let valid = TetMesh::new(positions.clone(), tets.clone()).unwrap();
    // Put extra tetrahedra on interior faces (each face then bounds three) and on one of
    // them twice more (four), each with a new apex off the face.
    let faces = reference_faces(valid.tets());
    let interior: Vec<[u32; 3]> = face_runs(&faces)
        .into_iter()
        .filter(|r| r.len() == 2)
        .map(|r| r[0].0)
        .collect();
    let picks = [
        interior[interior.len() * 3 / 4],
        interior[interior.len() / 2],
        interior[interior.len() / 5],
        interior[interior.len() / 5],
        interior[interior.len() / 5],
    ];
    for (k, face) in picks.iter().enumerate() {
        let p = face.map(|n| positions[n as usize]);
        let normal = (p[1] - p[0]).cross(&(p[2] - p[0])).normalize();
        let side = if k % 2 == 0 { 0.4 } else { -0.4 };
        positions.push((p[0] + p[1] + p[2]) / 3.0 + normal * side);
        let apex = positions.len() - 1;
        tets.insert(
            k * 37 % tets.len(),
            [face[0] as usize, face[2] as usize, face[1] as usize, apex],
        );
    }
    let expected = reference_error(&as_u32(&tets)).unwrap();
    let MeshError::NonManifoldFace { face, count, .. } = &expected else {
        panic!("expected an overfull face, the reference gives {expected:?}");
    };
    let first = interior[interior.len() / 5].map(|n| n as usize);
    assert_eq!((*face, *count), (first, 5));
    assert_eq!(TetMesh::new(positions, tets).unwrap_err(), expected);
}
