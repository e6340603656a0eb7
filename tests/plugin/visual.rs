//! What is drawn: finer visual meshes, haptics and a non-manifold mesh.

use super::*;

/// A finer cylinder than the simulation's (Bevy's primitive mesh, 48 around, axis y) of the
/// paper's size times `scale`, turned by `rotation` and moved by `shift`.
fn fine_cylinder(scale: f32, rotation: Quat, shift: Vec3) -> Mesh {
    Cylinder::new(0.62 * scale, 1.72 * scale)
        .mesh()
        .resolution(48)
        .segments(8)
        .build()
        .rotated_by(rotation)
        .translated_by(shift)
}

/// In the coordinates of the cylinder mesh file (axis z).
fn y_to_z() -> Quat {
    Quat::from_rotation_arc(Vec3::Y, Vec3::Z)
}

#[test]
fn finer_visual_meshes_follow_the_simulation() {
    let (mut app, bodies, world) = scene_app(CYLINDERS);
    let (a, b) = (bodies[0], bodies[1]);
    let centre = world.bodies()[0].mesh().bbox().center();
    // The scene stands the cylinders along y.
    let source = fine_cylinder(
        1.0,
        Quat::IDENTITY,
        bevy_soft_tissue::convert::to_bevy(&centre),
    );
    let source_positions = mesh_positions(&source);
    let handle = app.world_mut().resource_mut::<Assets<Mesh>>().add(source);
    app.world_mut()
        .entity_mut(a)
        .insert(VisualMesh::mesh(handle.clone()));
    app.world_mut()
        .entity_mut(b)
        .insert(VisualMesh::Subdivided { levels: 2 });
    let (script, tool, dt) = scripted_tool(&mut app, &world, "poke-a");
    app.update();
    // Settled under gravity, the visual mesh is where it was given, up to the sag of the
    // simulated surface; the asset itself is not touched.
    assert_eq!(app.world().get::<VisualMeshError>(a), None);
    assert_eq!(app.world().get::<VisualMeshError>(b), None);
    let drawn = app.world().get::<Mesh3d>(a).unwrap().0.clone();
    assert_ne!(drawn, handle);
    let initial = positions(&app, &drawn);
    assert_eq!(initial.len(), source_positions.len());
    let sim = app.world().get::<SoftBodyState>(a).unwrap().body();
    let file: Vec<[f32; 3]> = sim
        .surface_nodes()
        .iter()
        .map(|&i| bevy_soft_tissue::convert::to_bevy(&sim.mesh().positions()[i as usize]).into())
        .collect();
    let sag = max_distance(sim.surface_positions(), &file);
    let off = max_distance(&initial, &source_positions);
    assert!(off <= 1.2 * sag + 1e-5, "{off} vs sag {sag}");
    // The subdivided surface has 16 times the simulation's triangles.
    let sub = app.world().get::<Mesh3d>(b).unwrap().0.clone();
    let sub_mesh = app.world().resource::<Assets<Mesh>>().get(&sub).unwrap();
    let sim_triangles = world.bodies()[1].surface_triangles().len();
    assert_eq!(sub_mesh.indices().unwrap().len(), 3 * 16 * sim_triangles);
    let surface0 = surfaces(&app, &[a])[0].clone();
    let (mut visual_moved, mut surface_moved) = (0.0f32, 0.0f32);
    for k in 1..=900 {
        drive_tool(&mut app, tool, &script, k, dt);
        app.update();
        visual_moved = visual_moved.max(max_distance(&positions(&app, &drawn), &initial));
        surface_moved = surface_moved.max(max_distance(&surfaces(&app, &[a])[0], &surface0));
    }
    // The fine mesh deforms with the simulated surface: by as much, within what linear
    // interpolation inside the tetrahedra loses at a poke between nodes.
    assert!(surface_moved > 0.01, "{surface_moved}");
    assert!(
        visual_moved > 0.5 * surface_moved && visual_moved < 1.2 * surface_moved,
        "visual {visual_moved} vs surface {surface_moved}"
    );
    // Back at rest, the visual mesh is back where it started.
    assert_eq!(level(&app, a), Level::Cage);
    let back = max_distance(&positions(&app, &drawn), &initial);
    let surface_back = max_distance(&surfaces(&app, &[a])[0], &surface0);
    assert!(
        back <= 1.5 * surface_back + 1e-5,
        "{back} vs {surface_back}"
    );
    assert_eq!(
        app.world()
            .resource::<Assets<Mesh>>()
            .get(&handle)
            .map(mesh_positions),
        Some(source_positions)
    );
}

