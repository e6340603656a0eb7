//! What a burn does to what is drawn: a visual mesh of the app's own keeps its vertices and
//! shows the crater an electrode carves as a dent; a piece a blade takes off a burnt body
//! draws the burn marks it took along.

use super::*;
use bevy::asset::RenderAssetUsages;
use bevy::mesh::{Indices, PrimitiveTopology};
use bevy_soft_tissue::EmbeddedVisual;
use bevy_soft_tissue::core::Vec3 as V;
use bevy_soft_tissue::core::contact::ContactConfig;
use bevy_soft_tissue::core::heat::{ElectrodeSource, HeatParams, HeatSample};
use bevy_soft_tissue::core::material::FemParams;
use bevy_soft_tissue::core::mesh::cut::Ball;
use bevy_soft_tissue::core::mesh::embed::Embedding;
use bevy_soft_tissue::core::mesh::generate::block;
use bevy_soft_tissue::{CutPiece, TissueHeat};

/// The surface of the box `lo..hi` as an app's mesh: every face an `n` by `n` grid of its
/// own vertices (the copies along the box's edges are a UV seam's).
fn grid_box(lo: Vec3, hi: Vec3, n: u32) -> Mesh {
    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut indices: Vec<u32> = Vec::new();
    for axis in 0..3 {
        for high in [false, true] {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let base = positions.len() as u32;
            for j in 0..=n {
                for i in 0..=n {
                    let mut p = [0.0f32; 3];
                    p[axis] = if high { hi[axis] } else { lo[axis] };
                    p[u] = lo[u] + (hi[u] - lo[u]) * i as f32 / n as f32;
                    p[v] = lo[v] + (hi[v] - lo[v]) * j as f32 / n as f32;
                    positions.push(p);
                }
            }
            let at = |i: u32, j: u32| base + i + (n + 1) * j;
            for j in 0..n {
                for i in 0..n {
                    // Counter-clockwise seen from outside.
                    let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                    if high {
                        indices.extend([a, b, c, a, c, d]);
                    } else {
                        indices.extend([a, c, b, a, d, c]);
                    }
                }
            }
        }
    }
    let mut mesh = Mesh::new(
        PrimitiveTopology::TriangleList,
        RenderAssetUsages::default(),
    );
    mesh.insert_attribute(Mesh::ATTRIBUTE_POSITION, positions);
    mesh.insert_indices(Indices::U32(indices));
    mesh
}

/// A heated block of liver `lo..hi` (metres) meshed in `cells`, fixed at its bottom, drawn
/// with `visual`, in an app stepping at `dt` with contact at the block's scale; its entity.
fn burnt_block(dt: f64, lo: V, hi: V, cells: [usize; 3], visual: Mesh) -> (App, Entity) {
    let mut app = app(dt);
    app.world_mut().resource_mut::<SoftTissueConfig>().contact =
        ContactConfig::for_scale((hi - lo).max());
    let mesh = block(lo, hi, cells).unwrap();
    let fem = FemParams {
        young_modulus: 2.0e4,
        poisson_ratio: 0.45,
        mass: 1079.0 * mesh.volume(),
        damping: 1.0,
    };
    let handle = app
        .world_mut()
        .resource_mut::<Assets<TetMeshAsset>>()
        .add(TetMeshAsset::from(mesh));
    let visual = app.world_mut().resource_mut::<Assets<Mesh>>().add(visual);
    let body = app
        .world_mut()
        .spawn((
            Name::new("block"),
            SoftBody::new(handle).with_anchor(Anchor::FixedBottom { fraction: 0.01 }),
            TissueMaterial { fem, ..default() },
            TissueHeat(HeatParams {
                meters_per_unit: 1.0,
                ..HeatParams::liver()
            }),
            VisualMesh::mesh(visual),
        ))
        .id();
    app.update();
    embedded_visual(&app, body);
    (app, body)
}

/// The app's own visual mesh `body` is drawn with (none refused).
fn embedded_visual(app: &App, body: Entity) -> &EmbeddedVisual {
    assert_eq!(app.world().get::<VisualMeshError>(body), None);
    app.world()
        .get::<EmbeddedVisual>(body)
        .expect("the visual mesh was dropped")
}

