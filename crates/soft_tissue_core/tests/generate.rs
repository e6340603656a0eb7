//! The mesher and the predefined bodies: counts against the paper, element quality,
//! geometry against the signed distance function, closed surfaces, placement of the organs,
//! reproducibility, and the committed assets.

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::generate::{Organ, Primitive, Shape, coarsen_interior, stuff};
use soft_tissue_core::mesh::io::{self, MeshFormat, WriteOptions};
use soft_tissue_core::scenario::{PreciseMethod, Scene};
use std::collections::BTreeMap;
use std::path::Path;

fn assert_closed_sphere(m: &TetMesh, what: &str) {
    let mut edges = BTreeMap::new();
    for t in m.surface().triangles() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    assert!(
        edges.values().all(|&c| c == 2),
        "{what}: surface not closed"
    );
    // Euler characteristic V - E + F = 2 for a sphere-like surface.
    let chi = m.surface().vertices().len() as i64 - edges.len() as i64
        + m.surface().triangles().len() as i64;
    assert_eq!(chi, 2, "{what}: surface is not a topological sphere");
}

#[test]
fn bodies_match_the_paper_counts_within_15_percent() {
    for organ in [Organ::Cylinder].into_iter().chain(Organ::ORGANS) {
        let m = organ.generate(1.0).unwrap();
        let (pn, pt, ps) = organ.paper_counts();
        let got = [m.node_count(), m.tet_count(), m.surface().triangles().len()];
        for (g, p) in got.iter().zip([pn, pt, ps]) {
            let rel = (*g as f64 / p as f64 - 1.0).abs();
            assert!(
                rel <= 0.15,
                "{}: {got:?} vs paper {:?}",
                organ.name(),
                (pn, pt, ps)
            );
        }
        // Quality: the tetrahedra are positively oriented by construction (TetMesh checks) and
        // the dihedral angles stay well away from 0 and 180 degrees.
        let q = m.quality();
        assert!(q.min_dihedral_deg >= 15.0, "{}: {q:?}", organ.name());
        assert!(q.max_dihedral_deg <= 163.0, "{}: {q:?}", organ.name());
        assert_eq!(m.component_count(), 1);
        assert!(
            m.warnings().is_empty(),
            "{}: {:?}",
            organ.name(),
            m.warnings()
        );
        assert_closed_sphere(&m, organ.name());
    }
}

#[test]
fn cylinder_has_the_papers_dimensions() {
    let b = Organ::Cylinder.generate(1.0).unwrap().bbox();
    let e = b.extent();
    // Surface vertices lie on the cylinder, so the box is the cylinder's to within a
    // lattice cut: diameter 1.24, height 1.72 (paper section V-B).
    assert!(
        (e.x - 1.24).abs() < 0.02 && (e.y - 1.24).abs() < 0.02,
        "{e:?}"
    );
    assert!((e.z - 1.72).abs() < 0.02, "{e:?}");
}

#[test]
fn surface_vertices_lie_on_the_implicit_surface() {
    for organ in [Organ::Cylinder].into_iter().chain(Organ::ORGANS) {
        let shape = organ.shape();
        let m = organ.generate(1.0).unwrap();
        let h = organ.base_spacing();
        for &v in m.surface().vertices() {
            let f = shape.eval(&m.positions()[v as usize]);
            assert!(
                f.abs() < 1e-9 * h.max(1.0),
                "{}: node {v} is {f} off the surface",
                organ.name()
            );
        }
    }
}

#[test]
fn sphere_volume_converges_under_refinement() {
    // A sphere of radius 1: the inscribed mesh volume approaches 4/3 pi from below, with the
    // error falling roughly as h^2 (chord error of a smooth surface).
    let shape = Shape {
        parts: vec![Primitive::Ellipsoid {
            center: [0.0; 3],
            radii: [1.0; 3],
            rotation_deg: [0.0; 3],
        }],
        blend: 0.0,
        scale: [1.0; 3],
        offset: [0.0; 3],
    };
    let exact = 4.0 / 3.0 * std::f64::consts::PI;
    let mut errors = Vec::new();
    for h in [0.4, 0.2, 0.1] {
        let m = stuff(&shape, h).unwrap();
        let err = (m.volume() - exact).abs() / exact;
        errors.push(err);
        assert!(
            m.quality().min_dihedral_deg > 10.0,
            "h {h}: {:?}",
            m.quality()
        );
        assert_closed_sphere(&m, "sphere");
    }
    assert!(errors[2] < 0.01, "{errors:?}");
    assert!(errors[1] < errors[0] && errors[2] < errors[1], "{errors:?}");
    assert!(
        errors[0] / errors[2] > 6.0,
        "convergence too slow: {errors:?}"
    );
}

