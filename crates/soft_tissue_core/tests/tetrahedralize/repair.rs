//! The repair: scan defects, nesting (cavities, inner pieces), duplicated faces, overlapping
//! parts, far coordinates, and surfaces too broken to mesh.

use std::f64::consts::PI;

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::io::SurfaceMesh;
use soft_tissue_core::mesh::tetrahedralize::{
    TetrahedralizeError, TetrahedralizeOptions, repair, tetrahedralize,
};

use super::check;
use super::shapes::{grid, joined, sphere};

#[test]
fn duplicated_vertices_flipped_triangles_and_a_small_hole_still_mesh() {
    let clean = sphere(0.5);
    let mut s = clean.clone();
    // Every vertex of the first ring written twice (a scan's seams), some triangles
    // flipped, one removed (a hole), and an unused vertex.
    let n = s.positions.len() as u32;
    for i in 0..48u32 {
        s.positions.push(s.positions[i as usize]);
    }
    for t in s.triangles.iter_mut().step_by(7) {
        t.swap(1, 2);
    }
    for t in s.triangles.iter_mut().take(48) {
        for v in t.iter_mut() {
            if *v < 48 {
                *v += n;
            }
        }
    }
    s.triangles.remove(100);
    s.positions.push(Vec3::new(5.0, 5.0, 5.0));
    // A speck floating beside it (a tetrahedron 0.01 across, 0.4 away), as segmentations
    // leave: dropped, not meshed, not counted against the distances.
    let b = s.positions.len() as u32;
    for p in [
        [0.9, 0.0, 0.0],
        [0.91, 0.0, 0.0],
        [0.9, 0.01, 0.0],
        [0.9, 0.0, 0.01],
    ] {
        s.positions.push(Vec3::new(p[0], p[1], p[2]));
    }
    for t in [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]] {
        s.triangles.push(t.map(|v: u32| b + v));
    }
    let fixed = repair(&s).unwrap();
    assert_eq!(fixed.defects.duplicate_vertices, 48);
    assert_eq!(fixed.defects.unused_vertices, 1);
    assert_eq!(fixed.defects.boundary_edges, 3);
    assert!(fixed.defects.flipped_triangles > 0);
    assert_eq!(fixed.defects.specks_dropped, 1);
    let (_, r) = tetrahedralize(&s, &TetrahedralizeOptions::default()).unwrap();
    assert!(r.surface_to_mesh < 0.01 * r.bbox_diagonal, "{r:?}");
    let (_, clean_r) = tetrahedralize(&clean, &TetrahedralizeOptions::default()).unwrap();
    assert!(
        (r.volume - clean_r.volume).abs() <= 0.03 * clean_r.volume,
        "{} against {}",
        r.volume,
        clean_r.volume
    );
}

/// A hollow organ: a sphere of radius 1 with one of radius 0.5 inside, written facing
/// inward as segmentations write an inner wall, is a cavity (before, the repair turned it
/// outward and the mesh filled it: 35 % off in volume). The winding number is zero in the
/// cavity and one in the wall; the mesh has the shell's volume (4/3 pi (1 - 0.125)) and no
/// tetrahedron in the cavity. The same file turned wholly inside out (as the Chaste hearts
/// come) reads the same; a stone inside the cavity is solid again.
#[test]
fn a_sphere_inside_a_sphere_facing_inward_is_a_cavity() {
    let (outer, inner) = (sphere(1.0), sphere(0.5));
    let volume = |s: &SurfaceMesh| repair(s).unwrap().enclosed_volume;
    let shell = volume(&outer) - volume(&inner);
    for turned in [false, true] {
        let hollow = joined(&[(outer.clone(), turned), (inner.clone(), !turned)]);
        let fixed = repair(&hollow).unwrap();
        assert_eq!(fixed.defects.cavities, 1, "turned {turned}");
        assert!(
            (fixed.enclosed_volume - shell).abs() < 1e-9 * shell,
            "turned {turned}"
        );
        assert!(fixed.winding_number(&Vec3::zeros()).abs() < 1e-6);
        assert!((fixed.winding_number(&Vec3::new(0.75, 0.0, 0.0)) - 1.0).abs() < 1e-6);
    }
    let hollow = joined(&[(outer.clone(), false), (inner.clone(), true)]);
    let r = check(
        "hollow sphere",
        &hollow,
        4.0 / 3.0 * PI * 0.875,
        1500,
        0.01,
        0.01,
    );
    assert_eq!(r.defects.flipped_triangles, 0);
    let (mesh, _) = tetrahedralize(&hollow, &TetrahedralizeOptions::default()).unwrap();
    let deepest_in_cavity = mesh
        .tets()
        .iter()
        .map(|t| {
            t.iter()
                .map(|&v| mesh.positions()[v as usize])
                .sum::<Vec3>()
                / 4.0
        })
        .map(|c| c.norm())
        .fold(f64::INFINITY, f64::min);
    assert!(
        deepest_in_cavity > 0.45,
        "a tetrahedron centred {deepest_in_cavity} from the centre"
    );
    let stone = joined(&[
        (outer.clone(), false),
        (inner.clone(), true),
        (sphere(0.25), false),
    ]);
    let fixed = repair(&stone).unwrap();
    assert_eq!(fixed.defects.cavities, 1);
    let want = shell + volume(&sphere(0.25));
    assert!((fixed.enclosed_volume - want).abs() < 1e-9 * want);
}

