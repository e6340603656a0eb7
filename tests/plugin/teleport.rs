//! Moving a body's entity (its own `Transform` or a parent's) moves the whole body rigidly:
//! a deformed, moving, heated body keeps its shape in its own frame, its temperatures and
//! damage, and its velocities turned with it, and is not built again at rest.

use super::*;
use bevy_soft_tissue::core::Vec3 as CoreVec3;
use bevy_soft_tissue::core::world::WorldBody;

/// A cylinder with a heat field under a parent at `parent`, pinned to its precise level.
fn spawn_heated(app: &mut App, mesh: &Handle<TetMeshAsset>, parent: Transform) -> Entity {
    let root = app.world_mut().spawn(parent).id();
    app.world_mut()
        .spawn((
            SoftBody::new(mesh.clone()),
            TissueHeat::default(),
            PinnedLevel(Level::Precise),
            Transform::from_xyz(0.3, -0.2, 0.1),
            ChildOf(root),
        ))
        .id()
}

fn state(app: &App, e: Entity) -> &WorldBody {
    app.world()
        .get::<SoftBodyState>(e)
        .expect("the body has its state (it was not removed to be built again)")
        .body()
}

/// Pushes nodes `nodes` of `e` sideways in a frame turned by `turn` (the body's own frame
/// when `turn` is its orientation) and heats the first of them, for the next step.
fn load(app: &mut App, e: Entity, nodes: &[usize], turn: Quat) {
    let f = bevy_soft_tissue::convert::to_core(turn * Vec3::new(4.0, 0.0, 1.5));
    let mut sim = app.world_mut().get_mut::<SoftBodyState>(e).unwrap();
    let b = sim.body_mut();
    for &i in nodes {
        b.model_mut().add_force(i, f).unwrap();
    }
    b.heat_mut().unwrap().add_power(nodes[0], 400.0).unwrap();
}

/// The distance of every node from each of a few others: what a rigid motion keeps.
fn distances(p: &[CoreVec3]) -> Vec<f64> {
    let anchors = [0, p.len() / 3, 2 * p.len() / 3, p.len() - 1];
    p.iter()
        .flat_map(|q| anchors.iter().map(move |&a| (q - p[a]).norm()))
        .collect()
}

/// Two identical heated cylinders, each under a parent, pushed and heated the same way; then
/// one parent moves and turns while the other stays. After the move, and the steps that
/// follow with the loads going on in each body's own frame, the moved body is the body left
/// in place seen through the move: the same distances between its nodes (its shape), the
/// same surface drawn in its own frame, its velocities turned by the parent's turn, the
/// very same temperatures and damage; and it was not built again.
#[test]
fn a_deformed_heated_body_keeps_its_shape_and_temperatures_when_its_parent_moves() {
    let mut app = app(0.01);
    let mesh = cylinder_asset(&mut app);
    let start = Transform::from_xyz(-2.0, 1.0, 0.0).with_rotation(Quat::from_rotation_y(0.4));
    let still = spawn_heated(&mut app, &mesh, start);
    let moved = spawn_heated(&mut app, &mesh, start);
    app.update();
    let root = app.world().get::<ChildOf>(moved).unwrap().parent();
    // The nodes on top of the cylinder, in its own frame.
    let file = state(&app, moved).mesh().clone();
    let hi = file.bbox().max.y;
    let top: Vec<usize> = (0..file.node_count())
        .filter(|&i| file.positions()[i].y > hi - 0.15)
        .collect();
    for _ in 0..15 {
        for e in [still, moved] {
            load(&mut app, e, &top, start.rotation);
        }
        app.update();
    }
    let id = state(&app, moved).id();
    let deformation = state(&app, moved).diagnostics().max_displacement;
    assert!(
        deformation > 0.01,
        "the push deformed the body ({deformation})"
    );
    let hot = state(&app, moved).heat().unwrap().temperatures()[top[0]];
    assert!(hot > 38.0, "the power heated the body ({hot} C)");

    // The parent moves and turns; the other stays.
    let turn = Quat::from_axis_angle(Vec3::new(1.0, 2.0, -0.5).normalize(), 1.2);
    {
        let mut t = app.world_mut().get_mut::<Transform>(root).unwrap();
        t.translation += Vec3::new(1.5, -0.5, 3.0);
        t.rotation = turn * t.rotation;
    }
    for k in 0..5 {
        // Pushed on for two more steps in each body's own frame: loads given before the
        // move turn with the body.
        if k < 2 {
            load(&mut app, still, &top, start.rotation);
            let r = if k == 0 { Quat::IDENTITY } else { turn };
            load(&mut app, moved, &top, r * start.rotation);
        }
        app.update();
        let (a, b) = (state(&app, still), state(&app, moved));
        assert_eq!(b.id(), id, "step {k}: the moved body was built again");
        assert_eq!(b.model().level(), Level::Precise);
        // Its shape: every distance between nodes, to the rounding of the turn.
        let (da, db) = (
            distances(a.model().node_positions()),
            distances(b.model().node_positions()),
        );
        let off = da
            .iter()
            .zip(&db)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(
            off < 1e-5 * deformation,
            "step {k}: node distances {off} apart (deformation {deformation})"
        );
        // Its motion, turned with it (the turn as the plugin reads it from `f32`
        // transforms).
        let (va, vb) = (
            a.model().precise().velocities(),
            b.model().precise().velocities(),
        );
        let vmax = va.iter().map(|v| v.norm()).fold(0.0, f64::max);
        assert!(vmax > 1e-3, "the body still moves ({vmax})");
        let r = bevy_soft_tissue::convert::to_core_rotation(turn);
        let voff = va
            .iter()
            .zip(vb)
            .map(|(u, w)| (r * u - w).norm())
            .fold(0.0, f64::max);
        assert!(
            voff < 1e-5 * vmax,
            "step {k}: velocities {voff} off ({vmax})"
        );
        // Its heat, to the bit: temperatures and damage live on the mesh.
        let (ha, hb) = (a.heat().unwrap(), b.heat().unwrap());
        assert_eq!(ha.temperatures(), hb.temperatures(), "step {k}");
        assert_eq!(ha.damage(), hb.damage(), "step {k}");
        let (ta, tb) = (
            app.world().get::<Temperature>(still).unwrap(),
            app.world().get::<Temperature>(moved).unwrap(),
        );
        assert_eq!((&ta.surface, ta.max), (&tb.surface, tb.max));
    }
    // The drawn surfaces, each in its entity's own frame, are the same.
    let (ma, mb) = (
        app.world().get::<Mesh3d>(still).unwrap().0.clone(),
        app.world().get::<Mesh3d>(moved).unwrap().0.clone(),
    );
    let off = positions(&app, &ma)
        .iter()
        .zip(positions(&app, &mb))
        .map(|(p, q)| Vec3::from_array(*p).distance(Vec3::from_array(q)))
        .fold(0.0, f32::max);
    assert!(
        off < 1e-4,
        "the drawn surfaces are {off} apart in their own frames"
    );
    // And the moved one is where its parent took it.
    let centre = |app: &App, e| {
        let p = state(app, e).model().node_positions();
        bevy_soft_tissue::convert::to_bevy(&(p.iter().sum::<CoreVec3>() / p.len() as f64))
    };
    let mut q = app.world_mut().query::<&GlobalTransform>();
    let (ga, gb) = (
        *q.get(app.world(), still).unwrap(),
        *q.get(app.world(), moved).unwrap(),
    );
    let want = (gb.affine() * ga.affine().inverse()).transform_point3(centre(&app, still));
    let got = centre(&app, moved);
    assert!(want.distance(got) < 1e-4, "centre {got}, expected {want}");
}

