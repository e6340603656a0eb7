//! Spawning with defaults and writing each input component.

use super::*;

#[test]
fn bodies_get_only_the_components_they_use() {
    let mut app = app(0.02);
    let mesh = cylinder_asset(&mut app);
    let fem = app.world_mut().spawn(SoftBody::new(mesh.clone())).id();
    let msd_body = SoftBody::new(mesh.clone()).with_method(PreciseMethod::MsdImplicit);
    let msd = app
        .world_mut()
        .spawn((msd_body, Transform::from_xyz(3.0, 0.0, 0.0)))
        .id();
    let hot = app
        .world_mut()
        .spawn((
            SoftBody::new(mesh.clone()),
            TissueHeat::default(),
            Transform::from_xyz(-3.0, 0.0, 0.0),
        ))
        .id();
    let bad_anchor = SoftBody::new(mesh).with_anchor(Anchor::FixedBottom { fraction: 2.0 });
    let bad = app.world_mut().spawn(bad_anchor).id();
    app.update();
    app.update();
    let w = app.world();
    for e in [fem, msd, hot] {
        assert!(w.get::<SoftBodyState>(e).is_some());
        assert!(w.get::<PrecisionLevel>(e).is_some());
        assert!(w.get::<GreenCage>(e).is_some());
        assert!(w.get::<Mesh3d>(e).is_some(), "the render mesh is created");
        assert_eq!(level(&app, e), Level::Cage, "every body starts at its cage");
        assert_eq!(w.get::<TissueMaterial>(e), Some(&TissueMaterial::default()));
    }
    assert!(w.get::<FemState>(fem).is_some() && w.get::<MsdState>(fem).is_none());
    assert!(w.get::<MsdState>(msd).is_some() && w.get::<FemState>(msd).is_none());
    assert!(w.get::<Temperature>(fem).is_none() && w.get::<Temperature>(msd).is_none());
    let t = w.get::<Temperature>(hot).unwrap();
    assert!((t.max - 37.0).abs() < 1e-9 && !t.surface.is_empty());
    // The transform placed the mesh (the MSD body sits 3 units along x) and stays as set:
    // the rendered mesh is in the entity's frame.
    assert_eq!(
        *w.get::<Transform>(msd).unwrap(),
        Transform::from_xyz(3.0, 0.0, 0.0)
    );
    let sim = w.get::<SoftBodyState>(msd).unwrap().body();
    let cx = sim.mesh().bbox().min.x + 0.5 * sim.mesh().bbox().extent().x;
    assert!((cx - 3.0).abs() < 0.1, "centre x {cx}");
    let drawn = w.get::<Mesh3d>(msd).unwrap().0.clone();
    let local_cx = positions(&app, &drawn)
        .iter()
        .map(|p| p[0])
        .fold(f32::NEG_INFINITY, f32::max);
    assert!(
        local_cx < 1.0,
        "drawn in the entity's frame: largest x {local_cx}"
    );
    // A body with a setting out of range is refused, naming it.
    let err = w.get::<SoftBodyError>(bad).expect("refused");
    assert!(err.to_string().contains("fraction"), "{err}");
    assert!(w.get::<SoftBodyState>(bad).is_none());
}

/// The mesh of the body `e` in world coordinates now (its simulated nodes).
fn nodes(app: &App, e: Entity) -> Vec<bevy_soft_tissue::core::Vec3> {
    let sim = app.world().get::<SoftBodyState>(e).unwrap().body();
    sim.model().node_positions().to_vec()
}

fn centre(p: &[bevy_soft_tissue::core::Vec3]) -> Vec3 {
    let s = p
        .iter()
        .fold(bevy_soft_tissue::core::Vec3::zeros(), |a, b| a + b)
        / p.len() as f64;
    Vec3::new(s.x as f32, s.y as f32, s.z as f32)
}

