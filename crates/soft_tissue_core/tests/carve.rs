//! Carving a ball out of a mesh whose elements are far larger than it (a crater an
//! electrode vaporized): against the ball's own geometry, not numbers of the code.
//!
//! Checked: tissue farther than the radius from the centre all stays; tissue well inside the
//! ball is all gone; the removed volume is the ball's part inside the mesh (a half ball at a
//! flat face) to the polyhedral sphere's error; what is left is a valid mesh (every element
//! positive, its boundary closed and 2-manifold); every node's origin gives its position.

use std::path::Path;

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::cut::{
    Ball, CARVE_SPACING, CutMesh, OUTWARD_SNAP, RemoveError, carve, carve_keeping, check,
};
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::scenario::Scene;
use soft_tissue_core::world::SoftTissueWorld;

const SNAP: f64 = 0.3;

/// Whether `p` lies in some tetrahedron of `mesh` (within a relative tolerance).
fn inside(mesh: &TetMesh, p: &Vec3) -> bool {
    let x = mesh.positions();
    mesh.tets().iter().any(|t| {
        let [a, b, c, d] = t.map(|i| x[i as usize]);
        let m = nalgebra::Matrix3::from_columns(&[b - a, c - a, d - a]);
        let Some(inv) = m.try_inverse() else {
            return false;
        };
        let w = inv * (p - a);
        let tol = -1e-9;
        w.x >= tol && w.y >= tol && w.z >= tol && w.x + w.y + w.z <= 1.0 - tol
    })
}

/// Every element positive and every boundary edge in exactly two boundary triangles.
fn assert_valid(before: &TetMesh, cut: &CutMesh) {
    assert!(
        cut.mesh.tet_volumes().iter().all(|&v| v > 0.0),
        "an element is not positive"
    );
    let c = check(before, cut);
    assert_eq!(
        c.non_manifold_edges, 0,
        "the boundary is not closed and 2-manifold: {c:?}"
    );
    assert_eq!(c.orphan_nodes, 0, "{c:?}");
}

/// A field of the mesh before that is not linear (a value per node from its index):
/// interpolated by each node's origin it must equal the mesh before's own piecewise-linear
/// interpolation at the node's rest position (found by searching every element), which holds
/// only when the origin names the element the node lies in.
fn assert_origins_follow_elements(before: &TetMesh, cut: &CutMesh) {
    let field: Vec<f64> = (0..before.node_count())
        .map(|i| ((i as f64) * 0.618_033_988_75).fract())
        .collect();
    let x = before.positions();
    for (k, (o, p)) in cut.node_origin.iter().zip(cut.mesh.positions()).enumerate() {
        // The element the point is least outside of.
        let mut best = (f64::NEG_INFINITY, 0.0);
        for tet in before.tets() {
            let [x0, x1, x2, x3] = tet.map(|v| x[v as usize]);
            let m = nalgebra::Matrix3::from_columns(&[x1 - x0, x2 - x0, x3 - x0]);
            let Some(inv) = m.try_inverse() else { continue };
            let l = inv * (p - x0);
            let w = [1.0 - l.x - l.y - l.z, l.x, l.y, l.z];
            let inside = w.iter().copied().fold(f64::INFINITY, f64::min);
            if inside > best.0 {
                let value = (0..4).map(|j| w[j] * field[tet[j] as usize]).sum();
                best = (inside, value);
            }
        }
        let got = o.interpolate(&field);
        assert!(
            (got - best.1).abs() <= 1e-9,
            "node {k}: its origin gives {got}, the element it lies in {}",
            best.1
        );
    }
}

/// Every node's origin, interpolated on the mesh before, gives its position.
fn assert_origins(before: &TetMesh, cut: &CutMesh) {
    let scale = before.bbox().diagonal();
    for (o, p) in cut.node_origin.iter().zip(cut.mesh.positions()) {
        let q = o.interpolate(before.positions());
        assert!(
            (q - p).norm() <= 1e-12 * scale,
            "origin {q:?} of node at {p:?}"
        );
    }
}

/// Points on a grid of spacing `h` in the box of `mesh`.
fn grid(mesh: &TetMesh, h: f64) -> Vec<Vec3> {
    let b = mesh.bbox();
    let n = ((b.max - b.min) / h).map(|v| v.ceil() as usize);
    let mut out = Vec::new();
    for i in 0..=n.x {
        for j in 0..=n.y {
            for k in 0..=n.z {
                out.push(b.min + Vec3::new(i as f64, j as f64, k as f64) * h);
            }
        }
    }
    out
}

