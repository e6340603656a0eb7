//! Tetrahedral meshes from triangle surfaces, against closed forms: a sphere, a torus and a
//! non-convex L-shaped prism, their volumes and the distance between the mesh's boundary and
//! the surface both ways; a scan-like surface with duplicated vertices, flipped triangles and
//! a small hole still meshes; surfaces too broken to mesh get an error naming the defect.

use std::f64::consts::PI;

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::io::SurfaceMesh;
use soft_tissue_core::mesh::tetrahedralize::{
    TetrahedralizeError, TetrahedralizeOptions, TetrahedralizeReport, repair, tetrahedralize,
};

/// A closed grid surface: `f(u, v)` over `nu` x `nv` cells, periodic in `u`; `v` periodic
/// too (torus) or ending at two poles (sphere).
fn grid(nu: usize, nv: usize, periodic_v: bool, f: impl Fn(f64, f64) -> Vec3) -> SurfaceMesh {
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    let rows = if periodic_v { nv } else { nv - 1 };
    for j in 0..rows {
        let v = if periodic_v {
            j as f64 / nv as f64
        } else {
            (j + 1) as f64 / nv as f64
        };
        for i in 0..nu {
            positions.push(f(i as f64 / nu as f64, v));
        }
    }
    let at = |i: usize, j: usize| (j * nu + i % nu) as u32;
    let ring_pairs = if periodic_v { rows } else { rows - 1 };
    for j in 0..ring_pairs {
        let jn = (j + 1) % rows;
        for i in 0..nu {
            let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, jn), at(i, jn));
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    if !periodic_v {
        let south = positions.len() as u32;
        positions.push(f(0.0, 0.0));
        let north = positions.len() as u32;
        positions.push(f(0.0, 1.0));
        for i in 0..nu {
            triangles.push([south, at(i + 1, 0), at(i, 0)]);
            triangles.push([north, at(i, rows - 1), at(i + 1, rows - 1)]);
        }
    }
    SurfaceMesh {
        positions,
        triangles,
    }
}

fn sphere(r: f64) -> SurfaceMesh {
    grid(48, 24, false, |u, v| {
        let (t, p) = (2.0 * PI * u, PI * v);
        Vec3::new(r * p.sin() * t.cos(), r * p.sin() * t.sin(), -r * p.cos())
    })
}

/// An ellipsoid with semi-axes `a`, `b`, `c`: flat (`c` small), its rim curves as sharply as
/// a liver's edge.
fn ellipsoid(a: f64, b: f64, c: f64) -> SurfaceMesh {
    grid(96, 48, false, |u, v| {
        let (t, p) = (2.0 * PI * u, PI * v);
        Vec3::new(a * p.sin() * t.cos(), b * p.sin() * t.sin(), -c * p.cos())
    })
}

fn torus(big: f64, small: f64) -> SurfaceMesh {
    grid(64, 24, true, |u, v| {
        let (t, p) = (2.0 * PI * u, 2.0 * PI * v);
        let rho = big + small * p.cos();
        Vec3::new(rho * t.cos(), rho * t.sin(), small * p.sin())
    })
}

/// An L-shaped prism: the L of two unit squares on a 2 x 2 square's corner removed, `depth`
/// deep, each side face split into a fine grid so its triangles are not slivers.
fn l_prism(depth: f64) -> SurfaceMesh {
    // The L polygon, counter-clockwise: (0,0) (2,0) (2,1) (1,1) (1,2) (0,2).
    let outline: [(f64, f64); 6] = [
        (0.0, 0.0),
        (2.0, 0.0),
        (2.0, 1.0),
        (1.0, 1.0),
        (1.0, 2.0),
        (0.0, 2.0),
    ];
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    let n = 8; // subdivisions per unit length
    // Caps: the L as three unit squares, each an n x n grid, at z = 0 (facing -z) and
    // z = depth (facing +z).
    for (z, up) in [(0.0, false), (depth, true)] {
        for (ox, oy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)] {
            let base = positions.len() as u32;
            for j in 0..=n {
                for i in 0..=n {
                    positions.push(Vec3::new(
                        ox + i as f64 / n as f64,
                        oy + j as f64 / n as f64,
                        z,
                    ));
                }
            }
            let at = |i: u32, j: u32| base + j * (n as u32 + 1) + i;
            for j in 0..n as u32 {
                for i in 0..n as u32 {
                    let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                    if up {
                        triangles.push([a, b, c]);
                        triangles.push([a, c, d]);
                    } else {
                        triangles.push([a, c, b]);
                        triangles.push([a, d, c]);
                    }
                }
            }
        }
    }
    // Sides: each outline edge extruded, facing out (the outline runs counter-clockwise).
    let layers = (depth * n as f64).ceil() as u32;
    for k in 0..outline.len() {
        let (x0, y0) = outline[k];
        let (x1, y1) = outline[(k + 1) % outline.len()];
        let len = (x1 - x0).hypot(y1 - y0);
        let m = (len * n as f64).round() as u32;
        let base = positions.len() as u32;
        for j in 0..=layers {
            for i in 0..=m {
                let s = i as f64 / m as f64;
                positions.push(Vec3::new(
                    x0 + s * (x1 - x0),
                    y0 + s * (y1 - y0),
                    depth * j as f64 / layers as f64,
                ));
            }
        }
        let at = |i: u32, j: u32| base + j * (m + 1) + i;
        for j in 0..layers {
            for i in 0..m {
                let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                triangles.push([a, b, c]);
                triangles.push([a, c, d]);
            }
        }
    }
    // The caps and sides share their rim vertices by position: the repair welds them.
    SurfaceMesh {
        positions,
        triangles,
    }
}

