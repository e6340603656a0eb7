//! Contact inside the implicit step: the bodies' compliances against their own corrections,
//! Coulomb friction on an incline against the closed form, the balance of forces at rest.

use std::f64::consts::PI;
use std::path::Path;
use std::sync::Arc;

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion};
use soft_tissue_core::Vec3;
use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::contact::{ContactConfig, Friction, Obstacle, RigidShape, Tool, ToolShape};
use soft_tissue_core::material::{FemParams, MsdParams};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::generate::block;
use soft_tissue_core::precision::{BodySettings, Level, LeveledBody, PreciseMethod};
use soft_tissue_core::scenario::{Anchor, Scene};
use soft_tissue_core::state::NodalBody;
use soft_tissue_core::world::{SimBody, SoftTissueWorld, WorldConfig};

fn assets() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"))
}

/// A block body of 0.2 x 0.1 x 0.2 with `method`, free, at the precise level, no gravity.
fn block_body(method: PreciseMethod) -> (TetMesh, LeveledBody) {
    let mesh = block(Vec3::zeros(), Vec3::new(0.2, 0.1, 0.2), [4, 2, 4]).unwrap();
    let fem = FemParams {
        young_modulus: 2e4,
        poisson_ratio: 0.3,
        mass: 2.0,
        damping: 0.0,
    };
    let msd = MsdParams {
        stiffness: 500.0,
        mass: 2.0,
        damping: 0.1,
    };
    let mut s = BodySettings::new(fem, msd, 0.01);
    s.precise = method;
    s.boundary = Boundary::free();
    let mut b = LeveledBody::new(&mesh, s).unwrap();
    b.pin(Some(Level::Precise)).unwrap();
    (mesh, b)
}

/// Every precise method and the cage level: after a free step, the displacement the
/// compliance blocks predict for forces on three surface nodes is the one the correction
/// makes. Exact for the models whose step matrix is the factored one (linear and prefactored
/// FEM, the explicit MSD, the cage) and for the implicit MSD at rest; the corotational
/// model's warped rest compliance against its solve of the warped system on a body turned
/// by 60 degrees (exact for a rigid turn, to the solve's tolerance).
#[test]
fn compliances_predict_the_corrections() {
    let cases = [
        (PreciseMethod::LinearFem, 1e-9, false),
        (PreciseMethod::CorotationalFem, 1e-3, true),
        (PreciseMethod::PrefactoredFem, 1e-9, true),
        (PreciseMethod::MsdImplicit, 1e-6, false),
        (PreciseMethod::MsdSymplectic, 1e-12, false),
    ];
    for (method, tolerance, turn) in cases {
        for level in [Level::Precise, Level::Cage] {
            if level == Level::Cage && method != PreciseMethod::CorotationalFem {
                continue;
            }
            let (_, mut b) = block_body(method);
            if turn && level == Level::Precise {
                // Turn the whole body (through its cage, so the precise level takes the
                // turned state with its element rotations): the warped compliance must
                // follow.
                b.pin(Some(Level::Cage)).unwrap();
                let r = Rotation3::from_axis_angle(&Vec3::z_axis(), PI / 3.0);
                let x: Vec<Vec3> = b.cage().cage_positions().iter().map(|p| r * p).collect();
                b.cage_mut().msd_mut().positions_mut().copy_from_slice(&x);
                b.cage_mut().update_points().unwrap();
                b.pin(Some(Level::Precise)).unwrap();
            }
            if level == Level::Cage {
                b.pin(Some(Level::Cage)).unwrap();
            }
            // A few steps: the corotational model refreshes the warped stiffness of a quarter
            // of its turned elements a step, and its correction solves that matrix.
            for _ in 0..8 {
                b.step(false).unwrap();
            }
            let s = b.surface_vertices();
            let nodes = [s[0], s[s.len() / 2], s[s.len() - 1]];
            let forces = [
                Vec3::new(1.0, -2.0, 0.5),
                Vec3::new(-0.5, 1.0, 2.0),
                Vec3::new(0.3, 0.2, -1.0),
            ];
            let mut c = vec![Matrix3::zeros(); 9];
            b.contact_compliance(&nodes, &mut c).unwrap();
            let before: Vec<Vec3> = nodes
                .iter()
                .map(|&k| b.node_positions()[k as usize])
                .collect();
            let pairs: Vec<(u32, Vec3)> = nodes.iter().copied().zip(forces).collect();
            b.apply_contact_forces(&pairs).unwrap();
            let mut worst: f64 = 0.0;
            let mut scale: f64 = 0.0;
            for i in 0..3 {
                let predicted: Vec3 = (0..3).map(|j| c[i * 3 + j] * forces[j]).sum();
                let moved = b.node_positions()[nodes[i] as usize] - before[i];
                worst = worst.max((predicted - moved).norm());
                scale = scale.max(moved.norm());
            }
            assert!(scale > 0.0, "{method:?} {level:?}: nothing moved");
            eprintln!("{method:?} {level:?} {:.3e}", worst / scale);
            assert!(
                worst <= tolerance * scale,
                "{method:?} at {level:?}: prediction off by {:.3e} of {scale:.3e}",
                worst / scale
            );
        }
    }
}