/// Smallest dihedral angle of `mesh`'s elements, degrees (the cut's own measure, of the
/// mesh as it is: a carve of nothing).
fn smallest_angle(mesh: &TetMesh) -> f64 {
    let same = carve(mesh, None, &[], SNAP).unwrap();
    check(mesh, &same).smallest_dihedral
}

/// Carves `ball` out of `mesh` and checks it against the ball: returns the removed volume.
fn carve_and_check(mesh: &TetMesh, ball: Ball, probe: f64) -> (f64, CutMesh) {
    let started = std::time::Instant::now();
    let cut = carve(mesh, None, &[ball], SNAP).unwrap();
    let ms = started.elapsed().as_secs_f64() * 1e3;
    let before = smallest_angle(mesh);
    let after = smallest_angle(&cut.mesh);
    println!(
        "carve: {} -> {} tetrahedra, smallest dihedral angle {before:.1} -> {after:.1} deg, {ms:.1} ms",
        mesh.tet_count(),
        cut.mesh.tet_count(),
    );
    // Refinement and the sphere's cut keep elements usable: no angle below 2 degrees
    // (the outward snap's thinnest children) unless the mesh had smaller.
    assert!(
        after >= before.min(2.0),
        "smallest dihedral angle {after} deg"
    );
    assert_valid(mesh, &cut);
    assert_origins(mesh, &cut);
    let removed = mesh.volume() - cut.mesh.volume();
    // Probes near the ball: outside the radius (but for what snapping may take, a few %)
    // they stay, well inside they are gone.
    let mut stayed = 0;
    let mut gone = 0;
    for p in grid(mesh, probe) {
        let r = (p - ball.centre).norm();
        if r > 2.0 * ball.radius || !inside(mesh, &p) {
            continue;
        }
        if r > ball.radius * (1.0 + OUTWARD_SNAP * SNAP * CARVE_SPACING) {
            assert!(
                inside(&cut.mesh, &p),
                "tissue at {r:e} from the centre was removed"
            );
            stayed += 1;
        } else if r < 0.7 * ball.radius {
            assert!(
                !inside(&cut.mesh, &p),
                "tissue at {r:e} from the centre stayed"
            );
            gone += 1;
        }
    }
    assert!(stayed > 50 && gone > 5, "too few probes: {stayed} {gone}");
    (removed, cut)
}

/// A block of 10 mm elements; a ball of 2.5 mm carved at a point of its top face that is
/// not a node: half a ball leaves.
#[test]
fn a_half_ball_leaves_a_face_of_coarse_elements() {
    let mesh = block(Vec3::zeros(), Vec3::repeat(0.04), [4, 4, 4]).unwrap();
    let r = 0.0025;
    let ball = Ball {
        centre: Vec3::new(0.0172, 0.04, 0.0231),
        radius: r,
    };
    let (removed, cut) = carve_and_check(&mesh, ball, r / 8.0);
    let half = 2.0 / 3.0 * std::f64::consts::PI * r.powi(3);
    println!(
        "removed {:.3} mm^3 of a half ball of {:.3} mm^3 ({:+.1} %), {} bisections",
        removed * 1e9,
        half * 1e9,
        100.0 * (removed / half - 1.0),
        cut.bisected,
    );
    assert!((removed / half - 1.0).abs() < 0.25, "{removed} vs {half}");
    assert!(
        !cut.cut_faces.is_empty(),
        "the crater's walls are not cut sides"
    );
}

/// A ball wholly inside one element (no node or edge near it) is carved out all the same,
/// leaving a cavity with a closed inner surface.
#[test]
fn a_ball_inside_one_element_leaves_a_cavity() {
    let mesh = block(Vec3::zeros(), Vec3::repeat(0.04), [2, 2, 2]).unwrap();
    let r = 0.002;
    let ball = Ball {
        centre: Vec3::new(0.013, 0.011, 0.0087),
        radius: r,
    };
    let (removed, _) = carve_and_check(&mesh, ball, r / 8.0);
    let whole = 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
    println!(
        "cavity {:.3} mm^3 of a ball of {:.3} mm^3 ({:+.1} %)",
        removed * 1e9,
        whole * 1e9,
        100.0 * (removed / whole - 1.0),
    );
    assert!((removed / whole - 1.0).abs() < 0.25, "{removed} vs {whole}");
}

