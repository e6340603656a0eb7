//! A rigid move of a body (a teleport, [`WorldBody::teleport`]) while it is deformed, moving
//! and heated: for every precise method, supports and the cage level, the moved body goes on
//! as the same body left in place does, seen through the move (positions moved, velocities
//! turned), and its temperatures are those of the body left in place. A move that only
//! turned the positions would leave the linear model's stiffness, the anchors and the cage's
//! rest where they were: ghost forces far above these tolerances.

use std::sync::Arc;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::cage::CageDynamics;
use soft_tissue_core::contact::ContactConfig;
use soft_tissue_core::heat::{HeatBoundary, HeatParams};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::io::read_tet_mesh;
use soft_tissue_core::precision::{BodySettings, Level, PreciseMethod};
use soft_tissue_core::scenario::{Anchor, CYLINDER_FEM, CYLINDER_MSD};
use soft_tissue_core::world::{SoftTissueWorld, WorldBody, WorldConfig};
use soft_tissue_core::{NodalModel, Vec3};

const DT: f64 = 0.02;

fn cylinder() -> Arc<TetMesh> {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/meshes/cylinder.vtk");
    Arc::new(read_tet_mesh(path).unwrap().mesh)
}

/// A heated cylinder of `method`, held by `boundary`, pinned to `level`.
fn body(
    mesh: &Arc<TetMesh>,
    method: PreciseMethod,
    boundary: Boundary,
    cage: CageDynamics,
    level: Level,
) -> WorldBody {
    let mut s = BodySettings::new(CYLINDER_FEM.params, CYLINDER_MSD.params, DT);
    s.precise = method;
    s.boundary = boundary;
    s.cage_dynamics = cage;
    let heat = Some((HeatParams::liver(), HeatBoundary::insulated()));
    let mut body = WorldBody::new("cylinder", mesh.clone(), s, heat).unwrap();
    body.model_mut().pin(Some(level)).unwrap();
    body
}

/// A world of `body` alone.
fn alone(body: WorldBody) -> SoftTissueWorld {
    let mut w = SoftTissueWorld::new(WorldConfig {
        dt: DT,
        contact: ContactConfig::for_scale(1.0),
    })
    .unwrap();
    w.add_body(body).unwrap();
    w
}

/// A world with one heated cylinder (see [`body`]).
fn world(
    mesh: &Arc<TetMesh>,
    method: PreciseMethod,
    boundary: Boundary,
    cage: CageDynamics,
    level: Level,
) -> SoftTissueWorld {
    alone(body(mesh, method, boundary, cage, level))
}

/// The move of the tests: a turn about a skew axis and a shift.
fn skew_move() -> Isometry3<f64> {
    let axis = Vector3::new(0.3, 1.0, -0.5).normalize();
    Isometry3::from_parts(
        Translation3::new(2.0, -1.0, 0.5),
        UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), 1.1),
    )
}

fn at(m: &Isometry3<f64>, p: &Vec3) -> Vec3 {
    m * nalgebra::Point3::from(*p) - nalgebra::Point3::origin()
}

/// Positions and velocities of the level the body is at (nodes, or cage vertices).
fn state(w: &SoftTissueWorld) -> (Vec<Vec3>, Vec<Vec3>) {
    let m = w.bodies()[0].model();
    match m.level() {
        Level::Precise => (
            m.precise().positions().to_vec(),
            m.precise().velocities().to_vec(),
        ),
        Level::Cage => (
            m.cage().cage_positions().to_vec(),
            m.cage().msd().velocities().to_vec(),
        ),
    }
}

/// Loads the same in both worlds (`m` turns the moved world's): a push on the top nodes for
/// the first steps, heat into one node.
fn load(w: &mut SoftTissueWorld, step: usize, top: &[usize], m: Option<&Isometry3<f64>>) {
    let b = &mut w.bodies_mut()[0];
    if step < 12 {
        for &i in top {
            let f = Vec3::new(6.0, 0.0, 2.0);
            let f = m.map_or(f, |m| m.rotation * f);
            b.model_mut().add_force(i, f).unwrap();
        }
    }
    b.heat_mut().unwrap().add_power(top[0], 40.0).unwrap();
}