/// A stiff block on a rigid incline under gravity, both surfaces with friction `mu`: where
/// its centroid is along the slope, every step for `seconds`.
fn slide(angle_deg: f64, mu: f64, seconds: f64) -> (Vec<f64>, f64, f64) {
    let theta = angle_deg.to_radians();
    let size = 0.2;
    let base = block(Vec3::zeros(), Vec3::new(size, 0.1, size), [4, 2, 4]).unwrap();
    // The block turned with the slope and set on it (a hair above: the contact skin).
    let turn = Rotation3::from_axis_angle(&Vec3::z_axis(), theta);
    let config = WorldConfig {
        dt: 0.005,
        contact: ContactConfig::for_scale(size),
    };
    let lift = config.contact.thickness * 1.01;
    let positions: Vec<Vec3> = base
        .positions()
        .iter()
        .map(|p| turn * (p + Vec3::new(-0.5 * size, lift, -0.5 * size)))
        .collect();
    let tets = base.tets().iter().map(|t| t.map(|i| i as usize)).collect();
    let mesh = TetMesh::new(positions, tets).unwrap();
    let fem = FemParams {
        young_modulus: 1e5,
        poisson_ratio: 0.3,
        mass: 2.0,
        damping: 0.0,
    };
    let mut s = BodySettings::new(fem, soft_tissue_core::material::PAPER_CAGE_MSD, config.dt);
    s.gravity = Vec3::new(0.0, -9.81, 0.0);
    s.policy.min_precise_steps = u32::MAX;
    let mut world = SoftTissueWorld::new(config).unwrap();
    let mut body = SimBody::new("block", Arc::new(mesh), s, None).unwrap();
    body.set_friction(Friction::new(mu)).unwrap();
    world.add_body(body).unwrap();
    let slope = Isometry3::from_parts(
        Translation3::identity(),
        UnitQuaternion::from_axis_angle(&Vec3::z_axis(), theta),
    );
    world
        .add_obstacle(Obstacle::new("incline", RigidShape::Plane, slope, Friction::new(mu)).unwrap())
        .unwrap();
    // Down the slope: the plane's x axis, turned (gravity's component along it is g sin).
    let down = -(turn * Vec3::x());
    let centroid = |w: &SoftTissueWorld| -> f64 {
        let x = w.bodies()[0].body().node_positions();
        x.iter().sum::<Vec3>().dot(&down) / x.len() as f64
    };
    let steps = (seconds / config.dt).round() as usize;
    let mut track = Vec::with_capacity(steps + 1);
    track.push(centroid(&world));
    let mut worst_penetration: f64 = 0.0;
    for _ in 0..steps {
        world.step_fixed().unwrap();
        assert_eq!(world.bodies()[0].body().level(), Level::Precise);
        worst_penetration = worst_penetration.max(world.bodies()[0].diagnostics().max_penetration);
        track.push(centroid(&world));
    }
    (track, config.dt, worst_penetration)
}

/// Least-squares acceleration of `s(t)` over samples `from..` (a parabola fit).
fn acceleration(track: &[f64], dt: f64, from: usize) -> f64 {
    let pts: Vec<(f64, f64)> = track[from..]
        .iter()
        .enumerate()
        .map(|(k, s)| (k as f64 * dt, *s))
        .collect();
    // Normal equations of s = c0 + c1 t + c2 t^2.
    let mut a = nalgebra::Matrix3::<f64>::zeros();
    let mut b = Vec3::zeros();
    for (t, s) in &pts {
        let phi = Vec3::new(1.0, *t, t * t);
        a += phi * phi.transpose();
        b += phi * *s;
    }
    let c = a.lu().solve(&b).unwrap();
    2.0 * c.z
}