/// On the organs scene's liver, a 2 mm ball at its highest node.
#[test]
fn a_crater_on_the_liver() {
    let assets = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"));
    let w = SoftTissueWorld::from_scene(&Scene::paper_organs(), assets).unwrap();
    let i = w.body_index("Liver").unwrap();
    let mesh = (**w.bodies()[i].mesh()).clone();
    let s = w.bodies()[i]
        .heat()
        .map_or(0.01, |h| h.params().meters_per_unit);
    let x = mesh.positions();
    let top = x
        .iter()
        .copied()
        .max_by(|a, b| a.y.total_cmp(&b.y))
        .unwrap();
    let r = 0.002 / s;
    let ball = Ball {
        centre: top,
        radius: r,
    };
    let (removed, cut) = carve_and_check(&mesh, ball, r / 6.0);
    let whole = 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
    println!(
        "liver: removed {:.3} mm^3 ({:.2} of the ball); {} -> {} tetrahedra",
        removed * s.powi(3) * 1e9,
        removed / whole,
        mesh.tet_count(),
        cut.mesh.tet_count()
    );
    assert!(removed > 0.0 && removed < whole);
}

/// How many of the crater wall's nodes (those of the cut faces) lie on the ball's sphere
/// (to rounding), of how many.
fn wall_on_sphere(cut: &CutMesh, ball: &Ball) -> (usize, usize) {
    let p = cut.mesh.positions();
    let mut nodes: Vec<u32> = cut.cut_faces.iter().flatten().copied().collect();
    nodes.sort_unstable();
    nodes.dedup();
    let on = nodes
        .iter()
        .filter(|&&v| {
            ((p[v as usize] - ball.centre).norm() - ball.radius).abs() <= 1e-9 * ball.radius
        })
        .count();
    (on, nodes.len())
}

/// Nodes inside the mesh whose edge the sphere crosses near them are moved onto it (not
/// merely counted as on it), so the crater's wall is nearly the sphere's polyhedron. Off it
/// stay the nodes a move would spoil an element around, those counted as on it whose
/// crossings are farther than the warp reaches, and nodes of the mesh's own surface (a
/// crater's rim). Counted as on the sphere within snapping reach instead (the carve before
/// warping), 62 % of the cavity's and 82 % of the liver crater's wall nodes lay on it. The
/// nodes' origins still name the elements they lie in.
#[test]
fn crater_walls_lie_on_the_sphere() {
    let mesh = block(Vec3::zeros(), Vec3::repeat(0.04), [2, 2, 2]).unwrap();
    let ball = Ball {
        centre: Vec3::new(0.013, 0.011, 0.0087),
        radius: 0.002,
    };
    let cut = carve(&mesh, None, &[ball], SNAP).unwrap();
    assert_valid(&mesh, &cut);
    assert_origins(&mesh, &cut);
    assert_origins_follow_elements(&mesh, &cut);
    let (on, all) = wall_on_sphere(&cut, &ball);
    println!("cavity: {on} of {all} wall nodes on the sphere");
    assert!(on as f64 >= 0.95 * all as f64, "{on} of {all}");

    let assets = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"));
    let w = SoftTissueWorld::from_scene(&Scene::paper_organs(), assets).unwrap();
    let i = w.body_index("Liver").unwrap();
    let liver = (**w.bodies()[i].mesh()).clone();
    let s = w.bodies()[i]
        .heat()
        .map_or(0.01, |h| h.params().meters_per_unit);
    let top = liver
        .positions()
        .iter()
        .copied()
        .max_by(|a, b| a.y.total_cmp(&b.y))
        .unwrap();
    let ball = Ball {
        centre: top - Vec3::new(0.0, 0.0005 / s, 0.0),
        radius: 0.002 / s,
    };
    let cut = carve(&liver, None, &[ball], SNAP).unwrap();
    assert_valid(&liver, &cut);
    assert_origins(&liver, &cut);
    assert_origins_follow_elements(&liver, &cut);
    let (on, all) = wall_on_sphere(&cut, &ball);
    println!("liver crater: {on} of {all} wall nodes on the sphere");
    assert!(on as f64 >= 0.9 * all as f64, "{on} of {all}");
}