/// Meshes `s` to about `target` tetrahedra and checks the issue's targets against the closed
/// form `exact`: the mesh's volume within 3 % of the enclosed one and that within 3 % of the
/// closed form, the mesh's boundary within `mesh_to_surface` of the bounding-box diagonal of
/// the surface and the surface within `surface_to_mesh` of the boundary (both sampled at
/// vertices, edge midpoints and centroids), no dihedral angle below 8 degrees, the
/// tetrahedron count within a third of the target (1000-2000 for 1500).
fn check(
    name: &str,
    s: &SurfaceMesh,
    exact: f64,
    target: usize,
    mesh_to_surface: f64,
    surface_to_mesh: f64,
) -> TetrahedralizeReport {
    let options = TetrahedralizeOptions {
        target_tets: Some(target),
        ..TetrahedralizeOptions::default()
    };
    let (mesh, r) = tetrahedralize(s, &options).unwrap();
    eprintln!("{name}: {r:?}");
    assert!(
        (r.volume - r.enclosed_volume).abs() <= 0.03 * r.enclosed_volume,
        "{name}: volume {} against the enclosed {}",
        r.volume,
        r.enclosed_volume
    );
    assert!(
        (r.enclosed_volume - exact).abs() <= 0.03 * exact,
        "{name}: the surface encloses {} against the closed form {exact}",
        r.enclosed_volume
    );
    for (what, d, bound) in [
        ("mesh to surface", r.mesh_to_surface, mesh_to_surface),
        ("surface to mesh", r.surface_to_mesh, surface_to_mesh),
    ] {
        assert!(
            d <= bound * r.bbox_diagonal,
            "{name}: {what} {d} against {} % of the diagonal {}",
            100.0 * bound,
            r.bbox_diagonal
        );
    }
    assert!(
        r.min_dihedral_deg >= 8.0,
        "{name}: smallest dihedral {}",
        r.min_dihedral_deg
    );
    assert!(
        (2 * target / 3..=4 * target / 3).contains(&r.tets),
        "{name}: {} tetrahedra for a target of {target}",
        r.tets
    );
    assert_eq!(mesh.tet_count(), r.tets);
    // Within what the mesher aims at, its report says nothing is missed.
    if mesh_to_surface <= 0.01 && surface_to_mesh <= 0.01 {
        assert_eq!(r.shortfall(), None, "{name}");
    }
    r
}

/// A sphere of radius 0.5 at a spacing of 0.3: its chords cut a cap of height
/// r (1 - cos(theta / 2)) off the sphere, several % of the diagonal for chords this long,
/// and the report says what it missed.
#[test]
fn a_mesh_too_coarse_for_the_surface_says_what_it_missed() {
    let options = TetrahedralizeOptions {
        edge_length: Some(0.3),
        ..TetrahedralizeOptions::default()
    };
    let (_, r) = tetrahedralize(&sphere(0.5), &options).unwrap();
    let worst = r.mesh_to_surface.max(r.surface_to_mesh) / r.bbox_diagonal;
    assert!(worst > 0.01, "{r:?}");
    let short = r.shortfall().expect("a shortfall");
    assert!(
        short.contains(&format!(
            "{:.2} % of the bounding box's diagonal",
            100.0 * worst
        )),
        "{short}"
    );
    assert!(short.contains(&format!("{} tetrahedra", r.tets)), "{short}");
}

