//! Meshes with the defects real meshes have: tetrahedra that share only an edge or only a
//! vertex (non-manifold boundary edges and vertices), a bowtie of two cubes meeting along an
//! edge, several components and nodes no tetrahedron uses. Every part that reads the surface
//! must take them: the contact surface's inside test (checked against the tetrahedra
//! themselves, an independent answer), tools and bodies in contact, cages, heat.

use std::sync::Arc;

use soft_tissue_core::Vec3;
use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::contact::{ContactConfig, SurfaceCollider, Tool, ToolShape};
use soft_tissue_core::heat::{HeatBoundary, HeatField, HeatParams};
use soft_tissue_core::material::{FemParams, MsdParams};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::precision::{BodySettings, Level, LeveledModel};
use soft_tissue_core::scenario::CageKind;
use soft_tissue_core::world::{SoftTissueWorld, WorldBody, WorldConfig};

/// Merges meshes, joining nodes at exactly the same position, and appends `unused` nodes no
/// tetrahedron refers to.
fn merged(parts: &[TetMesh], unused: &[Vec3]) -> TetMesh {
    let mut positions: Vec<Vec3> = Vec::new();
    let mut tets = Vec::new();
    for m in parts {
        let map: Vec<usize> = m
            .positions()
            .iter()
            .map(|p| match positions.iter().position(|q| q == p) {
                Some(i) => i,
                None => {
                    positions.push(*p);
                    positions.len() - 1
                }
            })
            .collect();
        tets.extend(m.tets().iter().map(|t| t.map(|i| map[i as usize])));
    }
    positions.extend_from_slice(unused);
    TetMesh::new(positions, tets).unwrap()
}

fn single(points: [Vec3; 4]) -> TetMesh {
    TetMesh::new(points.to_vec(), vec![[0, 1, 2, 3]]).unwrap()
}

/// Two tetrahedra on either side of the edge from the origin to (0, 0, 1), sharing only it.
fn edge_pair() -> TetMesh {
    let (o, z) = (Vec3::zeros(), Vec3::new(0.0, 0.0, 1.0));
    merged(
        &[
            single([o, z, Vec3::new(1.0, 0.0, 0.5), Vec3::new(0.7, 0.7, 0.5)]),
            single([o, z, Vec3::new(-1.0, 0.0, 0.5), Vec3::new(-0.7, -0.7, 0.5)]),
        ],
        &[],
    )
}

/// Two tetrahedra above and below the origin, sharing only it.
fn vertex_pair() -> TetMesh {
    let o = Vec3::zeros();
    merged(
        &[
            single([
                o,
                Vec3::new(1.0, 0.2, 1.0),
                Vec3::new(-0.5, 0.9, 1.0),
                Vec3::new(-0.5, -0.9, 1.0),
            ]),
            single([
                o,
                Vec3::new(1.0, -0.2, -1.0),
                Vec3::new(-0.5, -0.9, -1.0),
                Vec3::new(-0.5, 0.9, -1.0),
            ]),
        ],
        &[],
    )
}

/// Cubes [0, 1]^3 and [1, 2] x [1, 2] x [0, 1], `cells` per side, meeting along the edge
/// x = y = 1; plus one node no tetrahedron uses.
fn bowtie(cells: usize) -> TetMesh {
    let a = block(Vec3::zeros(), Vec3::repeat(1.0), [cells; 3]).unwrap();
    let b = block(
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(2.0, 2.0, 1.0),
        [cells; 3],
    )
    .unwrap();
    merged(&[a, b], &[Vec3::new(5.0, 5.0, 5.0)])
}

/// Whether `p` lies in some tetrahedron of `mesh` at node positions `x` (the answer the
/// surface's inside test must give).
fn inside(mesh: &TetMesh, x: &[Vec3], p: &Vec3) -> bool {
    mesh.tets().iter().any(|t| {
        let [a, b, c, d] = t.map(|i| x[i as usize]);
        let m = nalgebra::Matrix3::from_columns(&[b - a, c - a, d - a]);
        match m.try_inverse() {
            Some(inv) => {
                let l = inv * (p - a);
                l.iter().all(|&v| v >= 0.0) && l.sum() <= 1.0
            }
            None => false,
        }
    })
}