#[test]
fn interior_coarsening_keeps_surface_volume_and_quality() {
    let shape = Organ::Liver.shape();
    let m = stuff(&shape, 0.15).unwrap();
    let c = coarsen_interior(&m, 18.0).unwrap();
    assert!(c.node_count() < m.node_count());
    // Only interior nodes go: the surface is the same set of points and triangles.
    assert_eq!(c.surface().triangles().len(), m.surface().triangles().len());
    assert_eq!(c.surface().vertices().len(), m.surface().vertices().len());
    assert!(
        (c.volume() - m.volume()).abs() < 1e-9 * m.volume(),
        "{} vs {}",
        c.volume(),
        m.volume()
    );
    assert!(c.quality().min_dihedral_deg >= m.quality().min_dihedral_deg.min(18.0) - 1e-9);
}

#[test]
fn resolution_refines() {
    let coarse = Organ::Spleen.generate(1.0).unwrap();
    let fine = Organ::Spleen.generate(2.0).unwrap();
    assert!(fine.tet_count() > 3 * coarse.tet_count());
    assert!(fine.surface().triangles().len() > 3 * coarse.surface().triangles().len());
    assert!(Organ::Spleen.generate(0.0).is_err());
    assert!(Organ::Spleen.generate(f64::NAN).is_err());
}

#[test]
fn organs_touch_without_overlapping() {
    // Touching pairs of the paper's Fig. 4: each rests against its neighbour. The gap is the
    // smallest signed distance from one organ's surface nodes to the other's shape.
    let meshes: Vec<(Organ, TetMesh)> = Organ::ORGANS
        .iter()
        .map(|&o| (o, o.generate(1.0).unwrap()))
        .collect();
    let gap = |a: &TetMesh, b: Organ| {
        let s = b.shape();
        a.surface()
            .vertices()
            .iter()
            .map(|&v| s.eval(&a.positions()[v as usize]))
            .fold(f64::INFINITY, f64::min)
    };
    let touching = [
        (Organ::Stomach, Organ::Liver),
        (Organ::Spleen, Organ::Stomach),
        (Organ::Pancreas, Organ::Stomach),
    ];
    for (a, ma) in &meshes {
        for (b, _) in &meshes {
            if a == b {
                continue;
            }
            let g = gap(ma, *b);
            assert!(g > -0.01, "{} penetrates {} by {}", a.name(), b.name(), -g);
            if touching.contains(&(*a, *b)) {
                assert!(
                    g < 0.01,
                    "{} does not touch {}: gap {g}",
                    a.name(),
                    b.name()
                );
            }
        }
    }
}

#[test]
fn generation_is_reproducible_and_assets_are_current() {
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets");
    for organ in [Organ::Cylinder].into_iter().chain(Organ::ORGANS) {
        let a = io::write_tet_mesh_bytes(
            &organ.generate(1.0).unwrap(),
            MeshFormat::VtkLegacy,
            WriteOptions::default(),
            "a",
        )
        .unwrap();
        let b = io::write_tet_mesh_bytes(
            &organ.generate(1.0).unwrap(),
            MeshFormat::VtkLegacy,
            WriteOptions::default(),
            "b",
        )
        .unwrap();
        assert_eq!(a, b, "{}: generation is not deterministic", organ.name());
        let committed = std::fs::read(assets.join(format!("meshes/{}.vtk", organ.name()))).unwrap();
        assert!(
            committed == a,
            "assets/meshes/{}.vtk is stale: run `soft-tissue mesh generate {} --out assets/meshes`",
            organ.name(),
            organ.name()
        );
    }
    for scene in [
        Scene::paper_cylinders(PreciseMethod::LinearFem, PreciseMethod::LinearFem),
        Scene::paper_organs(),
        Scene::large_organs(),
    ] {
        let path = assets.join(format!("scenes/{}.scene.ron", scene.name));
        let text = std::fs::read_to_string(&path).unwrap();
        let parsed = Scene::from_ron(&text, &path.display().to_string()).unwrap();
        assert_eq!(
            parsed,
            scene,
            "{} is stale: run `soft-tissue scene export --out assets/scenes`",
            path.display()
        );
        // Every mesh a scene names exists and loads.
        for body in &scene.bodies {
            if let soft_tissue_core::scenario::MeshSource::File(f) = &body.mesh {
                io::read_tet_mesh(assets.join(f)).unwrap();
            }
        }
    }
}

#[test]
fn mesher_rejects_bad_spacing() {
    let s = Organ::Liver.shape();
    assert!(stuff(&s, 0.0).is_err());
    assert!(stuff(&s, -1.0).is_err());
    assert!(stuff(&s, 1e-6).is_err()); // lattice too large: refused, not attempted
    // A shape far smaller than the lattice yields a clear error, not an empty mesh.
    let tiny = Shape {
        parts: vec![Primitive::Ellipsoid {
            center: [0.01, 0.02, 0.03],
            radii: [0.001; 3],
            rotation_deg: [0.0; 3],
        }],
        blend: 0.0,
        scale: [1.0; 3],
        offset: [0.0; 3],
    };
    assert!(stuff(&tiny, 1.0).is_err());
    let _ = Vec3::zeros();
}