#[test]
fn a_sphere_meshes_to_its_volume_and_surface() {
    let r = 0.5;
    check(
        "sphere",
        &sphere(r),
        4.0 / 3.0 * PI * r.powi(3),
        1500,
        0.01,
        0.01,
    );
}

#[test]
fn a_torus_meshes_to_its_volume_and_surface() {
    // A thin tube needs more tetrahedra than a ball for the same accuracy: at 1500 its
    // volume came out 3.1 % low (2.313 against 2.387).
    let (big, small) = (1.0, 0.35);
    check(
        "torus",
        &torus(big, small),
        2.0 * PI * PI * big * small * small,
        3000,
        0.01,
        0.01,
    );
}

/// A lens (the ellipsoid 1 x 0.6 x `c`) at 1500 tetrahedra, held to 1 % of the diagonal both
/// ways and 3 % of its volume.
fn lens(name: &str, c: f64) -> TetrahedralizeReport {
    let (a, b) = (1.0, 0.6);
    check(
        name,
        &ellipsoid(a, b, c),
        4.0 / 3.0 * PI * a * b * c,
        1500,
        0.01,
        0.01,
    )
}

/// A flat lens (c = 0.15): a uniform lattice at 1500 tetrahedra leaves its rim near 1 % of
/// the diagonal away; whichever mesh is kept, its boundary edges are split toward the rim.
#[test]
fn a_thin_lens_meshes_to_its_volume_and_surface() {
    let r = lens("lens", 0.15);
    assert!(r.split_edges > 0, "{r:?}");
}

/// A knife-edged lens (c = 0.1: its rim's radius of curvature, c^2 / a, is 0.43 % of the
/// diagonal): meshed finer and coarsened where the faces are flat (graded).
#[test]
fn a_knife_edged_lens_meshes_graded_to_its_volume_and_surface() {
    let r = lens("knife lens", 0.1);
    assert!(r.graded, "the knife lens needs the graded mesh: {r:?}");
}

/// A wafer lens (c = 0.03: 0.06 thick, 2.6 % of its bounding box's diagonal). Five
/// tetrahedra per lattice cube of the volume give a spacing of 0.063, at which the wafer
/// holds too few; the count's correction then asks for a spacing thicker than the wafer,
/// where no lattice tetrahedron fits inside it. That spacing is halved until one does; the
/// count is corrected from there and the rim graded as for any shape.
#[test]
fn a_wafer_thinner_than_the_counts_spacing_meshes_to_its_volume_and_surface() {
    let r = lens("wafer lens", 0.03);
    assert!(r.graded, "the wafer's rim needs the graded mesh: {r:?}");
}

#[test]
fn a_non_convex_l_prism_meshes_to_its_volume_and_surface() {
    let depth = 0.6;
    // Stuffing rounds sharp edges; the feature fit then pulls boundary nodes onto the
    // creases and corners where the quality bound allows (interior nodes making room).
    // Measured: 0.49 % of the diagonal mesh to surface, 0.63 % surface to mesh, graded
    // (1.22 and 1.29 % before interior nodes made room, 4.0 % before the fit).
    let r = check("L prism", &l_prism(depth), 3.0 * depth, 1500, 0.01, 0.01);
    assert!(r.snapped_nodes > 0, "nodes moved onto the creases");
    assert!(r.defects.duplicate_vertices > 0, "the rims are welded");
}

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