/// What moving a body did before: it was built again at rest at its new pose (a new body,
/// its deformation, motion and heat gone). Now a move of its own `Transform` keeps them; a
/// change of its scale, which is not a rigid move, still builds it again at rest.
#[test]
fn moving_a_body_no_longer_builds_it_again_at_rest() {
    let mut app = app(0.01);
    let mesh = cylinder_asset(&mut app);
    let e = app
        .world_mut()
        .spawn((
            SoftBody::new(mesh),
            TissueHeat::default(),
            Transform::default(),
        ))
        .id();
    app.update();
    let n = state(&app, e).mesh().node_count();
    // Asleep at its cage, turned and moved: the cage component (world coordinates) follows.
    let id = state(&app, e).id();
    *app.world_mut().get_mut::<Transform>(e).unwrap() =
        Transform::from_xyz(1.0, 0.0, -1.0).with_rotation(Quat::from_rotation_z(0.7));
    app.update();
    assert_eq!(state(&app, e).id(), id, "built again");
    assert!(state(&app, e).model().is_asleep());
    let cage = app.world().get::<GreenCage>(e).unwrap();
    let core = state(&app, e).model().cage().cage_positions();
    assert_eq!(cage.vertices.len(), core.len());
    for (v, c) in cage.vertices.iter().zip(core) {
        assert!(
            v.distance(bevy_soft_tissue::convert::to_bevy(c)) < 1e-5,
            "{v} {c}"
        );
    }
    let drawn = app.world().get::<Mesh3d>(e).unwrap().0.clone();
    let rest = state(&app, e).mesh().clone();
    let off = positions(&app, &drawn)
        .iter()
        .zip(state(&app, e).surface_nodes())
        .map(|(p, &i)| {
            Vec3::from_array(*p).distance(bevy_soft_tissue::convert::to_bevy(
                &rest.positions()[i as usize],
            ))
        })
        .fold(0.0, f32::max);
    assert!(off < 1e-4, "drawn {off} from the mesh in its own frame");
    *app.world_mut().get_mut::<Transform>(e).unwrap() = Transform::default();
    app.update();
    // Pinned up and pushed: deformed and moving; heated.
    app.world_mut()
        .entity_mut(e)
        .insert(PinnedLevel(Level::Precise));
    for _ in 0..10 {
        load(&mut app, e, &[0, n / 2], Quat::IDENTITY);
        app.update();
    }
    let id = state(&app, e).id();
    let steps = app.world().resource::<SoftTissueStatus>().steps;
    app.world_mut()
        .get_mut::<Transform>(e)
        .unwrap()
        .translation
        .x += 4.0;
    app.update();
    let b = state(&app, e);
    assert_eq!(b.id(), id, "built again");
    assert!(b.diagnostics().max_displacement > 1e-3, "at rest again");
    assert!(b.model().precise().max_speed() > 1e-3, "stopped");
    assert_eq!(b.model().level(), Level::Precise);
    assert!(b.heat().unwrap().temperatures().iter().any(|&t| t > 37.5));
    let shift = b.frame().translation.vector - CoreVec3::new(4.0, 0.0, 0.0);
    assert!(shift.norm() < 1e-6, "frame {}", b.frame());
    assert_eq!(
        app.world().resource::<SoftTissueStatus>().steps,
        steps + 1,
        "the step ran with the body in it"
    );
    // A new scale is not a rigid move: the body is built again, at rest.
    app.world_mut().get_mut::<Transform>(e).unwrap().scale = Vec3::splat(1.5);
    for _ in 0..2 {
        app.update();
    }
    let b = state(&app, e);
    assert_ne!(b.id(), id, "a new scale builds the body again");
    let t = b.heat().unwrap().temperatures();
    assert!(t.iter().all(|&t| (t - 37.0).abs() < 1e-6), "heat kept");
}