/// Spawns a body with the defaults through the asset server and waits for it to be built.
fn spawn_liver(app: &mut App, extra: impl Bundle) -> Entity {
    let mesh: Handle<TetMeshAsset> = app
        .world()
        .resource::<AssetServer>()
        .load("meshes/liver.vtk");
    let e = app.world_mut().spawn((SoftBody::new(mesh), extra)).id();
    for _ in 0..2000 {
        app.update();
        if app.world().get::<SoftBodyState>(e).is_some() {
            return e;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    panic!("the liver was not built");
}

/// Whether `e` has a `Temperature` and its core body a heat field.
fn heated(app: &App, e: Entity) -> (bool, bool) {
    let sim = app.world().get::<SoftBodyState>(e).unwrap();
    (
        app.world().get::<Temperature>(e).is_some(),
        sim.body().heat().is_some(),
    )
}

#[test]
fn a_body_with_defaults_spawns_through_the_asset_server_and_each_input_takes_effect() {
    let mut app = app(0.01);
    // Two livers side by side: `a` is written, `b` is the control.
    let a = spawn_liver(&mut app, Name::new("a"));
    let b = spawn_liver(
        &mut app,
        (Name::new("b"), Transform::from_xyz(0.0, 0.0, 3.0)),
    );
    let pl = *app.world().get::<PrecisionLevel>(a).unwrap();
    assert_eq!(
        pl.method,
        PreciseMethod::CorotationalFem,
        "the default method"
    );
    let settings = |app: &App, e| {
        app.world()
            .get::<SoftBodyState>(e)
            .unwrap()
            .body()
            .model()
            .settings()
            .clone()
    };
    assert_eq!(settings(&app, a).fem, TissueMaterial::default().fem);
    assert_eq!(settings(&app, a).cage, CageKind::BoundingBox);

    // Pin: both raised, then pushed the same way by the same load on their top nodes.
    for e in [a, b] {
        app.world_mut()
            .entity_mut(e)
            .insert(PinnedLevel(Level::Precise));
    }
    app.update();
    assert_eq!(level(&app, a), Level::Precise);
    assert_eq!(level(&app, b), Level::Precise);

    // Material: four times stiffer; the same gravity-free push then moves `a` less.
    app.world_mut()
        .get_mut::<TissueMaterial>(a)
        .unwrap()
        .fem
        .young_modulus *= 4.0;
    app.update();
    assert_eq!(
        settings(&app, a).fem.young_modulus,
        4.0 * TissueMaterial::default().fem.young_modulus
    );
    let rest_a = nodes(&app, a);
    let rest_b = nodes(&app, b);
    for _ in 0..20 {
        for (e, rest) in [(a, &rest_a), (b, &rest_b)] {
            let mut w = app.world_mut().entity_mut(e);
            let mut sim = w.get_mut::<SoftBodyState>().unwrap();
            let top = (0..rest.len())
                .max_by(|&i, &j| rest[i].y.total_cmp(&rest[j].y))
                .unwrap();
            sim.body_mut()
                .model_mut()
                .add_force(top, bevy_soft_tissue::core::Vec3::new(0.0, 0.0, 2.0))
                .unwrap();
        }
        app.update();
    }
    let moved = |app: &App, e, rest: &[bevy_soft_tissue::core::Vec3]| {
        nodes(app, e)
            .iter()
            .zip(rest)
            .map(|(p, q)| (p - q).norm())
            .fold(0.0, f64::max)
    };
    let (ma, mb) = (moved(&app, a, &rest_a), moved(&app, b, &rest_b));
    assert!(mb > 1e-3, "the push moves the control ({mb})");
    assert!(ma < 0.7 * mb, "stiffer moves less: {ma} against {mb}");

    // Method: written on `SoftBody`, the solver and the state components follow.
    app.world_mut().get_mut::<SoftBody>(a).unwrap().method = PreciseMethod::MsdImplicit;
    app.update();
    app.update();
    assert_eq!(settings(&app, a).precise, PreciseMethod::MsdImplicit);
    assert!(app.world().get::<MsdState>(a).is_some());
    assert!(app.world().get::<FemState>(a).is_none());

    // Heat: added, a temperature field appears; removed, it goes.
    app.world_mut().entity_mut(a).insert(TissueHeat::default());
    app.update();
    app.update();
    assert_eq!(heated(&app, a), (true, true));
    app.world_mut().entity_mut(a).remove::<TissueHeat>();
    app.update();
    app.update();
    assert_eq!(heated(&app, a), (false, false));

    // Pin to the cage: it drops.
    app.world_mut()
        .entity_mut(a)
        .insert(PinnedLevel(Level::Cage));
    app.update();
    assert_eq!(level(&app, a), Level::Cage);

    // Cage, anchor and tuning: the body is built again with them.
    app.world_mut().get_mut::<SoftBody>(a).unwrap().anchor = Anchor::SoftToRest { stiffness: 2.0 };
    app.world_mut().get_mut::<SoftBody>(a).unwrap().cage = CageKind::Fitted { vertices: 32 };
    for _ in 0..3 {
        app.update();
    }
    let s = settings(&app, a);
    assert_eq!(s.cage, CageKind::Fitted { vertices: 32 });
    assert!(
        s.boundary != settings(&app, b).boundary,
        "the anchor holds it now"
    );
    app.world_mut().entity_mut(a).insert(SoftBodyTuning {
        fem_integrator: bevy_soft_tissue::core::fem::FemIntegrator::Bdf2,
        ..default()
    });
    for _ in 0..3 {
        app.update();
    }
    assert_eq!(
        settings(&app, a).fem_integrator,
        bevy_soft_tissue::core::fem::FemIntegrator::Bdf2
    );

    // Transform: moved 2 units up, the body is placed there.
    let before = centre(&nodes(&app, a));
    app.world_mut()
        .get_mut::<Transform>(a)
        .unwrap()
        .translation
        .y += 2.0;
    for _ in 0..3 {
        app.update();
    }
    let after = centre(&nodes(&app, a));
    assert!(
        (after - before - Vec3::Y * 2.0).length() < 0.05,
        "{before} -> {after}"
    );
    assert!(app.world().resource::<SoftTissueStatus>().error.is_none());
}

#[test]
fn a_parented_body_lands_at_its_global_pose() {
    let mut app = app(0.01);
    let parent = Transform::from_xyz(1.0, 2.0, 3.0)
        .with_rotation(Quat::from_rotation_y(std::f32::consts::FRAC_PI_2))
        .with_scale(Vec3::splat(0.5));
    let child = Transform::from_xyz(0.5, 0.0, 0.0);
    let root = app.world_mut().spawn(parent).id();
    let body = spawn_liver(&mut app, (child, ChildOf(root)));
    let file = bevy_soft_tissue::core::mesh::io::read_tet_mesh(assets().join("meshes/liver.vtk"))
        .unwrap()
        .mesh;
    let global = parent * child;
    let sim = nodes(&app, body);
    let off = file
        .positions()
        .iter()
        .zip(&sim)
        .map(|(p, q)| {
            let want = global.transform_point(Vec3::new(p.x as f32, p.y as f32, p.z as f32));
            (want - Vec3::new(q.x as f32, q.y as f32, q.z as f32)).length()
        })
        .fold(0.0, f32::max);
    assert!(off < 1e-4, "simulated nodes {off} from the global pose");
    // The rendered mesh is in the body's own frame: the file's coordinates.
    app.update();
    let drawn = app.world().get::<Mesh3d>(body).unwrap().0.clone();
    let sb = app.world().get::<SoftBodyState>(body).unwrap().body();
    let off = positions(&app, &drawn)
        .iter()
        .zip(sb.surface_nodes())
        .map(|(p, &i)| {
            let q = file.positions()[i as usize];
            (Vec3::from_array(*p) - Vec3::new(q.x as f32, q.y as f32, q.z as f32)).length()
        })
        .fold(0.0, f32::max);
    assert!(off < 1e-4, "drawn surface {off} from the file's");
    // Moving the parent moves the body.
    app.world_mut()
        .get_mut::<Transform>(root)
        .unwrap()
        .translation
        .x += 1.0;
    for _ in 0..4 {
        app.update();
    }
    let moved = centre(&nodes(&app, body)) - centre(&sim);
    assert!((moved - Vec3::X).length() < 1e-3, "{moved}");
}

#[test]
fn contacts_name_entities() {
    let (mut app, bodies, world) = scene_app(CYLINDERS);
    let (script, tool, dt) = scripted_tool(&mut app, &world, "push-a-into-b");
    let (a, b) = (bodies[0], bodies[1]);
    app.update();
    let (mut tool_seen, mut body_seen) = (false, false);
    let mut touched = Vec::new();
    for k in 1..=600 {
        drive_tool(&mut app, tool, &script, k, dt);
        app.update();
        let contacts = app.world().resource::<SoftTissueContacts>();
        for c in contacts.iter() {
            assert!(bodies.contains(&c.body), "{c:?}");
            assert!(c.points > 0 && c.max_depth.is_finite());
            match c.partner {
                ContactPartner::Tool(t) => {
                    assert_eq!(t, tool);
                    tool_seen |= c.body == a;
                }
                ContactPartner::Body(o) => {
                    assert!(o != c.body && (o == a || o == b), "{c:?}");
                    body_seen = true;
                    assert!(contacts.involving(o).any(|d| d == c));
                }
                ContactPartner::Obstacle(o) => panic!("no obstacle in this scene: {o:?}"),
            }
        }
        let msgs = app.world().resource::<Messages<BodyTouched>>();
        touched.extend(msgs.iter_current_update_messages().map(|m| m.entity));
    }
    assert!(tool_seen, "the tool touched A");
    assert!(body_seen, "A was pushed into B");
    assert!(touched.contains(&a) && touched.contains(&b));
}

#[test]
fn build_errors_name_the_entity_among_namesakes() {
    let mut app = app(0.02);
    let mesh = cylinder_asset(&mut app);
    // Three bodies of one name: one builds, one has a setting out of range, one a
    // transform that flattens its mesh.
    let twin = || Name::new("twin");
    let good = app
        .world_mut()
        .spawn((twin(), SoftBody::new(mesh.clone())))
        .id();
    let bad_anchor = SoftBody::new(mesh.clone()).with_anchor(Anchor::FixedBottom { fraction: 2.0 });
    let settings = app
        .world_mut()
        .spawn((twin(), bad_anchor, Transform::from_xyz(3.0, 0.0, 0.0)))
        .id();
    let flat = Transform::from_xyz(-3.0, 0.0, 0.0).with_scale(Vec3::new(1.0, 1.0, 0.0));
    let placement = app
        .world_mut()
        .spawn((twin(), SoftBody::new(mesh), flat))
        .id();
    app.update();
    app.update();
    let w = app.world();
    assert!(w.get::<SoftBodyState>(good).is_some());
    assert!(w.get::<SoftBodyError>(good).is_none());
    let err = w.get::<SoftBodyError>(settings).expect("refused");
    assert!(matches!(err, SoftBodyError::Settings { .. }), "{err:?}");
    assert_eq!((err.body(), err.name()), (settings, "twin"));
    let text = err.to_string();
    assert!(
        text.contains("`twin`")
            && text.contains(&settings.to_string())
            && text.contains("fraction"),
        "{text}"
    );
    let err = w.get::<SoftBodyError>(placement).expect("refused");
    assert!(matches!(err, SoftBodyError::Placement { .. }), "{err:?}");
    assert_eq!((err.body(), err.name()), (placement, "twin"));
    assert!(err.to_string().contains(&placement.to_string()), "{err}");
}