/// Pieces joined into one surface, each renumbered; `inward` turns a piece inside out.
fn joined(parts: &[(SurfaceMesh, bool)]) -> SurfaceMesh {
    let mut out = SurfaceMesh::default();
    for (part, inward) in parts {
        let base = out.positions.len() as u32;
        out.positions.extend(&part.positions);
        out.triangles.extend(part.triangles.iter().map(|t| {
            let t = t.map(|v| base + v);
            if *inward { [t[0], t[2], t[1]] } else { t }
        }));
    }
    out
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

/// The hierarchy's answers against the sums over every triangle: the closest distance exact,
/// the winding number within 2e-2 (the far clusters' dipoles; the mesher reads only whether
/// it exceeds one half), at points inside, outside and
/// near the surface of a torus.
#[test]
fn the_surface_tree_agrees_with_the_sums_over_every_triangle() {
    let s = repair(&torus(1.0, 0.35)).unwrap();
    let tree = soft_tissue_core::mesh::surface_tree::SurfaceTree::new(&s.positions, &s.triangles);
    let mut seed = 12345u64;
    let mut next = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut worst: f64 = 0.0;
    for _ in 0..400 {
        let p = Vec3::new(3.0 * next() - 1.5, 3.0 * next() - 1.5, next() - 0.5);
        let exact_d = s
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|v| s.positions[v as usize]);
                // Distance to the triangle by its closest point (sampled edges and the plane
                // are not needed: compare with the tree's own closest point's distance).
                [a, b, c]
                    .iter()
                    .map(|q| (q - p).norm())
                    .fold(f64::INFINITY, f64::min)
            })
            .fold(f64::INFINITY, f64::min);
        let (q, d) = tree.closest(&p).unwrap();
        assert!((q - p).norm() - d < 1e-12);
        assert!(
            d <= exact_d + 1e-12,
            "closest {d} beyond the nearest vertex {exact_d}"
        );
        let w = tree.winding_number(&p);
        let exact = s.winding_number(&p);
        worst = worst.max((w - exact).abs());
        assert!(
            (w - exact).abs() < 2e-2,
            "winding {w} against {exact} at {p:?}"
        );
    }
    eprintln!("largest winding-number difference {worst:.2e}");
}

/// A point written as a JSON array of three numbers.
fn json_point(p: &serde_json::Value) -> Vec3 {
    let c: Vec<f64> = p
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    Vec3::new(c[0], c[1], c[2])
}

/// The surface readers against files meshio wrote (tests/fixtures/make_surface_fixtures.py):
/// ASCII and binary STL and PLY, and OBJ give, once welded, the reference's points and triangles
/// (binary STL to float precision), and the binary STL meshes.
#[test]
fn surface_files_written_by_meshio_read_back_as_the_reference() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures");
    let text = std::fs::read_to_string(dir.join("surface_reference.json")).unwrap();
    let reference: serde_json::Value = serde_json::from_str(&text).unwrap();
    let points: Vec<Vec3> = reference["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(json_point)
        .collect();
    let triangles: Vec<[usize; 3]> = reference["triangles"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| {
            let c: Vec<usize> = t
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_u64().unwrap() as usize)
                .collect();
            [c[0], c[1], c[2]]
        })
        .collect();
    for (file, tol) in [
        ("sphere_ascii.stl", 1e-12),
        ("sphere_binary.stl", 1e-6),
        ("sphere.obj", 1e-12),
        ("sphere_ascii.ply", 1e-12),
        ("sphere_binary.ply", 1e-12),
    ] {
        let s = soft_tissue_core::mesh::io::read_surface(dir.join(file)).unwrap();
        assert_eq!(s.triangles.len(), triangles.len(), "{file}");
        let fixed = repair(&s).unwrap();
        assert_eq!(
            fixed.positions.len(),
            points.len(),
            "{file}: welded vertices"
        );
        assert_eq!(fixed.defects.boundary_edges, 0, "{file}");
        assert_eq!(
            fixed.defects.flipped_triangles, 0,
            "{file}: meshio keeps the orientation"
        );
        // Every reference triangle is there, in the same turning order.
        for (k, t) in triangles.iter().enumerate() {
            let want = t.map(|v| points[v]);
            let found = fixed.triangles.iter().any(|f| {
                let got = f.map(|v| fixed.positions[v as usize]);
                (0..3).any(|r| (0..3).all(|i| (got[(i + r) % 3] - want[i]).norm() < tol))
            });
            assert!(found, "{file}: triangle {k} missing");
        }
    }
    let s = soft_tissue_core::mesh::io::read_surface(dir.join("sphere_binary.stl")).unwrap();
    let (_, r) = tetrahedralize(&s, &TetrahedralizeOptions::default()).unwrap();
    assert!(
        (r.volume - r.enclosed_volume).abs() <= 0.03 * r.enclosed_volume,
        "{r:?}"
    );
    // Not a surface file, and a truncated binary STL: errors naming the file.
    let e = soft_tissue_core::mesh::io::read_surface(dir.join("block.node")).unwrap_err();
    assert!(e.to_string().contains("block.node"), "{e}");
    let data = std::fs::read(dir.join("sphere_binary.stl")).unwrap();
    let e = soft_tissue_core::mesh::io::parse_stl(&data[..data.len() - 7], "cut.stl").unwrap_err();
    assert!(e.to_string().contains("cut.stl"), "{e}");
}