#[test]
fn visual_meshes_are_placed_with_the_body_and_mismatched_ones_refused() {
    let mut app = app(0.02);
    let mesh = cylinder_asset(&mut app);
    // No gravity (the default): the body stays in its file shape, so the drawn mesh must be
    // exactly the visual mesh (drawn in the entity's frame, placed by its transform).
    let place = Transform::from_xyz(3.0, -1.0, 0.5)
        .with_rotation(Quat::from_rotation_x(1.0))
        .with_scale(Vec3::splat(0.5));
    let fine = fine_cylinder(1.0, y_to_z(), Vec3::ZERO);
    let want: Vec<[f32; 3]> = mesh_positions(&fine);
    let fine = app.world_mut().resource_mut::<Assets<Mesh>>().add(fine);
    // Both bodies share a name: the error names the refused one's entity.
    let placed = app
        .world_mut()
        .spawn((
            Name::new("wrong"),
            SoftBody::new(mesh.clone()),
            place,
            VisualMesh::mesh(fine),
        ))
        .id();
    // Ten times too large: most vertices are far outside the body.
    let huge = app
        .world_mut()
        .resource_mut::<Assets<Mesh>>()
        .add(fine_cylinder(10.0, y_to_z(), Vec3::ZERO));
    let wrong = app
        .world_mut()
        .spawn((
            Name::new("wrong"),
            SoftBody::new(mesh),
            VisualMesh::mesh(huge),
        ))
        .id();
    app.update();
    let drawn = app.world().get::<Mesh3d>(placed).unwrap().0.clone();
    let off = max_distance(&positions(&app, &drawn), &want);
    assert!(off < 1e-4, "{off}");
    assert!(app.world().get::<VisualMeshError>(placed).is_none());
    let error = app.world().get::<VisualMeshError>(wrong).expect("refused");
    assert!(
        matches!(error, VisualMeshError::Embedding { .. }),
        "{error:?}"
    );
    assert_eq!((error.body(), error.name()), (wrong, "wrong"));
    let text = error.to_string();
    assert!(
        text.contains("`wrong`")
            && text.contains(&wrong.to_string())
            && text.contains("farther than the limit"),
        "{text}"
    );
    // The refused body is drawn with its simulation surface.
    let drawn = app.world().get::<Mesh3d>(wrong).unwrap().0.clone();
    let sim = app.world().get::<SoftBodyState>(wrong).unwrap();
    assert_eq!(
        positions(&app, &drawn).len(),
        sim.body().surface_positions().len()
    );
}

#[cfg(feature = "haptics")]
#[test]
fn a_haptic_device_pokes_through_the_haptic_thread_and_feels_the_tissue() {
    use bevy_soft_tissue::core::haptics::VirtualDevice;
    use bevy_soft_tissue::haptics::{HapticTool, SoftTissueHapticsPlugin};
    let (mut app, bodies, world) = scene_app(CYLINDERS);
    app.add_plugins(SoftTissueHapticsPlugin);
    let a = bodies[0];
    let (lo, hi) = world.bodies()[0].collider().bounds();
    let y = 0.5 * (lo[1] + hi[1]);
    let outside = bevy_soft_tissue::core::Vec3::new(lo[0] - 0.2, y, 0.5 * (lo[2] + hi[2]));
    let (device, handle) = VirtualDevice::new(outside, 8.0);
    let haptic = HapticTool::start(Box::new(device), haptic_config(), 0.0).unwrap();
    let tool = app
        .world_mut()
        .spawn((SoftTool::sphere(0.05), Transform::default(), haptic))
        .id();
    app.update();
    // Push the device 0.1 into A from its -x side, in small steps (a hand, not a jump: a
    // proxy that crosses the surface between two physics steps would pass through it).
    let inside = bevy_soft_tissue::core::Vec3::new(lo[0] + 0.1, outside.y, outside.z);
    let mut felt = false;
    for k in 0..1500 {
        let s = (k as f64 / 300.0).min(1.0);
        handle.set(outside + (inside - outside) * s, 0);
        app.update();
        std::thread::sleep(Duration::from_millis(2));
        if s == 1.0 && level(&app, a) == Level::Precise && handle.force().x < -0.1 {
            felt = true;
            break;
        }
    }
    assert!(
        felt,
        "force {:?}, level {:?}",
        handle.force(),
        level(&app, a)
    );
    // The tool is where the thread's proxy is: held back by the tissue, short of the device.
    let tool_x = app.world().get::<Transform>(tool).unwrap().translation.x as f64;
    assert!(tool_x < inside.x, "tool {tool_x} vs device {}", inside.x);
    assert!(handle.force().norm() <= 8.0 + 1e-9);
    let h = app.world().get::<HapticTool>(tool).unwrap();
    // The thread got the real time it asks for by default, or says why not.
    let p = h.priority();
    assert!(p.is_real_time() || p.refused.is_some(), "{p}");
    assert!(
        h.model().active && h.model().normal.x < 0.0,
        "{:?}",
        h.model()
    );
    // Removing the component stops the thread and leaves the device with no force.
    app.world_mut().entity_mut(tool).remove::<HapticTool>();
    assert_eq!(handle.force(), bevy_soft_tissue::core::Vec3::zeros());
}

