//! Cutting meshes: a cut separates without removing volume, keeps every tetrahedron
//! positive and every boundary edge in two triangles, and tells where each node came from;
//! checked on a bar cut through and half-way, and by random incisions on the liver, on the
//! 8k-tetrahedron liver and on a real mesh from another project's library.

mod support;

use std::path::Path;

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::cut::{CutMesh, CutOptions, CutTriangle, check, cut};
use soft_tissue_core::mesh::io::read_tet_mesh;

/// A bar of `n.0 x n.1 x n.2` cubes of side `h`, each split into six tetrahedra around its
/// diagonal (a conforming mesh).
fn bar(n: (usize, usize, usize), h: f64) -> TetMesh {
    let id = |i: usize, j: usize, k: usize| (k * (n.1 + 1) + j) * (n.0 + 1) + i;
    let mut positions = Vec::new();
    for k in 0..=n.2 {
        for j in 0..=n.1 {
            for i in 0..=n.0 {
                positions.push(Vec3::new(i as f64, j as f64, k as f64) * h);
            }
        }
    }
    let mut tets = Vec::new();
    for k in 0..n.2 {
        for j in 0..n.1 {
            for i in 0..n.0 {
                let c = |d: usize| id(i + (d & 1), j + ((d >> 1) & 1), k + ((d >> 2) & 1));
                // The six paths from corner 0 to corner 7 along the axes.
                for (a, b) in [(1, 3), (1, 5), (2, 3), (2, 6), (4, 5), (4, 6)] {
                    let mut t = [c(0), c(a), c(b), c(7)];
                    let p = t.map(|v| positions[v]);
                    if (p[1] - p[0]).cross(&(p[2] - p[0])).dot(&(p[3] - p[0])) < 0.0 {
                        t.swap(1, 2);
                    }
                    tets.push(t);
                }
            }
        }
    }
    TetMesh::new(positions, tets).unwrap()
}

/// Two triangles covering the rectangle `y` by `z` of the plane `x = at`.
fn plane_x(at: f64, y: (f64, f64), z: (f64, f64)) -> [CutTriangle; 2] {
    let p = |y: f64, z: f64| Vec3::new(at, y, z);
    [
        CutTriangle {
            corners: [p(y.0, z.0), p(y.1, z.0), p(y.1, z.1)],
        },
        CutTriangle {
            corners: [p(y.0, z.0), p(y.1, z.1), p(y.0, z.1)],
        },
    ]
}