fn segment_distance(p: &Vec3, a: &Vec3, b: &Vec3) -> f64 {
    let ab = b - a;
    let s = ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
    (p - (a + ab * s)).norm()
}

/// Distance from `p` to a triangle: to its plane when the foot is inside, else to its edges.
fn triangle_distance(p: &Vec3, [a, b, c]: [Vec3; 3]) -> f64 {
    let n = (b - a).cross(&(c - a));
    let foot = p - n * ((p - a).dot(&n) / n.norm_squared());
    let inside_edge = |u: &Vec3, v: &Vec3| (v - u).cross(&(foot - u)).dot(&n) >= 0.0;
    if inside_edge(&a, &b) && inside_edge(&b, &c) && inside_edge(&c, &a) {
        return (p - foot).norm();
    }
    segment_distance(p, &a, &b)
        .min(segment_distance(p, &b, &c))
        .min(segment_distance(p, &c, &a))
}

/// A small deterministic generator (xorshift64*), uniform in [0, 1).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn point(&mut self, lo: Vec3, hi: Vec3) -> Vec3 {
        Vec3::new(
            lo.x + (hi.x - lo.x) * self.next(),
            lo.y + (hi.y - lo.y) * self.next(),
            lo.z + (hi.z - lo.z) * self.next(),
        )
    }
}

#[test]
fn non_manifold_surfaces_are_counted_and_paired() {
    let c = SurfaceCollider::new(&edge_pair()).unwrap();
    assert_eq!((c.non_manifold_edges(), c.non_manifold_vertices()), (1, 2));
    let c = SurfaceCollider::new(&vertex_pair()).unwrap();
    assert_eq!((c.non_manifold_edges(), c.non_manifold_vertices()), (0, 1));
    let c = SurfaceCollider::new(&bowtie(3)).unwrap();
    assert_eq!((c.non_manifold_edges(), c.non_manifold_vertices()), (3, 4));
    // Every triangle's partner across an edge shares that edge, reversed (same solid wedge
    // on a consistently oriented surface), and pairs are mutual.
    for mesh in [edge_pair(), vertex_pair(), bowtie(2)] {
        let c = SurfaceCollider::new(&mesh).unwrap();
        for (t, tri) in c.triangles().iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let p = c.neighbor(t, k) as usize;
                let other = c.triangles()[p];
                let kp = (0..3)
                    .find(|&j| other[j] == b && other[(j + 1) % 3] == a)
                    .unwrap_or_else(|| panic!("triangle {t} edge {k}: partner {p} lacks it"));
                assert_eq!(c.neighbor(p, kp) as usize, t);
            }
        }
    }
}

#[test]
fn the_inside_test_agrees_with_the_tetrahedra_near_non_manifold_features() {
    let cases = [
        (
            "edge pair",
            edge_pair(),
            Vec3::new(-0.4, -0.4, -0.2),
            Vec3::new(0.4, 0.4, 1.2),
        ),
        (
            "vertex pair",
            vertex_pair(),
            Vec3::repeat(-0.4),
            Vec3::repeat(0.4),
        ),
        (
            "bowtie",
            bowtie(2),
            Vec3::new(0.6, 0.6, -0.2),
            Vec3::new(1.4, 1.4, 1.2),
        ),
    ];
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    for (name, mesh, lo, hi) in cases {
        let c = SurfaceCollider::new(&mesh).unwrap();
        let mut checked = 0;
        for _ in 0..20_000 {
            let p = rng.point(lo, hi);
            let hit = c.closest(&p, 10.0).unwrap();
            if hit.distance.abs() < 1e-9 {
                continue;
            }
            let truth = inside(&mesh, mesh.positions(), &p);
            assert_eq!(
                hit.distance < 0.0,
                truth,
                "{name}: point {p:?} at signed distance {} (inside the tetrahedra: {truth})",
                hit.distance
            );
            checked += 1;
        }
        assert!(checked > 19_000, "{name}: {checked}");
    }
}

