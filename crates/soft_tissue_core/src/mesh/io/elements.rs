//! Conforming splits of volume elements into tetrahedra.
//!
//! Every quadrilateral face is cut along the diagonal through its smallest node index, a rule
//! that depends only on the face, so two elements sharing a face cut it the same way and the
//! result is conforming. Hexahedra and wedges get a centre node and become one tetrahedron per
//! face triangle; pyramids need no extra node. Tets are oriented positively where possible.

use super::RawMesh;
use crate::Vec3;

/// Kinds of volume elements that are split.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum VolumeKind {
    /// 8 corners: bottom 0-3, top 4-7 (VTK/Gmsh ordering).
    Hexahedron,
    /// 6 corners: triangles 0-2 and 3-5.
    Wedge,
    /// 5 corners: base 0-3, apex 4.
    Pyramid,
}

impl VolumeKind {
    pub(crate) fn plural(self) -> &'static str {
        match self {
            Self::Hexahedron => "hexahedra",
            Self::Wedge => "wedges",
            Self::Pyramid => "pyramids",
        }
    }

    pub(crate) fn corners(self) -> usize {
        match self {
            Self::Hexahedron => 8,
            Self::Wedge => 6,
            Self::Pyramid => 5,
        }
    }

    fn faces(self) -> &'static [&'static [usize]] {
        match self {
            Self::Hexahedron => &[
                &[0, 3, 2, 1],
                &[4, 5, 6, 7],
                &[0, 1, 5, 4],
                &[1, 2, 6, 5],
                &[2, 3, 7, 6],
                &[3, 0, 4, 7],
            ],
            Self::Wedge => &[
                &[0, 2, 1],
                &[3, 4, 5],
                &[0, 1, 4, 3],
                &[1, 2, 5, 4],
                &[2, 0, 3, 5],
            ],
            Self::Pyramid => &[&[0, 3, 2, 1]],
        }
    }
}

/// Splits one element whose corner node indices are already checked to be in range.
/// `origin` is the file's element number for every produced tet.
pub(crate) fn split(raw: &mut RawMesh, kind: VolumeKind, corners: &[usize], origin: u64) {
    let apex = match kind {
        VolumeKind::Pyramid => corners[4],
        _ => {
            let c = corners
                .iter()
                .fold(Vec3::zeros(), |s, &n| s + raw.positions[n])
                / corners.len() as f64;
            raw.positions.push(c);
            raw.positions.len() - 1
        }
    };
    let before = raw.tets.len();
    for face in kind.faces() {
        let f: Vec<usize> = face.iter().map(|&i| corners[i]).collect();
        let tris: Vec<[usize; 3]> = if f.len() == 3 {
            vec![[f[0], f[1], f[2]]]
        } else {
            let m = (0..4).min_by_key(|&i| f[i]).unwrap_or(0);
            let (a, b, c, d) = (f[m], f[(m + 1) % 4], f[(m + 2) % 4], f[(m + 3) % 4]);
            vec![[a, b, c], [a, c, d]]
        };
        for t in tris {
            let mut tet = [t[0], t[1], t[2], apex];
            let p = tet.map(|n| raw.positions[n]);
            if crate::mesh::tet_signed_volume(&p) < 0.0 {
                tet.swap(1, 2);
            }
            raw.tets.push(tet);
            raw.origin.push(origin);
        }
    }
    let entry = raw.converted.entry(kind.plural()).or_insert((0, 0, 0));
    entry.0 += 1;
    entry.1 += raw.tets.len() - before;
    entry.2 += usize::from(kind != VolumeKind::Pyramid);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::TetMesh;

    fn grid_hexes(n: usize) -> RawMesh {
        // n x n x n unit hexahedra on a structured grid.
        let mut raw = RawMesh::default();
        let id = |i: usize, j: usize, k: usize| i + (n + 1) * (j + (n + 1) * k);
        for k in 0..=n {
            for j in 0..=n {
                for i in 0..=n {
                    raw.positions.push(Vec3::new(i as f64, j as f64, k as f64));
                }
            }
        }
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let c = [
                        id(i, j, k),
                        id(i + 1, j, k),
                        id(i + 1, j + 1, k),
                        id(i, j + 1, k),
                        id(i, j, k + 1),
                        id(i + 1, j, k + 1),
                        id(i + 1, j + 1, k + 1),
                        id(i, j + 1, k + 1),
                    ];
                    split(&mut raw, VolumeKind::Hexahedron, &c, 0);
                }
            }
        }
        raw
    }

    #[test]
    fn split_hex_grid_is_conforming_and_exact() {
        let raw = grid_hexes(3);
        let m = TetMesh::new(raw.positions, raw.tets).unwrap();
        assert_eq!(m.tet_count(), 27 * 12);
        assert!((m.volume() - 27.0).abs() < 1e-12);
        // A conforming split of a cube has exactly the cube's boundary: 6 faces x 9 squares
        // x 2 triangles, closed (every edge in exactly two triangles).
        assert_eq!(m.surface().triangles().len(), 6 * 9 * 2);
        assert!(m.warnings().is_empty());
    }

    #[test]
    fn wedge_and_pyramid_volumes() {
        let mut raw = RawMesh {
            positions: vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(0.0, 0.0, 2.0),
                Vec3::new(1.0, 0.0, 2.0),
                Vec3::new(0.0, 1.0, 2.0),
            ],
            ..Default::default()
        };
        split(&mut raw, VolumeKind::Wedge, &[0, 1, 2, 3, 4, 5], 0);
        let m = TetMesh::new(raw.positions.clone(), raw.tets.clone()).unwrap();
        assert!((m.volume() - 1.0).abs() < 1e-12); // 0.5 * 2
        let mut raw = RawMesh {
            positions: vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(0.5, 0.5, 3.0),
            ],
            ..Default::default()
        };
        split(&mut raw, VolumeKind::Pyramid, &[0, 1, 2, 3, 4], 0);
        let m = TetMesh::new(raw.positions, raw.tets).unwrap();
        assert!((m.volume() - 1.0).abs() < 1e-12); // 1 * 3 / 3
    }
}