/// A mesh with the defects real meshes have (two cubes meeting along an edge only, so
/// non-manifold boundary edges and vertices, and a node no tetrahedron uses) is built,
/// drawn with a Loop-subdivided visual mesh, poked at its pinch, rises and comes back; the
/// drawn mesh follows.
#[test]
fn a_non_manifold_mesh_simulates_and_draws_in_the_plugin() {
    use bevy_soft_tissue::core::Vec3 as V;
    use bevy_soft_tissue::core::mesh::TetMesh;
    use bevy_soft_tissue::core::mesh::generate::block;
    let a = block(V::zeros(), V::repeat(0.5), [3, 3, 3]).unwrap();
    let b = block(V::new(0.5, 0.5, 0.0), V::new(1.0, 1.0, 0.5), [3, 3, 3]).unwrap();
    let mut points: Vec<V> = Vec::new();
    let mut tets = Vec::new();
    for m in [&a, &b] {
        let map: Vec<usize> = m
            .positions()
            .iter()
            .map(|p| match points.iter().position(|q| q == p) {
                Some(i) => i,
                None => {
                    points.push(*p);
                    points.len() - 1
                }
            })
            .collect();
        tets.extend(m.tets().iter().map(|t| t.map(|i| map[i as usize])));
    }
    points.push(V::new(3.0, 3.0, 3.0));
    let mesh = TetMesh::new(points, tets).unwrap();
    let nodes = mesh.node_count();
    let mut app = app(0.01);
    let handle = app
        .world_mut()
        .resource_mut::<Assets<TetMeshAsset>>()
        .add(TetMeshAsset::from(mesh));
    assert!(nodes > 0);
    app.world_mut().resource_mut::<SoftTissueConfig>().contact =
        bevy_soft_tissue::core::contact::ContactConfig::for_scale(0.5);
    let body = app
        .world_mut()
        .spawn((
            SoftBody::new(handle).with_anchor(Anchor::SoftToRest { stiffness: 1.0 }),
            VisualMesh::Subdivided { levels: 1 },
        ))
        .id();
    // A ball pressed into the notch where the two cubes meet.
    let r = 0.08f32;
    let dir = Vec3::new(1.0, -1.0, 0.0).normalize();
    let start = Vec3::new(0.5 - r, 0.5 + r, 0.25) - dir * 0.1;
    let tool = app
        .world_mut()
        .spawn((
            soft_tool(ToolShape::Sphere { radius: r as f64 }),
            Transform::from_translation(start),
        ))
        .id();
    app.update();
    app.update();
    assert!(
        app.world().get::<SoftBodyError>(body).is_none(),
        "{:?}",
        app.world().get::<SoftBodyError>(body)
    );
    assert_eq!(app.world().get::<VisualMeshError>(body), None);
    let drawn = app.world().get::<Mesh3d>(body).unwrap().0.clone();
    let initial = positions(&app, &drawn);
    let (mut raised, mut moved, mut elastic) = (false, 0.0f32, 0.0f64);
    for k in 1..=400 {
        let t = k as f32 * 0.01;
        let depth = 0.15 * if t < 1.0 { t } else { (2.0 - t).max(0.0) };
        app.world_mut()
            .entity_mut(tool)
            .get_mut::<Transform>()
            .unwrap()
            .translation = start + dir * depth;
        app.update();
        raised |= level(&app, body) == Level::Precise;
        moved = moved.max(max_distance(&positions(&app, &drawn), &initial));
        // Energies on request: finite, and the pressed body stores elastic energy.
        let e = app.world().get::<SoftBodyState>(body).unwrap().energies();
        assert!(e.kinetic.is_finite() && e.kinetic >= 0.0 && e.elastic.is_finite());
        elastic = elastic.max(e.elastic);
        assert!(app.world().resource::<SoftTissueStatus>().error.is_none());
    }
    assert!(raised, "the poke did not raise the body");
    assert!(moved > 0.01, "the drawn mesh did not follow ({moved})");
    assert!(elastic > 0.0, "no elastic energy while pressed");
    assert_eq!(level(&app, body), Level::Cage, "it did not come back");
}