fn organ_settings(dt: f64, cage: CageKind, nodes: usize) -> BodySettings {
    let fem = FemParams {
        young_modulus: 140.0,
        poisson_ratio: 0.23,
        mass: 10.0,
        damping: 10.0,
    };
    let msd = MsdParams {
        stiffness: 50.0,
        mass: 10.0,
        damping: 0.3,
    };
    let mut s = BodySettings::new(fem, msd, dt);
    s.cage = cage;
    s.boundary = Boundary::anchored(nodes, 1.0);
    s
}

fn world_of(bodies: Vec<(&str, TetMesh)>, dt: f64) -> SoftTissueWorld {
    let mut w = SoftTissueWorld::new(WorldConfig {
        dt,
        contact: ContactConfig::for_scale(0.4),
    })
    .unwrap();
    for (name, mesh) in bodies {
        let s = organ_settings(dt, CageKind::BoundingBox, mesh.node_count());
        w.add_body(WorldBody::new(name, Arc::new(mesh), s, None).unwrap())
            .unwrap();
    }
    w
}

/// Tool centre at time `t` of a push along `dir` from `start`: in over 1 s, held 0.5 s, out
/// over 1 s.
fn push(start: Vec3, dir: Vec3, depth: f64, t: f64) -> Vec3 {
    let s = if t < 1.0 {
        t
    } else if t < 1.5 {
        1.0
    } else {
        (2.5 - t).max(0.0)
    };
    start + dir * (depth * s)
}

#[test]
fn a_bowtie_poked_into_its_pinch_rises_keeps_the_tool_out_and_returns() {
    let dt = 0.01;
    let mut w = world_of(vec![("bowtie", bowtie(3))], dt);
    let r = 0.15;
    let tool = w.add_tool(Tool::new("ball", ToolShape::Sphere { radius: r }).unwrap());
    // The notch x < 1 < y: the ball touches the two walls of the pinch at once.
    let dir = Vec3::new(1.0, -1.0, 0.0).normalize();
    let start = Vec3::new(1.0 - r, 1.0 + r, 0.5) - dir * 0.2;
    let mut raised = false;
    let mut deepest: f64 = 0.0;
    for k in 0..600 {
        let t = (k + 1) as f64 * dt;
        let c = push(start, dir, 0.3, t);
        w.tools_mut()[tool].set_position(c).unwrap();
        w.step_fixed().unwrap();
        let b = &w.bodies()[0];
        raised |= b.model().level() == Level::Precise;
        for p in b.collider().positions() {
            deepest = deepest.max(r - (p - c).norm());
        }
    }
    assert!(raised, "the poke did not raise the bowtie");
    // Tool contact moves vertices to the ball's surface and pushes triangles out: nothing
    // stays inside it by more than a percent of its radius.
    assert!(
        deepest < 0.01 * r,
        "a vertex stayed {deepest} inside the ball"
    );
    let b = &w.bodies()[0];
    assert_eq!(b.model().level(), Level::Cage, "did not return to its cage");
    assert_eq!(b.model().switch_count(), 2);
    let jump = b.model().last_switch().unwrap().jump_ratio;
    assert!(jump < 0.005, "down-switch jump {jump}");
}