/// A second outward surface inside the first (a tumour exported with its organ) lies inside
/// the union the mesh fills: dropped, so that neither the volume nor the distances count it
/// (before, the enclosed volume added both and the tumour's surface stood off the boundary).
/// A face written twice keeps one copy; two boxes sharing a face, each written closed, lose
/// the face between them (it runs both ways) and become one closed block.
#[test]
fn inner_pieces_and_duplicated_faces_leave_the_union() {
    let tumour = {
        let mut t = sphere(0.3);
        for p in &mut t.positions {
            p.x += 0.2;
        }
        t
    };
    let fixed = repair(&joined(&[(sphere(1.0), false), (tumour, false)])).unwrap();
    assert_eq!(fixed.defects.inner_pieces_dropped, 1);
    assert_eq!(fixed.defects.cavities, 0);
    let one = repair(&sphere(1.0)).unwrap();
    assert_eq!(fixed.positions, one.positions);
    assert_eq!(fixed.triangles, one.triangles);

    let twice = joined(&[(sphere(1.0), false), (sphere(1.0), false)]);
    let fixed = repair(&twice).unwrap();
    assert_eq!(fixed.defects.duplicate_triangles, one.triangles.len());
    assert_eq!(fixed.defects.non_manifold_edges, 0);
    assert!((fixed.enclosed_volume - one.enclosed_volume).abs() < 1e-12);

    // Unit boxes at x in [0, 1] and [1, 2], each face split along the same diagonal.
    let unit_box = |x0: f64| {
        let positions = (0..8)
            .map(|i| Vec3::new(x0 + (i & 1) as f64, ((i >> 1) & 1) as f64, (i >> 2) as f64))
            .collect();
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let triangles = quads
            .iter()
            .flat_map(|q: &[u32; 4]| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        SurfaceMesh {
            positions,
            triangles,
        }
    };
    let fixed = repair(&joined(&[(unit_box(0.0), false), (unit_box(1.0), false)])).unwrap();
    assert_eq!(
        fixed.defects.duplicate_triangles, 4,
        "the shared face, written both ways"
    );
    assert_eq!(fixed.triangles.len(), 20);
    assert_eq!(fixed.defects.boundary_edges, 0);
    assert_eq!(fixed.defects.non_manifold_edges, 0);
    assert!((fixed.enclosed_volume - 2.0).abs() < 1e-12);
}

/// Two parts through each other (two labels of a segmentation exported together): two unit
/// spheres whose centres lie 1 apart mesh to their union. Before, the enclosed volume counted
/// the lens they share twice (18 % over), the boundary was projected toward the buried caps
/// and the distances measured against them (5 % / 15 % of the diagonal). Checked against the
/// closed forms: the union's volume (two balls less the lens, pi (4 r + d) (2 r - d)^2 / 12),
/// the buried share of the triangles well inside the other sphere (all) and well outside it
/// (none), and every boundary node of the mesh against the union's signed distance,
/// min(|p - c1|, |p - c2|) - 1. Two cavities through each other, and a small ball on an
/// edge of a coarse one (no centroid of the coarse one buried), keep their union's volume.
/// A hollow organ's cavity and a lone sphere bury nothing.
#[test]
fn overlapping_parts_mesh_to_their_union() {
    let centres = [Vec3::zeros(), Vec3::new(1.0, 0.0, 0.0)];
    let second = {
        let mut s = sphere(1.0);
        for p in &mut s.positions {
            *p += centres[1];
        }
        s
    };
    let both = joined(&[(sphere(1.0), false), (second, false)]);
    let fixed = repair(&both).unwrap();
    // The grid sphere's volume falls short of the ball's; the union's by the same ratio, to
    // within what the shares' sixteenths leave along the seam.
    let ball = 4.0 / 3.0 * PI;
    let ratio = repair(&sphere(1.0)).unwrap().enclosed_volume / ball;
    let union = 2.0 * ball - PI * 5.0 / 12.0;
    assert!(
        (fixed.enclosed_volume / (union * ratio) - 1.0).abs() < 2e-3,
        "{} against {}",
        fixed.enclosed_volume,
        union * ratio
    );
    assert!(fixed.defects.buried_triangles > 0);
    let n = fixed.triangles.len() / 2;
    for (k, (t, &share)) in fixed.triangles.iter().zip(&fixed.buried).enumerate() {
        let other = centres[if k < n { 1 } else { 0 }];
        let from_other = t.map(|v| (fixed.positions[v as usize] - other).norm());
        if from_other.iter().all(|&d| d < 0.95) {
            assert_eq!(share, 1.0, "triangle {k} lies inside the other sphere");
        }
        if from_other.iter().all(|&d| d > 1.05) {
            assert_eq!(share, 0.0, "triangle {k} lies outside the other sphere");
        }
    }
    let r = check(
        "two spheres through each other",
        &both,
        union,
        1500,
        0.01,
        0.01,
    );
    let (mesh, _) = tetrahedralize(&both, &TetrahedralizeOptions::default()).unwrap();
    let worst = mesh
        .surface()
        .vertices()
        .iter()
        .map(|&v| {
            let p = mesh.positions()[v as usize];
            centres
                .iter()
                .map(|c| (p - c).norm())
                .fold(f64::INFINITY, f64::min)
                - 1.0
        })
        .fold(0.0f64, |m, d| m.max(d.abs()));
    assert!(
        worst <= 0.01 * r.bbox_diagonal,
        "a boundary node {worst} from the union's surface"
    );
    // Two cavities through each other in a ball of radius 3: each wall inside the other
    // cavity is outside on both sides, so buried too; the organ keeps the ball less the
    // cavities' union (before, their lens was taken away twice, 1.2 % off).
    let moved = |mut s: SurfaceMesh, d: Vec3| {
        for p in &mut s.positions {
            *p += d;
        }
        s
    };
    let two_cavities = joined(&[
        (sphere(3.0), false),
        (sphere(1.0), true),
        (moved(sphere(1.0), centres[1]), true),
    ]);
    let fixed = repair(&two_cavities).unwrap();
    assert_eq!(fixed.defects.cavities, 2);
    assert!(fixed.defects.buried_triangles > 0);
    let want = ratio * (27.0 * ball - union);
    assert!(
        (fixed.enclosed_volume / want - 1.0).abs() < 1e-3,
        "{} against {want}",
        fixed.enclosed_volume
    );
    // A small ball on an edge of a coarse one (8 x 4 cells): no centroid of the coarse one
    // is buried, but its triangles across the seam are found by their boxes. The union
    // keeps the coarse ball and the part of the small one outside it: more than half of
    // it at a convex edge, less than all (before: more than both together).
    let coarse = grid(8, 4, false, |u, v| {
        let (t, p) = (2.0 * PI * u, PI * v);
        Vec3::new(p.sin() * t.cos(), p.sin() * t.sin(), -p.cos())
    });
    let big = repair(&coarse).unwrap();
    let t = big.triangles[0];
    let edge = (big.positions[t[0] as usize] + big.positions[t[1] as usize]) / 2.0;
    let small = moved(sphere(0.12), edge);
    let small_volume = repair(&small).unwrap().enclosed_volume;
    let fixed = repair(&joined(&[(coarse, false), (small, false)])).unwrap();
    let outside = (fixed.enclosed_volume - big.enclosed_volume) / small_volume;
    assert!(
        (0.5..0.8).contains(&outside),
        "{outside} of the small ball outside the coarse one"
    );
    for lone in [
        sphere(1.0),
        joined(&[(sphere(1.0), false), (sphere(0.5), true)]),
    ] {
        let fixed = repair(&lone).unwrap();
        assert!(fixed.buried.is_empty());
        assert_eq!(fixed.defects.buried_triangles, 0);
    }
}

/// A surface in a scanner's coordinates, far from the origin: a unit sphere 2e6 away has
/// the volume it has at the origin (summed about the origin, its terms are 1e18 times the
/// volume and it cancelled: the spacing came out 40 times too fine and the lattice was
/// refused as too large), and meshes to it.
#[test]
fn a_surface_far_from_the_origin_keeps_its_volume_and_meshes() {
    let near = sphere(1.0);
    let mut far = near.clone();
    for p in &mut far.positions {
        *p += Vec3::new(1e6, -2e6, 5e5);
    }
    let (v_near, v_far) = (
        repair(&near).unwrap().enclosed_volume,
        repair(&far).unwrap().enclosed_volume,
    );
    assert!(
        (v_far - v_near).abs() < 1e-6 * v_near,
        "{v_far} against {v_near}"
    );
    let (_, r) = tetrahedralize(&far, &TetrahedralizeOptions::default()).unwrap();
    assert!((1000..=2000).contains(&r.tets), "{r:?}");
    assert!((r.volume - v_near).abs() < 0.03 * v_near, "{r:?}");
}

#[test]
fn surfaces_too_broken_to_mesh_name_the_defect() {
    // An open sheet: no volume.
    let sheet = SurfaceMesh {
        positions: vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ],
        triangles: vec![[0, 1, 2]],
    };
    let e = tetrahedralize(&sheet, &TetrahedralizeOptions::default()).unwrap_err();
    assert!(
        matches!(e, TetrahedralizeError::NoEnclosedVolume { .. }),
        "{e}"
    );
    // Half a sphere: a hole as wide as the body.
    let mut half = sphere(0.5);
    let keep: Vec<[u32; 3]> = half
        .triangles
        .iter()
        .copied()
        .filter(|t| t.iter().all(|&v| half.positions[v as usize].z <= 0.01))
        .collect();
    half.triangles = keep;
    let e = tetrahedralize(&half, &TetrahedralizeOptions::default()).unwrap_err();
    assert!(
        matches!(
            e,
            TetrahedralizeError::TooOpen { .. } | TetrahedralizeError::NoEnclosedVolume { .. }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("boundary edges"), "{e}");
    // The rim is the sphere's polygonal equator (or the ring just below it): at most the
    // circle's 2 pi r, within the rings' spacing of it.
    if let TetrahedralizeError::TooOpen { rim_length, .. } = e {
        let circle = 2.0 * PI * 0.5;
        assert!(
            (0.95 * circle..=circle).contains(&rim_length),
            "rim {rim_length} against the equator's {circle}"
        );
    }
    // A vertex that is not finite, a triangle past the vertices, bad options.
    let mut nan = sphere(0.5);
    nan.positions[3].x = f64::NAN;
    let e = tetrahedralize(&nan, &TetrahedralizeOptions::default()).unwrap_err();
    assert!(e.to_string().contains("vertex 3"), "{e}");
    let mut bad = sphere(0.5);
    bad.triangles[5][1] = 100_000;
    let e = tetrahedralize(&bad, &TetrahedralizeOptions::default()).unwrap_err();
    assert!(e.to_string().contains("triangle 5"), "{e}");
    let e = tetrahedralize(
        &sphere(0.5),
        &TetrahedralizeOptions {
            edge_length: Some(-1.0),
            ..TetrahedralizeOptions::default()
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("edge length"), "{e}");
}