/// Coulomb's incline (closed form): set on the incline, the block sticks for tan(angle) <
/// mu (once it has settled, half a second, its centroid drifts by at most 1e-3 of its size
/// over 2 s) and slides with g (sin - mu cos) within 3 %
/// for tan(angle) > mu, at three angles and two friction coefficients; nothing penetrates
/// the incline by more than 1e-3 of the block's smallest dimension.
#[test]
fn a_block_on_an_incline_sticks_or_slides_as_coulomb_says() {
    let g = 9.81;
    for mu in [0.3, 0.6] {
        for angle in [15.0f64, 25.0, 35.0] {
            // Half a second to settle on the incline, then two seconds measured.
            let (track, dt, penetration) = slide(angle, mu, 2.5);
            assert!(
                penetration <= 1e-3 * 0.1,
                "angle {angle}, mu {mu}: penetration {penetration:.3e}"
            );
            let theta = angle.to_radians();
            if theta.tan() < mu {
                let settled = (0.5 / dt) as usize;
                let drift = track[settled..]
                    .iter()
                    .map(|s| (s - track[settled]).abs())
                    .fold(0.0, f64::max);
                assert!(
                    drift <= 1e-3 * 0.2,
                    "angle {angle}, mu {mu}: sticks but drifted {drift:.3e}"
                );
            } else {
                let a = acceleration(&track, dt, (0.5 / dt) as usize);
                let expected = g * (theta.sin() - mu * theta.cos());
                assert!(
                    (a - expected).abs() <= 0.03 * expected,
                    "angle {angle}, mu {mu}: slides at {a:.4} against {expected:.4}"
                );
            }
        }
    }
}

/// Newton's third law at rest: a sphere held pressed into the anchored liver; once nothing
/// moves, the force on the tool (the sum of its contact forces) is the anchors' reaction
/// within 1 %.
#[test]
fn the_tool_force_balances_the_anchors_at_rest() {
    let scene = Scene::paper_organs();
    let mut scene = scene;
    scene.bodies.retain(|b| b.name == "Liver");
    assert_eq!(scene.bodies[0].anchor, Anchor::SoftToRest { stiffness: 1.0 });
    let mut world = SoftTissueWorld::from_scene(&scene, assets()).unwrap();
    let script = soft_tissue_core::world::Script::builtin("poke-liver", &world);
    // No other organ: place the ball on the liver's top by hand.
    assert!(script.is_err());
    let (lo, hi) = world.bodies()[0].collider().bounds();
    let small = (hi - lo).min();
    let r = 0.1 * small;
    let centre = (lo + hi) / 2.0;
    let top = world.bodies()[0]
        .collider()
        .positions()
        .iter()
        .filter(|p| (p.xz() - centre.xz()).norm() < 0.15 * small)
        .map(|p| p.y)
        .fold(f64::NEG_INFINITY, f64::max);
    let tool = world
        .add_tool(Tool::new("ball", ToolShape::Sphere { radius: r }).unwrap());
    let start = Vec3::new(centre.x, top + r + 0.05 * small, centre.z);
    let pressed = Vec3::new(centre.x, top + r - 0.25 * small, centre.z);
    let dt = world.config().dt;
    for k in 0..3000 {
        let t = (k + 1) as f64 * dt;
        let s = (t / 1.0).min(1.0);
        world.tools_mut()[tool]
            .set_position(start * (1.0 - s) + pressed * s)
            .unwrap();
        world.step_fixed().unwrap();
    }
    let b = world.bodies()[0].body();
    assert_eq!(b.level(), Level::Precise, "still pressed: precise");
    assert!(
        b.precise().max_speed() < 1e-6 * small,
        "at rest: {}",
        b.precise().max_speed()
    );
    let tool_force = world.tools()[tool].reaction_force();
    let anchors = b.precise().anchor_force();
    assert!(tool_force.norm() > 0.0);
    let off = (tool_force - anchors).norm() / tool_force.norm();
    assert!(
        off <= 0.01,
        "tool {tool_force:?} against anchors {anchors:?}: {:.3} %",
        100.0 * off
    );
}