/// Every node sits where its origin says, in the mesh before.
fn assert_origins(before: &TetMesh, after: &CutMesh) {
    let scale = before.bbox().diagonal();
    for (i, o) in after.node_origin.iter().enumerate() {
        let want = o.interpolate(before.positions());
        let got = after.mesh.positions()[i];
        assert!(
            (want - got).norm() <= 1e-12 * scale,
            "node {i}: {got:?} against its origin {want:?}"
        );
        assert!((o.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }
}

/// The sides of the cut are boundary faces of the mesh after it.
fn assert_cut_faces_on_boundary(after: &CutMesh) {
    let mut boundary: Vec<[u32; 3]> = after
        .mesh
        .surface()
        .triangles()
        .iter()
        .map(|t| {
            let mut t = *t;
            t.sort_unstable();
            t
        })
        .collect();
    boundary.sort_unstable();
    for f in &after.cut_faces {
        let mut k = *f;
        k.sort_unstable();
        assert!(
            boundary.binary_search(&k).is_ok(),
            "cut face {f:?} is inside"
        );
    }
}

#[test]
fn a_bar_cut_through_falls_in_two_with_its_volume() {
    let h = 0.1;
    let before = bar((8, 3, 3), h);
    // Through the middle of a column of cubes (far from any layer of nodes).
    let after = cut(
        &before,
        &plane_x(0.45, (-0.1, 0.4), (-0.1, 0.4)),
        &CutOptions::default(),
    )
    .unwrap();
    let c = check(&before, &after);
    assert_eq!(c.pieces, 2, "{c:?}");
    assert!(c.volume_change.abs() < 1e-12, "{c:?}");
    assert!(c.smallest_volume_ratio > 0.0, "{c:?}");
    assert_eq!(c.non_manifold_edges, 0, "{c:?}");
    assert_eq!(c.orphan_nodes, 0, "{c:?}");
    // Both sides of the 0.3 x 0.3 section.
    let area = after.cut_area();
    assert!((area - 2.0 * 0.09).abs() < 1e-9, "cut area {area}");
    assert!(after.bisected > 0 && after.separated > 0);
    assert_origins(&before, &after);
    assert_cut_faces_on_boundary(&after);
    // The two pieces lie on either side of the plane.
    let comp = after.mesh.node_components();
    for (i, p) in after.mesh.positions().iter().enumerate() {
        let other = comp.iter().zip(after.mesh.positions()).find(|(c, q)| {
            **c != comp[i] && (q.x - 0.45).abs() > 1e-9 && (p.x - 0.45).abs() > 1e-9
        });
        if let Some((_, q)) = other {
            assert!((p.x - 0.45) * (q.x - 0.45) < 0.0, "pieces mix sides");
        }
    }
}

/// A blade of two triangles cuts as one surface: the faces one triangle's bisections make
/// on the other's part are separated too, so nothing holds the pieces together along the
/// line between the triangles (wherever that line crosses the section).
#[test]
fn a_blade_of_two_triangles_cuts_through_along_their_shared_edge() {
    let h = 0.1;
    let before = bar((8, 3, 3), h);
    for at in [0.45, 0.25, 0.63] {
        for (y, z) in [
            ((-0.1, 0.4), (-0.1, 0.4)),
            ((-0.05, 0.31), (-0.23, 0.37)),
            ((-0.3, 0.35), (-0.02, 0.6)),
        ] {
            let after = cut(&before, &plane_x(at, y, z), &CutOptions::default()).unwrap();
            let c = check(&before, &after);
            assert_eq!(c.pieces, 2, "x = {at}, {y:?} x {z:?}: {c:?}");
            assert_eq!(c.non_manifold_edges, 0, "{c:?}");
            let area = after.cut_area();
            assert!((area - 0.18).abs() < 1e-9, "x = {at}: cut area {area}");
        }
    }
}

#[test]
fn a_cut_half_way_opens_a_crack_in_one_piece() {
    let h = 0.1;
    let before = bar((6, 4, 4), h);
    // The plane x = 0.35 (mid-cube, far from the snap threshold) from below up to y = 0.2
    // (half the bar's height), through its whole depth.
    let after = cut(
        &before,
        &plane_x(0.35, (-0.1, 0.2), (-0.1, 0.5)),
        &CutOptions::default(),
    )
    .unwrap();
    let c = check(&before, &after);
    assert_eq!(c.pieces, 1, "{c:?}");
    assert!(c.volume_change.abs() < 1e-12, "{c:?}");
    assert!(c.smallest_volume_ratio > 0.0, "{c:?}");
    assert_eq!(c.non_manifold_edges, 0, "{c:?}");
    assert!(after.separated > 0);
    assert!(after.mesh.node_count() > before.node_count());
    // The crack: half the 0.4 x 0.4 section, both sides, less what the front loses to the
    // faces it follows (at most one row of faces: 0.05 of the height).
    let area = after.cut_area();
    assert!(
        area > 2.0 * 0.4 * 0.15 && area <= 2.0 * 0.4 * 0.2 + 1e-9,
        "cut area {area}"
    );
    assert_origins(&before, &after);
    assert_cut_faces_on_boundary(&after);
}

/// A cut within `snap` of a layer of nodes moves onto the layer instead of bisecting.
#[test]
fn a_cut_near_a_layer_of_nodes_follows_the_layer() {
    let before = bar((8, 3, 3), 0.1);
    let after = cut(
        &before,
        &plane_x(0.42, (-0.1, 0.4), (-0.1, 0.4)),
        &CutOptions::default(),
    )
    .unwrap();
    let c = check(&before, &after);
    assert_eq!(c.pieces, 2, "{c:?}");
    assert_eq!(after.bisected, 0);
    assert_eq!(after.mesh.tet_count(), before.tet_count());
    let area = after.cut_area();
    assert!((area - 2.0 * 0.09).abs() < 1e-9, "cut area {area}");
    for f in &after.cut_faces {
        for &v in f {
            assert!((after.mesh.positions()[v as usize].x - 0.4).abs() < 1e-12);
        }
    }
}

#[test]
fn a_cut_that_misses_changes_nothing_and_bad_blades_are_refused() {
    let before = bar((2, 2, 2), 0.1);
    let after = cut(
        &before,
        &plane_x(5.0, (0.0, 1.0), (0.0, 1.0)),
        &CutOptions::default(),
    )
    .unwrap();
    assert_eq!(after.mesh.tets(), before.tets());
    assert!(after.cut_faces.is_empty());
    let flat = CutTriangle {
        corners: [Vec3::zeros(), Vec3::x(), Vec3::x() * 2.0],
    };
    let e = cut(&before, &[flat], &CutOptions::default()).unwrap_err();
    assert!(e.to_string().contains("blade triangle 0") && e.to_string().contains("no area"));
    let nan = CutTriangle {
        corners: [Vec3::zeros(), Vec3::x(), Vec3::new(f64::NAN, 0.0, 0.0)],
    };
    assert!(cut(&before, &[nan], &CutOptions::default()).is_err());
    let e = cut(
        &before,
        &plane_x(0.1, (0.0, 1.0), (0.0, 1.0)),
        &CutOptions {
            snap: 0.7,
            ..Default::default()
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("snap"), "{e}");
    for snap in [0.0, 1e-9, f64::NAN] {
        let r = cut(
            &before,
            &plane_x(0.1, (0.0, 1.0), (0.0, 1.0)),
            &CutOptions {
                snap,
                ..Default::default()
            },
        );
        assert!(r.is_err(), "snap {snap} accepted");
    }
}

/// A blade through a layer of nodes exactly (distance zero) cuts along the layer with the
/// smallest snap allowed, no child flat.
#[test]
fn a_blade_through_nodes_exactly_cuts_along_them() {
    let before = bar((4, 2, 2), 0.1);
    let after = cut(
        &before,
        &plane_x(0.2, (-0.1, 0.3), (-0.1, 0.3)),
        &CutOptions {
            snap: soft_tissue_core::mesh::cut::MIN_SNAP,
            ..Default::default()
        },
    )
    .unwrap();
    let c = check(&before, &after);
    assert_eq!(c.pieces, 2, "{c:?}");
    assert_eq!(after.bisected, 0);
    assert!(c.smallest_volume_ratio > 0.0);
}

/// `count` random incisions (a blade triangle a third of the mesh across, anywhere in its
/// box, any direction), each applied to the result of the last, checked after each.
fn random_incisions(before: &TetMesh, count: usize, seed: u64) {
    let mut rng = support::Rng::new(seed);
    let mut unit = || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
    let bbox = before.bbox();
    let size = bbox.diagonal() / 3.0;
    let start = check(
        before,
        &cut(before, &[], &CutOptions::default()).expect("an empty cut"),
    );
    let mut mesh = before.clone();
    let mut cut_area = 0.0;
    let (mut smallest_ratio, mut smallest_angle, mut taken_back) =
        (f64::INFINITY, f64::INFINITY, 0);
    for k in 0..count {
        let centre =
            bbox.min + (bbox.max - bbox.min).component_mul(&Vec3::new(unit(), unit(), unit()));
        let dir = |u: f64, v: f64| {
            let (theta, z) = (u * std::f64::consts::TAU, 2.0 * v - 1.0);
            let r = (1.0 - z * z).sqrt();
            Vec3::new(r * theta.cos(), r * theta.sin(), z)
        };
        let (a, b, c) = (
            dir(unit(), unit()),
            dir(unit(), unit()),
            dir(unit(), unit()),
        );
        let blade = CutTriangle {
            corners: [centre + a * size, centre + b * size, centre + c * size],
        };
        let Ok(after) = cut(&mesh, &[blade], &CutOptions::default()) else {
            // A degenerate blade is refused; nothing else may fail.
            let [p, q, r] = blade.corners;
            assert!((q - p).cross(&(r - p)).norm() == 0.0, "cut {k} failed");
            continue;
        };
        let c = check(&mesh, &after);
        assert!(c.volume_change.abs() <= 1e-9, "cut {k}: {c:?}");
        assert!(c.smallest_volume_ratio > 0.0, "cut {k}: {c:?}");
        assert!(
            c.non_manifold_edges <= start.non_manifold_edges,
            "cut {k}: {c:?} (before any cut {})",
            start.non_manifold_edges
        );
        assert!(c.orphan_nodes <= start.orphan_nodes, "cut {k}: {c:?}");
        assert_origins(&mesh, &after);
        assert_cut_faces_on_boundary(&after);
        cut_area += after.cut_area();
        smallest_ratio = smallest_ratio.min(c.smallest_volume_ratio);
        smallest_angle = smallest_angle.min(c.smallest_dihedral);
        taken_back += after.taken_back;
        mesh = after.mesh;
    }
    let total = (mesh.volume() - before.volume()) / before.volume();
    assert!(total.abs() <= 1e-9, "volume after {count} cuts: {total:e}");
    assert!(cut_area > 0.0, "the incisions cut something");
    eprintln!(
        "{count} cuts: {} -> {} tetrahedra, {} pieces, cut area {cut_area:.4}, smallest child \
         {smallest_ratio:.3} of its parent, smallest dihedral {:.2} deg (before {:.2}), faces \
         taken back {taken_back}, non-manifold edges before {}",
        before.tet_count(),
        mesh.tet_count(),
        mesh.component_count(),
        smallest_angle,
        start.smallest_dihedral,
        start.non_manifold_edges
    );
}

#[test]
fn two_hundred_random_incisions_keep_the_liver_valid() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/meshes/liver.vtk");
    let liver = read_tet_mesh(&path).unwrap().mesh;
    random_incisions(&liver, 200, 7);
}

/// The organ-sized liver of `organs-large` (8321 tetrahedra, generated from our liver shape:
/// `../shared/meshes` has no real mesh of 8k tetrahedra).
#[test]
fn two_hundred_random_incisions_keep_an_8k_liver_valid() {
    let liver = soft_tissue_core::mesh::generate::Organ::Liver
        .generate(2.0)
        .unwrap();
    assert!(liver.tet_count() > 8000, "{} tetrahedra", liver.tet_count());
    random_incisions(&liver, 200, 13);
}

#[test]
fn two_hundred_random_incisions_keep_a_real_mesh_valid() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/meshes");
    let Some(dir) = support::shared_folder(
        &dir,
        "two_hundred_random_incisions_keep_a_real_mesh_valid",
        support::shared_meshes_required(),
    ) else {
        return;
    };
    let mesh = read_tet_mesh(dir.join("Armadillo_Tetra_4406.vtu"))
        .unwrap()
        .mesh;
    random_incisions(&mesh, 200, 11);
}