/// Steps both worlds, moves the second by `m` after `before` steps, and checks after every
/// later step that it is the first moved: returns the largest position gap as a fraction of
/// the first's largest deformation (distance from its rest shape).
fn moved_follows(
    method: PreciseMethod,
    boundary: Boundary,
    cage: CageDynamics,
    level: Level,
    m: &Isometry3<f64>,
) -> f64 {
    let mesh = cylinder();
    let hi = mesh.bbox().max.y;
    let top: Vec<usize> = (0..mesh.node_count())
        .filter(|&i| mesh.positions()[i].y > hi - 0.1)
        .collect();
    let mut a = world(&mesh, method, boundary.clone(), cage, level);
    let mut b = world(&mesh, method, boundary, cage, level);
    let before = 10;
    let mut worst: f64 = 0.0;
    let mut deformed: f64 = 0.0;
    for step in 0..30 {
        if step == before {
            let (x0, _) = state(&b);
            b.bodies_mut()[0].teleport(*m).unwrap();
            let (x1, _) = state(&b);
            // The move itself is rigid: every node where the move puts it.
            for (p, q) in x0.iter().zip(&x1) {
                assert!((at(m, p) - q).norm() < 1e-12, "{method:?}: {p} -> {q}");
            }
            assert_eq!(b.bodies()[0].frame(), m);
        }
        let moved = (step >= before).then_some(m);
        load(&mut a, step, &top, None);
        load(&mut b, step, &top, moved);
        a.step_fixed().unwrap();
        b.step_fixed().unwrap();
        let (ba, bb) = (&a.bodies()[0], &b.bodies()[0]);
        assert_eq!(ba.model().level(), level);
        assert_eq!(bb.model().level(), level);
        // Heat lives on the mesh, not where the body is: the same field, to the bit.
        let (ta, tb) = (ba.heat().unwrap(), bb.heat().unwrap());
        assert_eq!(
            ta.temperatures(),
            tb.temperatures(),
            "{method:?} step {step}"
        );
        assert_eq!(ta.damage(), tb.damage());
        let rest = ba.mesh().positions();
        let xa = ba.model().node_positions();
        deformed = xa
            .iter()
            .zip(rest)
            .map(|(p, r)| (p - r).norm())
            .fold(deformed, f64::max);
        if step < before {
            continue;
        }
        let ((xa, va), (xb, vb)) = (state(&a), state(&b));
        for ((pa, pb), (ua, ub)) in xa.iter().zip(&xb).zip(va.iter().zip(&vb)) {
            worst = worst.max((at(m, pa) - pb).norm());
            worst = worst.max((m.rotation * ua - ub).norm() * DT);
        }
    }
    assert!(
        deformed > 1e-3,
        "{method:?}: the push deformed the body ({deformed})"
    );
    worst / deformed
}

const PRECISE: [PreciseMethod; 6] = [
    PreciseMethod::LinearFem,
    PreciseMethod::CorotationalFem,
    PreciseMethod::PrefactoredFem,
    PreciseMethod::MsdImplicit,
    PreciseMethod::MsdSymplectic,
    PreciseMethod::MsdBdf2,
];

#[test]
fn a_moved_body_goes_on_as_the_body_left_in_place_for_every_method_and_support() {
    let mesh = cylinder();
    let supports = [
        ("free", Anchor::Free.boundary(&mesh)),
        (
            "soft anchors",
            Anchor::SoftToRest { stiffness: 40.0 }.boundary(&mesh),
        ),
        (
            "fixed bottom",
            Anchor::FixedBottom { fraction: 0.1 }.boundary(&mesh),
        ),
    ];
    let m = skew_move();
    for method in PRECISE {
        for (name, boundary) in &supports {
            let gap = moved_follows(
                method,
                boundary.clone(),
                CageDynamics::Calibrated,
                Level::Precise,
                &m,
            );
            // Every operator turned with the body: the same steps to rounding (iterative
            // solves included: they see the same system, turned).
            assert!(
                gap < 1e-9,
                "{method:?}, {name}: the moved body is {gap} of its deformation off"
            );
        }
    }
}