/// Supports stay where they are: with every node of the mesh before pinned, no node of it
/// moves (without pins the same carve moves some onto the sphere), and the carve is still
/// valid.
#[test]
fn pinned_nodes_are_not_moved() {
    let mesh = block(Vec3::zeros(), Vec3::repeat(0.04), [4, 4, 4]).unwrap();
    let ball = Ball {
        centre: Vec3::new(0.0172, 0.021, 0.0231),
        radius: 0.0075,
    };
    let moved = |cut: &CutMesh| {
        cut.node_origin
            .iter()
            .zip(cut.mesh.positions())
            .filter(|(o, p)| {
                o.weights[0] == 1.0 && (mesh.positions()[o.nodes[0] as usize] - *p).norm() > 0.0
            })
            .count()
    };
    // Nodes of the mesh before that go on as themselves (a single-node origin).
    let survivors = |cut: &CutMesh| {
        let mut v: Vec<u32> = cut
            .node_origin
            .iter()
            .filter(|o| o.weights[0] == 1.0)
            .map(|o| o.nodes[0])
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    let free = carve(&mesh, None, &[ball], SNAP).unwrap();
    let all = vec![true; mesh.node_count()];
    let kept = carve_keeping(&mesh, None, &[ball], SNAP, &all).unwrap();
    assert_valid(&mesh, &kept);
    assert_origins(&mesh, &kept);
    let (f, k) = (survivors(&free), survivors(&kept));
    println!(
        "nodes of the mesh before going on as themselves: {} free, {} pinned, of {}",
        f.len(),
        k.len(),
        mesh.node_count()
    );
    assert!(f.len() < k.len(), "the free carve moved no node");
    // Pinned: each node of the mesh before goes on where it was, or was inside the ball
    // (removed with it, within what snapping reaches).
    assert_eq!(moved(&kept), 0);
    let reach = ball.radius * (1.0 + OUTWARD_SNAP * SNAP * CARVE_SPACING);
    for (v, x) in mesh.positions().iter().enumerate() {
        if k.binary_search(&(v as u32)).is_err() {
            assert!(
                (x - ball.centre).norm() <= reach,
                "pinned node {v} at {:e} from the centre is gone",
                (x - ball.centre).norm()
            );
        }
    }
}

/// A ball that misses the mesh changes nothing; bad balls are refused by name.
#[test]
fn misses_and_bad_balls() {
    let mesh = block(Vec3::zeros(), Vec3::repeat(1.0), [2, 2, 2]).unwrap();
    let far = Ball {
        centre: Vec3::repeat(5.0),
        radius: 0.5,
    };
    let cut = carve(&mesh, None, &[far], SNAP).unwrap();
    assert_eq!((cut.separated, cut.bisected), (0, 0));
    assert_eq!(cut.mesh.tet_count(), mesh.tet_count());
    let nan = Ball {
        centre: Vec3::new(f64::NAN, 0.0, 0.0),
        radius: 0.1,
    };
    assert!(matches!(
        carve(&mesh, None, &[far, nan], SNAP),
        Err(RemoveError::BadBall { index: 1, .. })
    ));
    let flat = Ball {
        centre: Vec3::repeat(0.5),
        radius: 0.0,
    };
    assert!(matches!(
        carve(&mesh, None, &[flat], SNAP),
        Err(RemoveError::BadBall { index: 0, .. })
    ));
    let tiny = Ball {
        centre: Vec3::new(0.31, 1.0, 0.47),
        radius: 1e-9,
    };
    assert!(matches!(
        carve(&mesh, None, &[far, tiny], SNAP),
        Err(RemoveError::BadBall { index: 1, .. })
    ));
}

/// Two overlapping balls carved in one go (an electrode's path): what each cut leaves inside
/// it goes, though the other's refinement splits it after; the union leaves.
#[test]
fn overlapping_balls_leave_their_union() {
    let mesh = block(Vec3::zeros(), Vec3::repeat(0.04), [4, 4, 4]).unwrap();
    let r = 0.0025;
    let a = Ball {
        centre: Vec3::new(0.0172, 0.04, 0.0231),
        radius: r,
    };
    let b = Ball {
        centre: a.centre + Vec3::new(0.0015, -0.0012, 0.0004),
        radius: r,
    };
    let cut = carve(&mesh, None, &[a, b], SNAP).unwrap();
    assert_valid(&mesh, &cut);
    assert_origins(&mesh, &cut);
    assert_origins_follow_elements(&mesh, &cut);
    let reach = 1.0 + OUTWARD_SNAP * SNAP * CARVE_SPACING;
    let (mut stayed, mut gone) = (0, 0);
    for p in grid(&mesh, r / 8.0) {
        let d = [a, b].map(|c| (p - c.centre).norm() / c.radius);
        if d.iter().all(|&x| x > 3.0) || !inside(&mesh, &p) {
            continue;
        }
        if d.iter().all(|&x| x > reach) {
            assert!(
                inside(&cut.mesh, &p),
                "tissue outside both balls was removed"
            );
            stayed += 1;
        } else if d.iter().any(|&x| x < 0.7) {
            assert!(
                !inside(&cut.mesh, &p),
                "tissue inside a ball stayed at {p:?}"
            );
            gone += 1;
        }
    }
    assert!(stayed > 50 && gone > 5, "too few probes: {stayed} {gone}");
}