/// The organs' liver drawn with a subdivided visual mesh and cauterized at 30 W: the burn is
/// drawn at the visual vertices from the heat field's samples there: a charred spot a few
/// millimetres wide (dark), and every burnt vertex within 12 mm of it, not a tint over
/// elements (which are centimetres across), also after the electrode carved its crater out
/// of the mesh (the subdivided visual mesh is made again, its burn from the heat field's
/// marks); the inspector's component has the burnt
/// volumes. (At 30 W the coagulated rim around the char is a fraction of a millimetre: the
/// heat has no time to spread.)
#[test]
fn a_cautery_burn_is_drawn_at_the_visual_vertices_not_over_elements() {
    let (mut app, bodies, world) = scene_app(ORGANS);
    let liver = bodies[world.body_index("Liver").unwrap()];
    app.world_mut()
        .entity_mut(liver)
        .insert(VisualMesh::Subdivided { levels: 3 });
    let (script, tool, dt) = scripted_tool(&mut app, &world, "cauterize-liver");
    for k in 1..=300 {
        drive_tool(&mut app, tool, &script, k, dt);
        app.update();
    }
    assert!(app.world().resource::<SoftTissueStatus>().error.is_none());
    let t = app.world().get::<Temperature>(liver).unwrap();
    assert!(
        t.charred_mm3 > 0.0 && t.coagulated_mm3 >= t.charred_mm3,
        "{t:?}"
    );
    assert!(t.max >= 99.0, "{t:?}");
    // The electrode carved its crater out of the mesh, and the visual mesh was made again.
    let sim = app.world().get::<SoftBodyState>(liver).unwrap();
    assert!(
        sim.body().cut_record().is_some_and(|c| c.cuts > 0),
        "nothing was carved"
    );
    assert!(
        app.world()
            .get::<bevy_soft_tissue::EmbeddedVisual>(liver)
            .is_some(),
        "the visual mesh was not embedded again"
    );
    let handle = app.world().get::<Mesh3d>(liver).unwrap().0.clone();
    let meshes = app.world().resource::<Assets<Mesh>>();
    let mesh = meshes.get(&handle).unwrap();
    let Some(VertexAttributeValues::Float32x4(colours)) = mesh.attribute(Mesh::ATTRIBUTE_COLOR)
    else {
        panic!("no vertex colours");
    };
    let p = mesh_positions(mesh);
    assert_eq!(p.len(), colours.len());
    let dark: Vec<Vec3> = (0..p.len())
        .filter(|&i| colours[i][0] < 0.4)
        .map(|i| Vec3::from_array(p[i]))
        .collect();
    // Burnt at all: coagulated (white-grey) or charred; unburnt tissue keeps its red
    // channel at 1, warm or not.
    let burnt: Vec<Vec3> = (0..p.len())
        .filter(|&i| colours[i][0] < 0.999)
        .map(|i| Vec3::from_array(p[i]))
        .collect();
    assert!(!dark.is_empty(), "no charred vertex among {}", p.len());
    let centre = dark.iter().sum::<Vec3>() / dark.len() as f32;
    // A liver element is about 0.14 units (1.4 cm) across; the charred spot's vertices
    // lie within 0.05 units (5 mm) of their centre.
    let spread = dark.iter().map(|q| q.distance(centre)).fold(0.0, f32::max);
    println!(
        "{} of {} vertices charred within {:.1} mm of their centre, {} burnt at all",
        dark.len(),
        p.len(),
        spread * 100.0,
        burnt.len()
    );
    assert!(spread < 0.05, "charred vertices spread over {spread} units");
    // Every burnt vertex is near the char: the burn is a spot, not elements tinted.
    let burnt_spread = burnt.iter().map(|q| q.distance(centre)).fold(0.0, f32::max);
    println!("burnt within {:.1} mm of the char", burnt_spread * 100.0);

    // (Under 12 mm: the crater the electrode carves makes the visual mesh again from the
    // carved surface, and the pressing tool stretches the crater's coagulated rim; a liver
    // element is 14 mm across.)
    assert!(
        burnt_spread < 0.12,
        "burnt vertices spread over {burnt_spread} units"
    );
}