#[test]
fn a_moved_cage_goes_on_as_the_cage_left_in_place() {
    let mesh = cylinder();
    let m = skew_move();
    for cage in [CageDynamics::Calibrated, CageDynamics::Paper] {
        for anchor in [Anchor::Free, Anchor::SoftToRest { stiffness: 40.0 }] {
            let gap = moved_follows(
                PreciseMethod::CorotationalFem,
                anchor.boundary(&mesh),
                cage,
                Level::Cage,
                &m,
            );
            assert!(
                gap < 1e-9,
                "{cage:?}, {anchor:?}: {gap} of the deformation off"
            );
        }
    }
}

#[test]
fn a_shift_builds_nothing_and_keeps_the_body_to_rounding() {
    let mesh = cylinder();
    let shift = Isometry3::translation(-3.0, 0.25, 7.0);
    for method in PRECISE {
        let gap = moved_follows(
            method,
            Anchor::SoftToRest { stiffness: 40.0 }.boundary(&mesh),
            CageDynamics::Calibrated,
            Level::Precise,
            &shift,
        );
        assert!(gap < 1e-9, "{method:?}: {gap} of the deformation off");
    }
}

#[test]
fn a_turn_of_nodes_held_along_one_axis_is_refused_and_changes_nothing() {
    let mesh = cylinder();
    let boundary = Boundary {
        fixed: vec![(0, [true, false, false])],
        anchors: Vec::new(),
    };
    let mut w = world(
        &mesh,
        PreciseMethod::CorotationalFem,
        boundary,
        CageDynamics::Calibrated,
        Level::Precise,
    );
    let before = state(&w);
    let err = w.bodies_mut()[0].teleport(skew_move()).unwrap_err();
    assert!(err.to_string().contains("node 0"), "{err}");
    assert_eq!(state(&w), before);
    assert_eq!(w.bodies()[0].frame(), &Isometry3::identity());
    // A shift keeps the held axis's meaning: allowed.
    w.bodies_mut()[0]
        .teleport(Isometry3::translation(1.0, 0.0, 0.0))
        .unwrap();
    assert!((state(&w).0[0] - before.0[0] - Vec3::x()).norm() < 1e-12);
}

/// A moved body cut through: the kept part and the loose piece are built in the mesh's
/// coordinates with the state where the body is, and `carry_frame` gives them the body's
/// frame, so their rests are where they are. Each part is then the part of the same cut of
/// the body left in place, seen through the move, and steps on as it does: an anchored part
/// whose anchors stayed behind would be pulled back across the move.
#[test]
fn the_parts_of_a_moved_body_cut_through_go_on_where_they_are() {
    use soft_tissue_core::mesh::cut::{CutOptions, CutTriangle};
    let mesh = cylinder();
    let m = skew_move();
    // A slanted plane across the cylinder's axis (z), in the mesh's coordinates.
    let (lo, hi) = (mesh.bbox().min, mesh.bbox().max);
    let z = 0.5 * (lo.z + hi.z);
    let corner = |x: f64, y: f64| Vec3::new(x, y, z + 0.1 * x);
    let (a, b) = (2.0 * lo - hi, 2.0 * hi - lo);
    let quad = [
        corner(a.x, a.y),
        corner(b.x, a.y),
        corner(b.x, b.y),
        corner(a.x, b.y),
    ];
    let blade = |mv: &Isometry3<f64>| {
        let q = quad.map(|p| at(mv, &p));
        [
            CutTriangle {
                corners: [q[0], q[1], q[2]],
            },
            CutTriangle {
                corners: [q[0], q[2], q[3]],
            },
        ]
    };
    let options = CutOptions {
        background_steps: 0,
        ..CutOptions::default()
    };
    let anchored = Anchor::SoftToRest { stiffness: 40.0 }.boundary(&mesh);
    // A temperature field that varies over the mesh's coordinates.
    let warm = |p: &Vec3| 37.0 + 20.0 * p.x - 10.0 * p.y + 5.0 * p.z;
    // Each part in a world of its own: the cut faces of two parts in one world touch, and a
    // contact solve's order follows the world's axes.
    let parts = |mv: Isometry3<f64>| -> Vec<SoftTissueWorld> {
        let mut b = body(
            &mesh,
            PreciseMethod::LinearFem,
            anchored.clone(),
            CageDynamics::Calibrated,
            Level::Precise,
        );
        b.model_mut().pin(None).unwrap();
        let rest = b.mesh().positions().to_vec();
        b.heat_mut()
            .unwrap()
            .set_temperatures(|i| warm(&rest[i]))
            .unwrap();
        b.teleport(mv).unwrap();
        let mut cut = b.cut(&blade(&mv), &options).unwrap().expect("cut through");
        b.carry_frame(&mut cut).unwrap();
        std::iter::once(b).chain(cut.pieces).map(alone).collect()
    };
    let mut still = parts(Isometry3::identity());
    let mut moved = parts(m);
    assert!(moved.len() > 1, "the cut made a loose piece");
    assert_eq!(still.len(), moved.len());
    for step in 0..20 {
        for (wa, wb) in still.iter_mut().zip(&mut moved) {
            let (a, b) = (&wa.bodies()[0], &wb.bodies()[0]);
            assert_eq!(b.frame(), &m);
            // The rest is where the state is: the mesh moved by the frame.
            let rest = b.rest_mesh().unwrap();
            let off = rest
                .positions()
                .iter()
                .zip(b.model().precise().rest_positions())
                .map(|(p, q)| (p - q).norm())
                .fold(0.0, f64::max);
            assert!(off < 1e-12, "{}: rest {off} from the moved mesh", b.name());
            let gap = a
                .model()
                .node_positions()
                .iter()
                .zip(b.model().node_positions())
                .map(|(p, q)| (at(&m, p) - q).norm())
                .fold(0.0, f64::max);
            assert!(gap < 1e-9, "step {step}, {}: {gap} off", b.name());
            // Heat is on the mesh's coordinates: the field the body had there, then the same
            // as the part left in place (the cut weighs new nodes from the shape where each
            // body is: the same weights to rounding).
            let (ha, hb) = (a.heat().unwrap(), b.heat().unwrap());
            for ((ta, tb), p) in ha
                .temperatures()
                .iter()
                .zip(hb.temperatures())
                .zip(b.mesh().positions())
            {
                assert!(
                    (ta - tb).abs() < 1e-9,
                    "step {step}, {}: {ta} against {tb} C",
                    b.name()
                );
                if step == 0 {
                    assert!((tb - warm(p)).abs() < 1e-6, "{}: {tb} C at {p}", b.name());
                }
            }
            wa.step_fixed().unwrap();
            wb.step_fixed().unwrap();
        }
    }
}