/// The glTF reader against files two other writers made (tests/fixtures/make_surface_fixtures.py):
/// a GLB from trimesh (one node, rotated and moved) and a `.gltf` from pygltflib (a scaled
/// parent with two children sharing the mesh, one mirrored), with its buffer in a `.bin` file
/// or in a base64 data URI. Every placed triangle is found at its world place, facing out.
#[test]
fn gltf_files_written_by_trimesh_and_pygltflib_read_back_placed() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures");
    let text = std::fs::read_to_string(dir.join("surface_reference.json")).unwrap();
    let reference: serde_json::Value = serde_json::from_str(&text).unwrap();
    let triangles_of = |key: &str| -> Vec<[Vec3; 3]> {
        reference["gltf"][key]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| {
                let p: Vec<Vec3> = t.as_array().unwrap().iter().map(json_point).collect();
                [p[0], p[1], p[2]]
            })
            .collect()
    };
    for (file, key) in [
        ("sphere.glb", "sphere.glb"),
        ("spheres.gltf", "spheres.gltf"),
        ("spheres_embedded.gltf", "spheres.gltf"),
    ] {
        let want = triangles_of(key);
        let s = soft_tissue_core::mesh::io::read_surface(dir.join(file)).unwrap();
        assert_eq!(s.triangles.len(), want.len(), "{file}");
        let got: Vec<[Vec3; 3]> = s
            .triangles
            .iter()
            .map(|t| t.map(|v| s.positions[v as usize]))
            .collect();
        // Positions are 32-bit floats in the file.
        let tol = 1e-5;
        for (k, w) in want.iter().enumerate() {
            let found = got
                .iter()
                .any(|g| (0..3).any(|r| (0..3).all(|i| (g[(i + r) % 3] - w[i]).norm() < tol)));
            assert!(
                found,
                "{file}: placed triangle {k} missing or turned the wrong way"
            );
        }
        let fixed = repair(&s).unwrap();
        assert_eq!(
            fixed.defects.flipped_triangles, 0,
            "{file}: every piece faces out"
        );
        assert_eq!(fixed.defects.boundary_edges, 0, "{file}");
    }
    // A mirrored child keeps its volume: the two spheres (scale 2) enclose 8x the one's.
    let one = repair(&soft_tissue_core::mesh::io::read_surface(dir.join("sphere.glb")).unwrap())
        .unwrap()
        .enclosed_volume;
    let two = repair(&soft_tissue_core::mesh::io::read_surface(dir.join("spheres.gltf")).unwrap())
        .unwrap()
        .enclosed_volume;
    assert!((two / one - 16.0).abs() < 1e-4, "{two} against {one}");
    // Broken files: a GLB cut short, a .gltf whose buffer file is missing, a buffer too
    // short and an index out of range each name the file and what is wrong.
    use soft_tissue_core::mesh::io::parse_gltf;
    let glb = std::fs::read(dir.join("sphere.glb")).unwrap();
    let e = parse_gltf(&glb[..glb.len() - 9], "cut.glb", &mut |_| unreachable!()).unwrap_err();
    assert!(e.to_string().contains("cut.glb"), "{e}");
    let gltf = std::fs::read(dir.join("spheres.gltf")).unwrap();
    let bin = std::fs::read(dir.join("spheres.bin")).unwrap();
    let e = soft_tissue_core::mesh::io::read_surface(dir.join("missing_buffer.gltf"));
    assert!(e.is_err());
    let e = parse_gltf(&gltf, "short.gltf", &mut |_| Ok(bin[..100].to_vec())).unwrap_err();
    assert!(
        e.to_string().contains("short.gltf") && e.to_string().contains("buffer 0"),
        "{e}"
    );
    let mut bad = bin.clone();
    bad[0] = 0xff; // the first 16-bit index: 255 + 256 * its high byte, past the 66 points
    bad[1] = 0x7f;
    let e = parse_gltf(&gltf, "index.gltf", &mut |_| Ok(bad.clone())).unwrap_err();
    assert!(e.to_string().contains("index 0 is 32767"), "{e}");
    let e = parse_gltf(
        b"{\"asset\":{\"version\":\"2.0\"}}",
        "empty.gltf",
        &mut |_| unreachable!(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("no triangles"), "{e}");
}