/// An electrode of 1 mm at `watts` on the node of `body` nearest `at` (rest), for the next
/// step (as a pressed cautery tool heats).
fn heat_at(app: &mut App, body: Entity, at: V, watts: f64) {
    let mut sim = app.world_mut().get_mut::<SoftBodyState>(body).unwrap();
    let x = sim.body().mesh().positions();
    let node = (0..x.len())
        .min_by(|&i, &j| (x[i] - at).norm().total_cmp(&(x[j] - at).norm()))
        .unwrap();
    let source = ElectrodeSource {
        center: x[node],
        watts,
        radius: 1e-3,
        tissue_fraction: 0.5,
    };
    sim.body_mut()
        .heat_mut()
        .unwrap()
        .add_electrode(&source, &[(node, 1.0)])
        .unwrap();
}

fn drawn(app: &App, body: Entity) -> Vec<[f32; 3]> {
    let handle = app.world().get::<Mesh3d>(body).unwrap().0.clone();
    positions(app, &handle)
}

fn indices(app: &App, handle: &Handle<Mesh>) -> Vec<u32> {
    let mesh = app.world().resource::<Assets<Mesh>>().get(handle).unwrap();
    mesh.indices().unwrap().iter().map(|i| i as u32).collect()
}

/// The positions of an app's mesh as the rest positions they are embedded at (the block's
/// frame is the world's).
fn given_positions(mesh: &Mesh) -> Vec<V> {
    mesh_positions(mesh)
        .iter()
        .map(|p| V::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .collect()
}

/// Heats `body` at `at` (30 W) until a carve lands; the visual mesh as drawn when the step
/// that carved began.
fn carve_at(app: &mut App, body: Entity, at: V) -> Vec<[f32; 3]> {
    let mut steps = 0;
    loop {
        let before = drawn(app, body);
        steps += 1;
        assert!(steps <= 256, "no crater was carved at {at}");
        heat_at(app, body, at, 30.0);
        app.update();
        assert!(app.world().resource::<SoftTissueStatus>().error.is_none());
        let sim = app.world().get::<SoftBodyState>(body).unwrap();
        if sim.body().cut_record().is_some() {
            return before;
        }
    }
}

/// How far the visual mesh of `body` is drawn from where its embedding puts its vertices in
/// the body's tetrahedra as they are now.
fn off_embedding(app: &App, body: Entity) -> f32 {
    let visual = app.world().get::<EmbeddedVisual>(body).unwrap();
    let sim = app.world().get::<SoftBodyState>(body).unwrap();
    let mut placed = vec![[0.0f32; 3]; visual.embedding().len()];
    visual
        .embedding()
        .apply(sim.body().model().node_positions(), &mut placed)
        .unwrap();
    max_distance(&placed, &drawn(app, body))
}

/// How far `q` is from the nearest of the spheres of `balls`, in their radii.
fn radii_off_the_spheres(q: &V, balls: &[Ball]) -> f64 {
    balls
        .iter()
        .map(|c| ((q - c.centre).norm() - c.radius).abs() / c.radius)
        .fold(f64::INFINITY, f64::min)
}

/// A 12 mm block of liver (2 mm elements) drawn with a mesh of the app's own (a box, every
/// face a 48 by 48 grid: 0.25 mm) is burnt at 30 W in the middle of its top face until
/// the crater is carved out of its tetrahedra. The visual mesh keeps its vertices and
/// triangles, every vertex embedded; those that were inside the carved ball lie on its
/// sphere (to 1e-9 of the radius), in or on the carved body (within the carve's polyhedral
/// error of a fraction of the radius), burnt; those farther than two radii from the
/// ball's centre are drawn where they were.
#[test]
fn an_apps_own_visual_mesh_shows_a_carved_crater_as_a_dent() {
    let side = 0.012;
    let (lo, hi) = (V::zeros(), V::repeat(side));
    let source = grid_box(Vec3::ZERO, Vec3::splat(side as f32), 48);
    let count = source.count_vertices();
    let original = given_positions(&source);
    let source_indices: Vec<u32> = source.indices().unwrap().iter().map(|i| i as u32).collect();
    let (mut app, body) = burnt_block(1.0 / 64.0, lo, hi, [6, 6, 6], source);
    let top = V::new(0.5 * side, side, 0.5 * side);
    let before = carve_at(&mut app, body, top);
    // The visual mesh was fitted to the carved body (this frame) and is drawn (the next).
    app.update();
    let visual = embedded_visual(&app, body);
    let sim = app.world().get::<SoftBodyState>(body).unwrap();
    let b = sim.body();
    let handle = app.world().get::<Mesh3d>(body).unwrap().0.clone();
    let after = positions(&app, &handle);
    assert_eq!(after.len(), count);
    assert_eq!(visual.embedding().len(), count);
    assert_eq!(indices(&app, &handle), source_indices);
    // Every vertex embedded in the carved body's tetrahedra, drawn where they put it.
    assert!(off_embedding(&app, body) < 1e-7);
    let balls = visual.carved().to_vec();
    assert!(!balls.is_empty());
    let rest = visual.rest_positions();
    let inside = |p: &V| {
        balls
            .iter()
            .any(|c| (p - c.centre).norm() < c.radius * (1.0 - 1e-6))
    };
    let moved: Vec<usize> = (0..count).filter(|&k| inside(&original[k])).collect();
    assert!(!moved.is_empty(), "no visual vertex was in the crater");
    let radius = balls.iter().map(|c| c.radius).fold(0.0, f64::max);
    // Those in the ball: on its sphere, outside every ball.
    let mut depth = 0.0f64;
    for &k in &moved {
        let q = rest[k];
        let off = radii_off_the_spheres(&q, &balls);
        assert!(off < 1e-9, "vertex {k} is {off} radii off the sphere");
        assert!(!inside(&q), "vertex {k} is left in the crater");
        depth = depth.max(original[k].y - q.y);
    }
    // ... in or on the carved body: the crater's wall is a polyhedron inscribed in the
    // sphere.
    let wall: Vec<V> = moved.iter().map(|&k| rest[k]).collect();
    let fit = Embedding::new(b.mesh(), &wall, side).unwrap();
    println!(
        "{} of {count} visual vertices moved onto the crater's wall (ball radius {:.3} mm, \
         dent {:.3} mm deep); {} of them outside the carved tetrahedra, at most {:.4} radii",
        moved.len(),
        radius * 1e3,
        depth * 1e3,
        fit.outside_count(),
        fit.max_distance() / radius
    );
    assert!(depth > 0.5 * radius, "the dent is {depth} deep");
    // The other choice measured: each vertex to the nearest point of the sphere (the
    // crater's wall, about the nearest point of the new simulation surface there). The
    // ball is centred on the surface, so that takes the vertices to the rim: no dent.
    let radial = moved
        .iter()
        .filter_map(|&k| {
            let p = original[k];
            let c = balls.iter().find(|c| (p - c.centre).norm() < c.radius)?;
            let d = p - c.centre;
            (d.norm() > 1e-9 * c.radius).then(|| p.y - (c.centre + d * (c.radius / d.norm())).y)
        })
        .fold(0.0f64, f64::max);
    println!(
        "moved to the nearest point of the sphere instead, the dent would be {:.3} mm deep",
        radial * 1e3
    );
    assert!(depth > radial + 0.5 * radius);
    assert!(fit.max_distance() < 0.1 * radius, "{}", fit.max_distance());
    // Far from the ball, drawn where they were.
    let far: Vec<usize> = (0..count)
        .filter(|&k| {
            balls
                .iter()
                .all(|c| (original[k] - c.centre).norm() > 2.0 * c.radius)
        })
        .collect();
    let far_moved = far
        .iter()
        .map(|&k| Vec3::from_array(before[k]).distance(Vec3::from_array(after[k])))
        .fold(0.0f32, f32::max);
    println!(
        "{} vertices farther than two radii from the ball moved at most {far_moved:.2e} m",
        far.len()
    );
    assert!(far.len() > count / 2);
    assert!(far_moved < 1e-7, "{far_moved}");
    // The heat field follows the new vertices: the crater's wall is burnt.
    let heat = b.heat().unwrap();
    assert_eq!(heat.sample_damage().len(), count);
    let wall_damage = moved
        .iter()
        .map(|&k| heat.sample_damage()[k])
        .fold(f64::INFINITY, f64::min);
    println!("least damage on the crater's wall {wall_damage:.3e}");
    assert!(wall_damage >= 1.0, "{wall_damage}");
    // A reset makes the body whole: the visual mesh is embedded again as it was given.
    app.world_mut()
        .write_message(bevy_soft_tissue::ResetSimulation);
    app.update();
    app.update();
    let visual = app.world().get::<EmbeddedVisual>(body).unwrap();
    assert!(visual.carved().is_empty());
    assert_eq!(visual.rest_positions(), &original[..]);
}

/// Whether the bodies' render meshes are written this frame: a test holds the drawing back
/// so that steps land between two frames drawn.
#[derive(Resource)]
struct Drawing(bool);

fn hold_drawing(app: &mut App) {
    app.insert_resource(Drawing(true));
    app.configure_sets(
        PostUpdate,
        bevy_soft_tissue::SoftTissueMeshSystems.run_if(|d: Res<Drawing>| d.0),
    );
}

/// The block of the dent test is carved at one place, reset (whole again) and carved at
/// another 4 mm away before a frame is drawn, with the first crater drawn before the reset
/// or not. The app's visual mesh is fitted to the second carve alone, from the rest shape
/// it was given: the balls it keeps are the second crater's, every vertex outside them is
/// embedded where it was given (none left in the first crater's dent), those inside lie on
/// the second crater's sphere, and the mesh is drawn where the embedding puts it.
#[test]
fn a_carve_after_a_reset_fits_the_apps_visual_mesh_from_the_shape_it_was_given() {
    let side = 0.012;
    let (lo, hi) = (V::zeros(), V::repeat(side));
    let (first, second) = (V::new(0.004, side, 0.006), V::new(0.008, side, 0.006));
    for drawn_between in [true, false] {
        let source = grid_box(Vec3::ZERO, Vec3::splat(side as f32), 48);
        let original = given_positions(&source);
        let (mut app, body) = burnt_block(1.0 / 64.0, lo, hi, [6, 6, 6], source);
        hold_drawing(&mut app);
        app.world_mut().resource_mut::<Drawing>().0 = drawn_between;
        carve_at(&mut app, body, first);
        if drawn_between {
            let visual = app.world().get::<EmbeddedVisual>(body).unwrap();
            assert!(
                !visual.carved().is_empty(),
                "the first crater was not drawn"
            );
        }
        app.world_mut().resource_mut::<Drawing>().0 = false;
        app.world_mut()
            .write_message(bevy_soft_tissue::ResetSimulation);
        app.update();
        let sim = app.world().get::<SoftBodyState>(body).unwrap();
        assert!(sim.body().cut_record().is_none(), "the reset left a carve");
        carve_at(&mut app, body, second);
        app.world_mut().resource_mut::<Drawing>().0 = true;
        app.update();
        app.update();
        let visual = embedded_visual(&app, body);
        let balls = visual.carved().to_vec();
        let rest = visual.rest_positions();
        let apart = (second - first).norm();
        println!(
            "first crater drawn before the reset: {drawn_between}; the visual mesh keeps {} \
             ball(s) at {:?} mm from the second spot",
            balls.len(),
            balls
                .iter()
                .map(|b| (b.centre - second).norm() * 1e3)
                .collect::<Vec<_>>()
        );
        assert!(!balls.is_empty(), "the second carve was not followed");
        for b in &balls {
            assert!(
                (b.centre - second).norm() < 0.5 * apart,
                "a ball at {} is the first crater's (drawn between: {drawn_between})",
                b.centre
            );
        }
        let inside = |p: &V| {
            balls
                .iter()
                .any(|c| (p - c.centre).norm() < c.radius * (1.0 - 1e-6))
        };
        let mut moved = 0;
        for (k, (p, q)) in original.iter().zip(rest).enumerate() {
            if inside(p) {
                moved += 1;
                let off = radii_off_the_spheres(q, &balls);
                assert!(off < 1e-9, "vertex {k} is {off} radii off the sphere");
            } else {
                assert_eq!(
                    p, q,
                    "vertex {k} outside the second crater is not where it was given \
                     (drawn between: {drawn_between})"
                );
            }
        }
        assert!(moved > 0, "no visual vertex was in the second crater");
        // Drawn where the embedding in the carved body puts it.
        assert!(off_embedding(&app, body) < 1e-7);
    }
}

/// A bar 2 by 10 by 2 cm of liver drawn with a mesh of the app's own is burnt at 10 W on the
/// middle of its top for 0.25 s, then a blade cuts its top 2 cm off. The loose piece is
/// drawn with its simulation surface subdivided twice; its visual vertex nearest the burn
/// shows the damage the core's heat field gives a sample at that rest point (and the colour
/// of burnt tissue), one far from it none.
#[test]
fn a_piece_cut_off_a_burnt_body_draws_its_burn_marks() {
    let dt = 0.005;
    let (lo, hi) = (V::zeros(), V::new(0.02, 0.1, 0.02));
    let source = grid_box(Vec3::ZERO, Vec3::new(0.02, 0.1, 0.02), 16);
    let (mut app, body) = burnt_block(dt, lo, hi, [2, 10, 2], source);
    let burn = V::new(0.01, 0.1, 0.01);
    for _ in 0..50 {
        heat_at(&mut app, body, burn, 10.0);
        app.update();
    }
    // A scalpel's edge along z at 8 cm, across the bar in one step.
    let y = 0.08;
    let along_z = Quat::from_rotation_arc(Vec3::Y, Vec3::Z);
    let blade = app
        .world_mut()
        .spawn((
            soft_tool(ToolShape::Blade { length: 0.06 }),
            Transform::from_xyz(-0.01, y, -0.02).with_rotation(along_z),
        ))
        .id();
    app.update();
    {
        let mut e = app.world_mut().entity_mut(blade);
        e.get_mut::<SoftTool>().unwrap().cut = true;
        e.get_mut::<Transform>().unwrap().translation = Vec3::new(0.04, y, -0.02);
    }
    let mut piece = None;
    for _ in 0..20 {
        app.update();
        app.world_mut()
            .entity_mut(blade)
            .get_mut::<SoftTool>()
            .unwrap()
            .cut = false;
        let mut q = app.world_mut().query_filtered::<Entity, With<CutPiece>>();
        piece = q.iter(app.world()).next();
        if piece.is_some_and(|p| app.world().get::<EmbeddedVisual>(p).is_some()) {
            break;
        }
    }
    assert!(app.world().resource::<SoftTissueStatus>().error.is_none());
    let piece = piece.expect("the top did not come off");
    assert!(
        matches!(
            app.world().get::<VisualMesh>(piece),
            Some(VisualMesh::Subdivided { levels: 2 })
        ),
        "{:?}",
        app.world().get::<VisualMesh>(piece)
    );
    assert_eq!(app.world().get::<VisualMeshError>(piece), None);
    let visual = app
        .world()
        .get::<EmbeddedVisual>(piece)
        .expect("the piece has no visual mesh");
    let rest = visual.rest_positions().to_vec();
    let (corners, weights) = (visual.embedding().corners(), visual.embedding().weights());
    let nearest = (0..rest.len())
        .min_by(|&i, &j| (rest[i] - burn).norm().total_cmp(&(rest[j] - burn).norm()))
        .unwrap();
    let sample = HeatSample {
        position: rest[nearest],
        nodes: std::array::from_fn(|k| (corners[nearest][k], weights[nearest][k])),
    };
    let handle = app.world().get::<Mesh3d>(piece).unwrap().0.clone();
    let mesh = app.world().resource::<Assets<Mesh>>().get(&handle).unwrap();
    let Some(VertexAttributeValues::Float32x4(colours)) = mesh.attribute(Mesh::ATTRIBUTE_COLOR)
    else {
        panic!("the piece's visual mesh has no colours");
    };
    let colour = colours[nearest];
    let mut sim = app.world_mut().get_mut::<SoftBodyState>(piece).unwrap();
    let heat = sim.body_mut().heat_mut().unwrap();
    let drawn_damage = heat.sample_damage()[nearest];
    let least = heat
        .sample_damage()
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    let count = heat.sample_damage().len();
    // The core's damage at the same rest point.
    heat.set_samples(vec![sample]).unwrap();
    let core = heat.sample_damage()[0];
    println!(
        "piece: {count} visual vertices; at {:.2} mm from the burn's centre damage {drawn_damage:.3e} \
         (the core's heat field there {core:.3e}), colour {colour:.3?}; least damage {least:.1e}",
        (rest[nearest] - burn).norm() * 1e3
    );
    assert_eq!(count, rest.len());
    assert!(core >= 1.0, "the piece lost the burn: {core}");
    assert!(
        (drawn_damage - core).abs() <= 1e-6 * core,
        "{drawn_damage} vs {core}"
    );
    assert!(colour[0] < 0.999, "the burn is not drawn: {colour:?}");
    assert_eq!(least, 0.0);
}