#[test]
fn a_block_pressed_into_the_pinch_does_not_pass_through_it() {
    let dt = 0.01;
    let pinch = bowtie(3);
    let cube = block(
        Vec3::new(0.45, 1.05, 0.3),
        Vec3::new(0.95, 1.55, 0.7),
        [3, 3, 3],
    )
    .unwrap();
    let size = 0.5;
    let mut w = world_of(vec![("bowtie", pinch.clone())], dt);
    // A stiff block on weak anchors: the push moves it as a whole into the pinch.
    let mut s = organ_settings(dt, CageKind::BoundingBox, cube.node_count());
    s.fem.young_modulus = 5000.0;
    s.boundary = Boundary::anchored(cube.node_count(), 0.05);
    w.add_body(WorldBody::new("block", Arc::new(cube), s, None).unwrap())
        .unwrap();
    let r = 0.15;
    let tool = w.add_tool(Tool::new("ball", ToolShape::Sphere { radius: r }).unwrap());
    // Pushes the block's far corner toward the pinch edge.
    let dir = Vec3::new(1.0, -1.0, 0.0).normalize();
    let start = Vec3::new(0.45, 1.55, 0.5) - dir * (r + 0.05);
    let mut deepest: f64 = 0.0;
    let mut raised = [false; 2];
    for k in 0..500 {
        let t = (k + 1) as f64 * dt;
        w.tools_mut()[tool]
            .set_position(push(start, dir, 0.3, t))
            .unwrap();
        w.step_fixed().unwrap();
        let x = w.bodies()[0].model().node_positions().to_vec();
        for (i, b) in w.bodies().iter().enumerate() {
            raised[i] |= b.model().level() == Level::Precise;
        }
        // Independent check: block vertices inside the bowtie's tetrahedra at their current
        // positions, and their distance to the bowtie's surface by brute force.
        let bowtie = w.bodies()[0].collider();
        for p in w.bodies()[1].collider().positions() {
            if inside(&pinch, &x, p) {
                let d = bowtie
                    .triangles()
                    .iter()
                    .map(|t| triangle_distance(p, t.map(|i| bowtie.positions()[i as usize])))
                    .fold(f64::INFINITY, f64::min);
                deepest = deepest.max(d);
            }
        }
    }
    assert_eq!(raised, [true, true], "the push did not reach the bowtie");
    // Pressed into the pinch, the block's vertices stay within 3 % of its size of the
    // bowtie's surface (1.5 % measured).
    assert!(
        deepest < 0.03 * size,
        "a block vertex went {deepest} into the bowtie"
    );
}

#[test]
fn cages_heat_and_levels_take_defective_meshes() {
    let mesh = bowtie(2);
    // Box and fitted cages embed every node, unused ones included, and switch without a jump.
    for cage in [CageKind::BoundingBox, CageKind::Fitted { vertices: 32 }] {
        let s = organ_settings(0.01, cage, mesh.node_count());
        let mut b = LeveledModel::new(&mesh, s).unwrap();
        let up = b.raise().unwrap().unwrap();
        assert!(up.jump_ratio < 1e-9, "{cage:?}: up jump {}", up.jump_ratio);
        for _ in 0..5 {
            b.step(false).unwrap();
        }
        let down = b.lower().unwrap().unwrap();
        assert!(
            down.jump_ratio < 1e-6,
            "{cage:?}: down jump {}",
            down.jump_ratio
        );
    }
    // Heat: the unused node has no conduction and keeps its temperature.
    let params = HeatParams::liver();
    let mut h = HeatField::new(&mesh, params, 0.01, &HeatBoundary::insulated()).unwrap();
    let unused = mesh.node_count() - 1;
    let pinch = mesh
        .positions()
        .iter()
        .position(|p| *p == Vec3::new(1.0, 1.0, 0.5))
        .unwrap();
    for _ in 0..50 {
        h.add_power(pinch, 5.0).unwrap();
        h.step().unwrap();
    }
    let t = h.temperatures();
    assert!(t.iter().all(|x| x.is_finite()));
    assert!(t[pinch] > params.initial_temperature);
    assert_eq!(t[unused], params.initial_temperature);
    // Insulated: the heat in the body is exactly the power times the time.
    let heat: f64 = t
        .iter()
        .zip(h.capacities())
        .map(|(t, c)| c * (t - params.initial_temperature))
        .sum();
    assert!(
        (heat - 5.0 * 50.0 * 0.01).abs() < 1e-9 * heat,
        "heat {heat} J"
    );
    // Several components: the edge and vertex pairs simulate under a tool too.
    for mesh in [edge_pair(), vertex_pair()] {
        let mut w = world_of(vec![("pair", mesh)], 0.01);
        let tool = w.add_tool(Tool::new("ball", ToolShape::Sphere { radius: 0.1 }).unwrap());
        for k in 0..300 {
            let t = (k + 1) as f64 * 0.01;
            let c = push(Vec3::new(0.45, 0.35, 1.2), -Vec3::z(), 0.45, t);
            w.tools_mut()[tool].set_position(c).unwrap();
            w.step_fixed().unwrap();
        }
        let b = &w.bodies()[0];
        assert!(b.model().switch_count() >= 1, "never touched");
        assert!(
            b.model()
                .node_positions()
                .iter()
                .all(|p| p.iter().all(|x| x.is_finite()))
        );
    }
}
