//! Tetrahedral meshes from triangle surfaces, against closed forms: a sphere, a torus and a
//! non-convex L-shaped prism, their volumes and the distance between the mesh's boundary and
//! the surface both ways; a scan-like surface with duplicated vertices, flipped triangles and
//! a small hole still meshes; surfaces too broken to mesh get an error naming the defect.
//!
//! One file per concern: the closed-form shapes (`shapes.rs`), the repair of scan defects,
//! nesting and overlaps (`repair.rs`), the surface readers against other writers' files
//! (`readers.rs`), a meshed surface simulated (`simulate.rs`), the meshes byte for byte
//! (`golden.rs`), meshing to a distance (`distance.rs`).

mod distance;
mod golden;
mod readers;
mod repair;
mod shapes;
mod simulate;

use std::f64::consts::PI;

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::io::SurfaceMesh;
use soft_tissue_core::mesh::tetrahedralize::{
    TetrahedralizeOptions, TetrahedralizeReport, repair, tetrahedralize,
};

use shapes::{capsule, cuboid, ellipsoid, l_prism, sphere, torus};

/// The mesh's volume, summed here from its tetrahedra (a sixth of each triple product).
pub fn volume_of(mesh: &TetMesh) -> f64 {
    let x = mesh.positions();
    mesh.tets()
        .iter()
        .map(|t| {
            let [a, b, c, d] = t.map(|v| x[v as usize]);
            (b - a).dot(&(c - a).cross(&(d - a))) / 6.0
        })
        .sum()
}

/// The largest of `distance` over the mesh's boundary: its nodes, edge midpoints and
/// triangle centroids.
pub fn farthest_on_boundary(mesh: &TetMesh, distance: impl Fn(&Vec3) -> f64) -> f64 {
    let x = mesh.positions();
    let mut worst: f64 = 0.0;
    for t in mesh.surface().triangles() {
        let [a, b, c] = t.map(|v| x[v as usize]);
        for p in [
            a,
            (a + b) / 2.0,
            (b + c) / 2.0,
            (c + a) / 2.0,
            (a + b + c) / 3.0,
        ] {
            worst = worst.max(distance(&p));
        }
    }
    worst
}

/// Meshes `s` to about `target` tetrahedra and checks the targets against the closed
/// form `exact` of the shape the surface approximates: the mesh's volume (summed here) within
/// 3 % of it (the mesher's aim, its facets' loss included: at most 1.3 % for these grid
/// surfaces, from their vertices), and the volume the mesher reports enclosed within 1.5 %;
/// the mesh's boundary within `mesh_to_surface` of the bounding-box diagonal of the surface
/// and the surface within `surface_to_mesh` of the boundary (the mesher's own measures,
/// sampled at vertices, edge midpoints and centroids; where the shape has a closed-form
/// distance, `test_distance` checks the first against it here), no dihedral angle below
/// 8 degrees, the tetrahedron count within a third of the target (1000-2000 for 1500).
pub fn check(
    name: &str,
    s: &SurfaceMesh,
    exact: f64,
    target: usize,
    mesh_to_surface: f64,
    surface_to_mesh: f64,
) -> TetrahedralizeReport {
    check_with(
        name,
        s,
        exact,
        target,
        (mesh_to_surface, surface_to_mesh),
        None,
    )
}