/// A glTF node hierarchy is a set of trees: a node under two parents is refused with both
/// named (walked as given, a chain of 40 such nodes placed its mesh 2^40 times and never
/// finished), while a mesh shared by two nodes, the format's instancing, is placed twice.
#[test]
fn a_gltf_node_under_two_parents_is_refused_and_a_shared_mesh_is_placed_twice() {
    use soft_tissue_core::mesh::io::parse_gltf;
    // One triangle, (0,0,0) (1,0,0) (0,1,0), in a data URI.
    let with_nodes = |nodes: &str, roots: &str| {
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":{roots}}}],
            "nodes":{nodes},"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",
            "min":[0,0,0],"max":[1,1,0]}}],"bufferViews":[{{"buffer":0,"byteLength":36}}],
            "buffers":[{{"byteLength":36,
            "uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA"}}]}}"#
        )
    };
    let diamond = with_nodes(r#"[{"children":[1,2]},{"children":[2]},{"mesh":0}]"#, "[0]");
    let e = parse_gltf(diamond.as_bytes(), "diamond.gltf", &mut |_| unreachable!()).unwrap_err();
    assert!(
        e.to_string()
            .contains("diamond.gltf: node 2 is a child of both node 0 and node 1"),
        "{e}"
    );
    let shared = with_nodes(
        r#"[{"children":[1,2]},{"mesh":0},{"mesh":0,"translation":[0,0,5]}]"#,
        "[0]",
    );
    let s = parse_gltf(shared.as_bytes(), "shared.gltf", &mut |_| unreachable!()).unwrap();
    assert_eq!(s.triangles.len(), 2);
    for z in [0.0, 5.0] {
        assert!(
            s.positions.contains(&Vec3::new(0.0, 1.0, z)),
            "{:?}",
            s.positions
        );
    }
}

/// A meshed surface simulates: in a world with the organ material, the built-in `poke`
/// raises it to its precise level and, after the withdrawal, it returns to its cage.
#[test]
fn a_meshed_surface_rises_under_a_poke_and_returns_to_its_cage() {
    let (mesh, r) = tetrahedralize(&sphere(0.5), &TetrahedralizeOptions::default()).unwrap();
    assert!(!r.graded);
    poke_rises_and_returns(mesh);
}

/// The same with a graded mesh (the lens): its coarsened boundary simulates as well.
#[test]
fn a_graded_mesh_rises_under_a_poke_and_returns_to_its_cage() {
    let (mesh, r) =
        tetrahedralize(&ellipsoid(1.0, 0.6, 0.1), &TetrahedralizeOptions::default()).unwrap();
    assert!(r.graded);
    poke_rises_and_returns(mesh);
}

fn poke_rises_and_returns(mesh: soft_tissue_core::mesh::TetMesh) {
    use soft_tissue_core::contact::{ContactConfig, Tool};
    use soft_tissue_core::precision::{BodySettings, Level};
    use soft_tissue_core::scenario::{Anchor, CYLINDER_MSD, ORGAN_FEM};
    use soft_tissue_core::world::{Script, ScriptAction, SimBody, SoftTissueWorld, WorldConfig};
    let dt = ORGAN_FEM.dt;
    let mut settings = BodySettings::new(ORGAN_FEM.params, CYLINDER_MSD.params, dt);
    settings.boundary = Anchor::SoftToRest { stiffness: 1.0 }.boundary(&mesh);
    let mut world = SoftTissueWorld::new(WorldConfig {
        dt,
        contact: ContactConfig::for_scale(mesh.bbox().smallest_dimension()),
    })
    .unwrap();
    let body = SimBody::new("sphere", std::sync::Arc::new(mesh), settings, None).unwrap();
    world.add_body(body).unwrap();
    let script = Script::builtin("poke", &world).unwrap();
    let tool = world.add_tool(Tool::new("tool", script.tool).unwrap());
    let (mut rose, mut precise_at_end) = (false, true);
    for k in 1..=800 {
        let t = k as f64 * dt;
        let (p, a) = script.pose_at(t);
        let tl = &mut world.tools_mut()[tool];
        tl.set_pose(p, a).unwrap();
        for e in script.events_in(t - dt, t) {
            if let ScriptAction::Cautery(w) = e.action {
                tl.set_cautery(w).unwrap();
            }
        }
        world.step_fixed().unwrap();
        let level = world.bodies()[0].body().level();
        rose |= level == Level::Precise;
        precise_at_end = level == Level::Precise;
    }
    assert!(rose, "the poke raised the meshed sphere");
    assert!(!precise_at_end, "it returned to its cage");
    let last = world.bodies()[0].body().last_switch().unwrap();
    assert!(last.jump_ratio < 0.005, "{last:?}");
}