/// A placement of a mesh (turned, moved, scaled) keeps its topology: `TetMesh::mapped` gives
/// what building the moved nodes anew gives; a mirror turns its elements inside out and is
/// refused by name.
#[test]
fn a_placed_mesh_keeps_its_topology_and_a_mirror_is_refused() {
    let mesh =
        soft_tissue_core::mesh::generate::block(Vec3::zeros(), Vec3::new(1.0, 2.0, 0.5), [3, 4, 2])
            .unwrap();
    let turn = nalgebra::Rotation3::from_euler_angles(0.3, -1.1, 2.0);
    let place = |p: &Vec3| turn * p * 2.5 + Vec3::new(0.1, -3.0, 7.0);
    let moved = mesh.mapped(place).unwrap();
    let positions: Vec<Vec3> = mesh.positions().iter().map(place).collect();
    let tets = mesh.tets().iter().map(|t| t.map(|i| i as usize)).collect();
    let anew = TetMesh::new(positions, tets).unwrap();
    assert_eq!(moved.tets(), anew.tets());
    assert_eq!(moved.surface().triangles(), anew.surface().triangles());
    assert_eq!(moved.positions(), anew.positions());
    assert!(((moved.volume() - anew.volume()) / anew.volume()).abs() < 1e-12);
    assert!((moved.volume() - 2.5f64.powi(3) * mesh.volume()).abs() < 1e-9 * moved.volume());
    assert!((moved.bbox().min - anew.bbox().min).norm() < 1e-12);
    assert!((moved.bbox().max - anew.bbox().max).norm() < 1e-12);
    let e = mesh
        .mapped(|p| Vec3::new(-p.x, p.y, p.z))
        .unwrap_err()
        .to_string();
    assert!(e.contains("tetrahedron 0"), "{e}");
}

/// A deformed state of a mesh (`TetMesh::moved_to`) is what building its nodes there anew
/// gives, topology and volumes; it is refused where `TetMesh::new` would refuse or turn an
/// element over (one node pushed through its opposite face, one flattened onto it), and for
/// positions of another count, each by name.
#[test]
fn a_deformed_state_keeps_the_topology_and_is_refused_where_new_would_refuse_it() {
    let mesh =
        soft_tissue_core::mesh::generate::block(Vec3::zeros(), Vec3::new(1.0, 2.0, 0.5), [3, 4, 2])
            .unwrap();
    // A smooth bend and twist that keeps every element upright.
    let bend = |p: &Vec3| {
        Vec3::new(
            p.x + 0.1 * (p.y * 1.3).sin(),
            p.y + 0.05 * p.x * p.z,
            p.z + 0.08 * (p.x - 0.5) * p.y,
        )
    };
    let positions: Vec<Vec3> = mesh.positions().iter().map(bend).collect();
    let moved = mesh.moved_to(positions.clone()).unwrap();
    let tets = mesh.tets().iter().map(|t| t.map(|i| i as usize)).collect();
    let anew = TetMesh::new(positions, tets).unwrap();
    assert_eq!(moved.tets(), anew.tets());
    assert_eq!(moved.edges(), anew.edges());
    assert_eq!(moved.surface().triangles(), anew.surface().triangles());
    assert_eq!(moved.tet_neighbors(), anew.tet_neighbors());
    for (a, b) in moved.tet_volumes().iter().zip(anew.tet_volumes()) {
        assert!(
            (a - b).abs() <= 1e-15 * b.abs().max(1e-300),
            "{a} against {b}"
        );
    }
    assert!((moved.bbox().min - anew.bbox().min).norm() < 1e-15);
    // Element 0's first corner pushed through the opposite face, then onto it.
    let t = mesh.tets()[0].map(|i| i as usize);
    let p = mesh.positions();
    let (a, b, c, d) = (p[t[0]], p[t[1]], p[t[2]], p[t[3]]);
    let normal = (c - b).cross(&(d - b)).normalize();
    let height = (a - b).dot(&normal);
    for (depth, what) in [(2.0, "inverted"), (1.0, "flat")] {
        let mut x = mesh.positions().to_vec();
        x[t[0]] = a - normal * (height * depth);
        let e = mesh.moved_to(x.clone()).unwrap_err();
        assert!(e.to_string().contains("tetrahedron 0"), "{what}: {e}");
        let tets: Vec<[usize; 4]> = mesh.tets().iter().map(|t| t.map(|i| i as usize)).collect();
        match TetMesh::new(x, tets) {
            Err(_) => {}
            Ok(m) => assert!(
                !m.warnings().is_empty(),
                "{what}: new takes it without turning anything over"
            ),
        }
    }
    let e = mesh.moved_to(vec![Vec3::zeros(); 3]).unwrap_err();
    assert_eq!(
        e,
        soft_tissue_core::mesh::MeshError::NodeCount {
            given: 3,
            nodes: mesh.node_count()
        }
    );
}