/// A moved body of a world cut there (`SoftTissueWorld::cut_body`): the world gives the kept
/// body and the loose piece the body's frame, so each one's rest is the mesh moved by it
/// (where its state is), not the mesh where the body was built.
#[test]
fn a_world_cutting_a_moved_body_gives_its_parts_its_frame() {
    use soft_tissue_core::mesh::cut::CutTriangle;
    let mesh = cylinder();
    let m = skew_move();
    let mut w = world(
        &mesh,
        PreciseMethod::CorotationalFem,
        Anchor::SoftToRest { stiffness: 40.0 }.boundary(&mesh),
        CageDynamics::Calibrated,
        Level::Precise,
    );
    w.bodies_mut()[0].teleport(m).unwrap();
    // A plane across the axis (z) half-way, in the mesh's coordinates, where the body is now.
    let (lo, hi) = (mesh.bbox().min, mesh.bbox().max);
    let z = 0.5 * (lo.z + hi.z);
    let (a, b) = (2.0 * lo - hi, 2.0 * hi - lo);
    let q =
        [(a.x, a.y), (b.x, a.y), (b.x, b.y), (a.x, b.y)].map(|(x, y)| at(&m, &Vec3::new(x, y, z)));
    let blade = [
        CutTriangle {
            corners: [q[0], q[1], q[2]],
        },
        CutTriangle {
            corners: [q[0], q[2], q[3]],
        },
    ];
    let made = w.cut_body(0, &blade).unwrap();
    assert_eq!(made.len(), 1, "one loose piece");
    for b in w.bodies() {
        assert_eq!(b.frame(), &m, "{}", b.name());
        let rest = b.rest_mesh().unwrap();
        let off = rest
            .positions()
            .iter()
            .zip(b.model().precise().rest_positions())
            .map(|(p, q)| (p - q).norm())
            .fold(0.0, f64::max);
        assert!(off < 1e-12, "{}: rest {off} from the moved mesh", b.name());
    }
}
