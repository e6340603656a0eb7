//! Contact in the plugin: a body resting on an obstacle entity, a grasper driven by its
//! component.

use super::*;
use bevy_soft_tissue::core::contact::JawShape;
use bevy_soft_tissue::{ContactPartner, ObstacleCollider, SoftObstacle, SoftTissueContacts};

/// A free cylinder under gravity falls onto a table entity (a plane obstacle) and comes to
/// rest on it: the contacts name the obstacle's entity, nothing sinks into the table by more
/// than 1e-3 of the cylinder's smallest dimension, and it drops back to its cage at rest.
#[test]
fn a_body_comes_to_rest_on_an_obstacle_entity() {
    let dt = 0.01;
    let mut app = app(dt);
    app.world_mut().resource_mut::<SoftTissueConfig>().gravity =
        bevy::math::DVec3::new(0.0, -2.0, 0.0);
    let mesh = cylinder_asset(&mut app);
    // The cylinder's axis is z: it lies on its side, its lowest point at y = -0.62.
    let body = app
        .world_mut()
        .spawn((SoftBody::new(mesh), Transform::from_xyz(0.0, 0.63, 0.0)))
        .id();
    let table = app
        .world_mut()
        .spawn((
            SoftObstacle::new(ObstacleCollider::Plane),
            Transform::default(),
        ))
        .id();
    let (mut seen, mut worst) = (false, 0.0f64);
    for _ in 0..1500 {
        app.update();
        let contacts = app.world().resource::<SoftTissueContacts>();
        for c in contacts.involving(body) {
            if c.partner == ContactPartner::Obstacle(table) {
                seen = true;
                assert!(c.force.y > 0.0, "the table pushes up: {c:?}");
            }
        }
        let d = app.world().get::<SoftBodyDiagnostics>(body).unwrap();
        worst = worst.max(d.penetration_ratio);
    }
    assert!(seen, "the body touched the table");
    assert!(
        worst <= 1e-3,
        "penetration {worst:.2e} of the smallest dimension"
    );
    assert_eq!(
        level(&app, body),
        Level::Cage,
        "at rest on the table: its cage"
    );
    let sim = app.world().get::<SoftBodyState>(body).unwrap();
    let lowest = sim
        .body()
        .surface_positions()
        .iter()
        .map(|p| p[1])
        .fold(f32::INFINITY, f32::min);
    assert!(
        lowest > -1e-3 && lowest < 0.02,
        "resting on the table: lowest {lowest}"
    );
}

/// A grasper's jaws move toward the opening its component asks for, at the jaw speed, and
/// report it.
#[test]
fn a_grasper_follows_its_jaws_setting() {
    let mut app = app(0.01);
    let mut tool = SoftTool::grasper(
        JawShape::Capsule {
            radius: 0.02,
            length: 0.2,
        },
        0.3,
    );
    tool.jaws = 0.3;
    let e = app
        .world_mut()
        .spawn((tool, Transform::from_xyz(5.0, 5.0, 5.0)))
        .id();
    app.update();
    app.update();
    let r = *app.world().get::<ToolReaction>(e).unwrap();
    assert!((r.opening - 0.3).abs() < 1e-12, "{r:?}");
    app.world_mut().get_mut::<SoftTool>(e).unwrap().jaws = 0.1;
    for _ in 0..100 {
        app.update();
    }
    let r = *app.world().get::<ToolReaction>(e).unwrap();
    assert!((r.opening - 0.1).abs() < 1e-12, "closed to 0.1: {r:?}");
    assert_eq!(r.contacts, 0);
}