/// [`check`], and where `distance` is given (the unsigned distance to the exact shape's
/// surface, in closed form) every boundary sample of the mesh within `mesh_to_surface` of
/// the diagonal of it.
pub fn check_with(
    name: &str,
    s: &SurfaceMesh,
    exact: f64,
    target: usize,
    (mesh_to_surface, surface_to_mesh): (f64, f64),
    distance: Option<&dyn Fn(&Vec3) -> f64>,
) -> TetrahedralizeReport {
    let options = TetrahedralizeOptions {
        target_tets: Some(target),
        ..TetrahedralizeOptions::default()
    };
    let (mesh, r) = tetrahedralize(s, &options).unwrap();
    eprintln!("{name}: {r:?}");
    let volume = volume_of(&mesh);
    assert!(
        (volume - exact).abs() <= 0.03 * exact,
        "{name}: volume {volume} against the closed form {exact}"
    );
    assert!(
        (r.enclosed_volume - exact).abs() <= 0.015 * exact,
        "{name}: the surface encloses {} against the closed form {exact}",
        r.enclosed_volume
    );
    assert!((r.volume - volume).abs() <= 1e-9 * volume, "{name}");
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
    if let Some(distance) = distance {
        let d = farthest_on_boundary(&mesh, distance);
        assert!(
            d <= mesh_to_surface * r.bbox_diagonal,
            "{name}: a boundary point {d} from the exact shape ({} % of the diagonal {})",
            100.0 * mesh_to_surface,
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
    check_with(
        "sphere",
        &sphere(r),
        4.0 / 3.0 * PI * r.powi(3),
        1500,
        (0.01, 0.01),
        Some(&|p: &Vec3| (p.norm() - r).abs()),
    );
}

#[test]
fn a_torus_meshes_to_its_volume_and_surface() {
    // A thin tube needs more tetrahedra than a ball for the same accuracy: at 1500 its
    // volume came out 3.1 % low (2.313 against 2.387).
    let (big, small) = (1.0, 0.35);
    check_with(
        "torus",
        &torus(big, small),
        2.0 * PI * PI * big * small * small,
        3000,
        (0.01, 0.01),
        Some(&|p: &Vec3| ((p.x.hypot(p.y) - big).hypot(p.z) - small).abs()),
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

/// A box (2 x 1 x 0.5, each face a grid of squares: its facets are the box, so its volume is
/// the closed form's exactly) meshes to its volume, its boundary within 1 % of the diagonal
/// of the box's faces (the closed-form distance to a box), its creases and corners fitted.
#[test]
fn a_box_meshes_to_its_volume_and_surface() {
    let size = Vec3::new(2.0, 1.0, 0.5);
    let half = size / 2.0;
    let r = check_with(
        "box",
        &cuboid(size, 8),
        size.x * size.y * size.z,
        1500,
        (0.01, 0.01),
        Some(&|p: &Vec3| {
            // Outside: the distance to the box; inside: to its nearest face.
            let q = p.abs() - half;
            let outside = q.map(|c| c.max(0.0)).norm();
            outside + q.max().min(0.0).abs()
        }),
    );
    assert!(r.snapped_nodes > 0, "nodes moved onto the creases");
}

/// A capsule (a cylinder of radius 0.3 and length 1 between two half balls) meshes to its
/// closed-form volume pi r^2 (4 r / 3 + l), its boundary within 1 % of the diagonal of the
/// exact capsule (distance to the axis segment, less r).
#[test]
fn a_capsule_meshes_to_its_volume_and_surface() {
    let (radius, length) = (0.3, 1.0);
    check_with(
        "capsule",
        &capsule(radius, length),
        PI * radius * radius * (4.0 * radius / 3.0 + length),
        1500,
        (0.01, 0.01),
        Some(&|p: &Vec3| {
            let z = p.z.clamp(-length / 2.0, length / 2.0);
            ((p - Vec3::new(0.0, 0.0, z)).norm() - radius).abs()
        }),
    );
}

/// Uniform numbers in [0, 1) from `seed` (xorshift64).
fn uniform(mut seed: u64) -> impl FnMut() -> f64 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The hierarchy's answers against the sums over every triangle: the closest distance exact,
/// the winding number within 2e-2 (the far clusters' dipoles; the mesher reads only whether
/// it exceeds one half), at points inside, outside and
/// near the surface of a torus.
#[test]
fn the_surface_tree_agrees_with_the_sums_over_every_triangle() {
    let s = repair(&torus(1.0, 0.35)).unwrap();
    let tree = soft_tissue_core::mesh::surface_tree::SurfaceTree::new(&s.positions, &s.triangles);
    let mut next = uniform(12345u64);
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

/// Along a segment the winding number changes only where the segment crosses a triangle
/// (what the stuffing's bisections ask instead of a winding number per step): on random
/// segments through a torus, the crossings found once give the side the hierarchy's winding
/// number gives at every point tried (away from the crossings themselves); a segment in a
/// triangle's plane or through one of its corners is refused (the bisection then asks the
/// winding number).
#[test]
fn the_winding_number_along_a_segment_gives_the_trees_sides() {
    let s = repair(&torus(1.0, 0.35)).unwrap();
    let tree = soft_tissue_core::mesh::surface_tree::SurfaceTree::new(&s.positions, &s.triangles);
    let mut next = uniform(777u64);
    let (mut along_count, mut crossings, mut points) = (0, 0, 0);
    for _ in 0..300 {
        let a = Vec3::new(3.0 * next() - 1.5, 3.0 * next() - 1.5, next() - 0.5);
        let b = a + Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * 0.8;
        let Some(along) = tree.winding_along(&a, &b) else {
            continue;
        };
        along_count += 1;
        let (wa, wb) = (tree.winding_number(&a), tree.winding_number(&b));
        crossings += usize::from((wa > 0.5) != (wb > 0.5));
        for k in 0..64 {
            let t = (k as f64 + next()) / 64.0;
            if let Some(w) = along.at(t) {
                points += 1;
                let direct = tree.winding_number(&(a + (b - a) * t));
                assert_eq!(
                    w > 0.5,
                    direct > 0.5,
                    "{w} against {direct} at {t} on {a:?} {b:?}"
                );
            }
        }
    }
    eprintln!(
        "{along_count} segments of 300 answered, {crossings} crossing the surface, {points} points"
    );
    assert!(along_count > 280, "{along_count}");
    assert!(crossings > 30, "{crossings}");
    // Through a corner of the surface, and along an edge (in the plane of its triangles).
    let [p, q, _] = s.triangles[0].map(|v| s.positions[v as usize]);
    let n = (q - p).cross(&Vec3::new(0.3, 0.2, 0.9)).normalize();
    assert!(tree.winding_along(&(p - n * 0.1), &(p + n * 0.1)).is_none());
    assert!(
        tree.winding_along(&(p - (q - p) * 0.5), &(q + (q - p) * 0.5))
            .is_none()
    );
}