/// A body built again because its scale changed is not counted among the contact bodies
/// of the step that queued its rebuild: the contacts of a body built after it keep naming
/// that body, not the one being rebuilt (whose index it would take). A body moved by its
/// transform every step (a teleport each step) keeps its place among them.
#[test]
fn contacts_name_the_touched_body_while_another_moves_or_is_rebuilt() {
    let dt = 0.01;
    let mut app = app(dt);
    let mesh = cylinder_asset(&mut app);
    let moving = app
        .world_mut()
        .spawn((
            SoftBody::new(mesh.clone()),
            Transform::from_xyz(5.0, 0.0, 0.0),
        ))
        .id();
    app.update();
    let touched = app
        .world_mut()
        .spawn((SoftBody::new(mesh), Transform::default()))
        .id();
    // A ball pressed into the top of the cylinder lying on its side (radius about 0.62).
    let probe = app
        .world_mut()
        .spawn((
            soft_tool(ToolShape::Sphere { radius: 0.1 }),
            Transform::from_xyz(0.0, 0.66, 0.0),
        ))
        .id();
    let mut touches = 0;
    let id = |app: &App| {
        app.world()
            .get::<SoftBodyState>(moving)
            .map(|s| s.body().id())
    };
    let mut built = None;
    for k in 0..60 {
        // Scaled (built again) once while it still comes first in build order, then moved
        // and turned every step.
        let mut t = app.world_mut().get_mut::<Transform>(moving).unwrap();
        if k == 20 {
            t.scale = Vec3::splat(1.01);
        }
        if k > 40 {
            t.translation.x = 5.0 + 0.001 * k as f32;
            t.rotation = Quat::from_rotation_y(0.01 * k as f32);
        }
        app.update();
        let contacts = app.world().resource::<SoftTissueContacts>();
        for c in contacts.iter() {
            assert_eq!(c.body, touched, "step {k}: a contact names {c:?}");
            assert_eq!(c.partner, ContactPartner::Tool(probe), "step {k}: {c:?}");
            touches += 1;
        }
        assert_eq!(contacts.involving(moving).count(), 0, "step {k}");
        // Built again after its new scale; moved, never again.
        match k {
            20 => assert_eq!(id(&app), None, "being built again"),
            40 => built = id(&app),
            41.. => assert_eq!(id(&app), built, "step {k}: built again"),
            _ => {}
        }
    }
    assert!(built.is_some());
    assert!(touches > 30, "the probe pressed the body: {touches} steps");
}

/// A Bevy mesh becomes a mesh obstacle only if it is a whole triangle list with positions;
/// otherwise the error names what is wrong.
#[test]
fn a_bevy_mesh_obstacle_is_refused_by_name() {
    use bevy::asset::RenderAssetUsages;
    use bevy::mesh::{Indices, PrimitiveTopology};
    use bevy_soft_tissue::ObstacleMeshError;
    let tetrahedron = |topology: PrimitiveTopology, indices: Vec<u32>| {
        let mut m = Mesh::new(topology, RenderAssetUsages::default());
        m.insert_attribute(
            Mesh::ATTRIBUTE_POSITION,
            vec![
                [0.0f32, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
            ],
        );
        m.insert_indices(Indices::U32(indices));
        m
    };
    let faces = vec![0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3];
    let ok = ObstacleCollider::from_mesh(&tetrahedron(PrimitiveTopology::TriangleList, faces));
    assert!(matches!(ok, Ok(ObstacleCollider::Mesh(_))), "{ok:?}");
    let lines = ObstacleCollider::from_mesh(&tetrahedron(PrimitiveTopology::LineList, vec![0, 1]));
    assert!(
        matches!(lines, Err(ObstacleMeshError::NotTriangles(_))),
        "{lines:?}"
    );
    let partial = ObstacleCollider::from_mesh(&tetrahedron(
        PrimitiveTopology::TriangleList,
        vec![0, 2, 1, 0],
    ));
    assert!(
        matches!(
            partial,
            Err(ObstacleMeshError::PartialTriangle { count: 4 })
        ),
        "{partial:?}"
    );
    let bad =
        ObstacleCollider::from_mesh(&tetrahedron(PrimitiveTopology::TriangleList, vec![0, 2, 9]));
    let e = bad.unwrap_err();
    assert!(matches!(e, ObstacleMeshError::Shape(_)), "{e:?}");
    assert!(e.to_string().starts_with("obstacle mesh: "), "{e}");
    let empty = Mesh::new(
        PrimitiveTopology::TriangleList,
        RenderAssetUsages::default(),
    );
    assert!(matches!(
        ObstacleCollider::from_mesh(&empty),
        Err(ObstacleMeshError::NoPositions)
    ));
}
