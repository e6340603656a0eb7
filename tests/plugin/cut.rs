//! Cutting in the plugin: a blade entity cuts a body through; the piece that comes loose is
//! an entity of its own, stepped exactly as the core world steps it; the rendered mesh is
//! made again with the cut sides as vertices of their own; a reset despawns the piece and
//! puts the whole body back.

use super::*;
use bevy_soft_tissue::core::mesh::cut::CutOptions;
use bevy_soft_tissue::core::world::{ScriptEvent, Waypoint};
use bevy_soft_tissue::{CutPiece, RenderedSurface, ResetSimulation, SoftBodyDiagnostics};

/// A scalpel whose edge stands vertical through the whole body `name`, moved along z
/// through its middle from 0.2 s to 0.8 s with cutting on: the body is cut in two halves
/// that both keep their part of its support.
fn through_cut(world: &SoftTissueWorld, name: &str) -> Script {
    let b = &world.bodies()[world.body_index(name).unwrap()];
    let (lo, hi) = b.collider().bounds();
    let x = 0.5 * (lo.x + hi.x) + 0.03 * (hi.x - lo.x);
    let height = hi.y - lo.y;
    let margin = 0.25 * (hi.z - lo.z);
    let w = |t: f64, z: f64| Waypoint {
        t,
        position: [x, lo.y - 0.2 * height, z],
        axis: [0.0, 1.0, 0.0],
        roll_deg: 0.0,
    };
    Script {
        name: "through".into(),
        tool: ToolShape::Blade {
            length: 1.4 * height,
        },
        waypoints: vec![
            w(0.0, lo.z - margin),
            w(0.2, lo.z - margin),
            w(0.8, hi.z + margin),
        ],
        events: vec![
            ScriptEvent {
                t: 0.2,
                action: ScriptAction::Cut(true),
            },
            ScriptEvent {
                t: 0.8,
                action: ScriptAction::Cut(false),
            },
        ],
    }
}

/// Toughness of the cut cylinder, force per scene length.
const TOUGHNESS: f64 = 6.0;

#[test]
fn a_blade_cuts_a_body_in_two_like_the_core_world_and_a_reset_makes_it_whole() {
    let (mut app, bodies, mut world) = scene_app(CYLINDERS);
    // The plugin's default: cuts prepared in the background, landing steps later.
    let options = app.world().resource::<SoftTissueConfig>().cut;
    assert!(options.background_steps > 0);
    world.set_cut_options(options).unwrap();
    let script = through_cut(&world, "Model A");
    let dt = world.config().dt;
    let tool = spawn_tool(&mut app, &script);
    let ti = add_core_tool(&mut world, &script);
    app.update();
    world.step_fixed().unwrap();
    let a = bodies[0];
    // Tissue that resists the cut (a toughness of a hundredth of the cylinder's Young's
    // modulus times a scene unit), in the plugin as in the core world: the blade is held
    // back the same, and the tissue pulled the same.
    app.world_mut()
        .get_mut::<TissueMaterial>(a)
        .unwrap()
        .toughness = TOUGHNESS;
    world.bodies_mut()[0].set_toughness(TOUGHNESS).unwrap();
    let mut resisted = 0;
    let nodes = world.bodies()[0].mesh().node_count();
    let mut piece = None;
    for k in 1..=50 {
        step_both(&mut app, &mut world, (tool, ti), &script, k, dt);
        let reaction = app.world().get::<ToolReaction>(tool).unwrap();
        let core = world.tools()[ti].cutting_resistance();
        assert_eq!(
            reaction.cutting,
            bevy_soft_tissue::convert::to_bevy(&core),
            "step {k}"
        );
        if core.norm() > 0.0 {
            resisted += 1;
        }
        if piece.is_none() {
            let mut q = app.world_mut().query::<(Entity, &CutPiece)>();
            piece = q.iter(app.world()).next().map(|(e, c)| {
                assert_eq!(c.from, a);
                e
            });
        }
        // Every body, the pieces included, as the core world has it.
        let mut entities = bodies.clone();
        entities.extend(piece);
        assert_eq!(world.bodies().len(), entities.len(), "step {k}");
        for (e, b) in entities.iter().zip(world.bodies()) {
            let plugin = app.world().get::<SoftBodyState>(*e).unwrap().body();
            assert_eq!(plugin.name(), b.name());
            assert_eq!(
                plugin.surface_positions(),
                b.surface_positions(),
                "{} differs at step {k}",
                b.name()
            );
        }
    }
    assert!(resisted > 5, "the blade was held back in {resisted} steps");
    let piece = piece.expect("the cut made a piece");
    assert_eq!(
        app.world().get::<Name>(piece).unwrap().as_str(),
        "Model A.1"
    );
    assert!(app.world().get::<SoftBody>(piece).is_some());
    let diag = app.world().get::<SoftBodyDiagnostics>(a).unwrap();
    assert!(diag.cut_faces > 0 && diag.cut_area > 0.0, "{diag:?}");
    // The rendered mesh was made again: the cut sides have vertices of their own.
    app.update();
    for e in [a, piece] {
        let rendered = app.world().get::<RenderedSurface>(e).unwrap();
        assert!(!rendered.inside_vertices().is_empty());
        let handle = app.world().get::<Mesh3d>(e).unwrap().0.clone();
        let p = positions(&app, &handle);
        assert_eq!(p.len(), rendered.inside_vertices().end);
    }
    // A reset: the piece goes, the body is whole again, at rest.
    app.world_mut().write_message(ResetSimulation);
    app.update();
    assert!(app.world().get_entity(piece).is_err(), "the piece is gone");
    let sim = app.world().get::<SoftBodyState>(a).unwrap();
    assert_eq!(sim.body().mesh().node_count(), nodes);
    assert!(sim.body().cut_record().is_none());
}

/// With `CutOptions::land_when_ready` the plugin lands a cut due before its thread is done
/// in a later step, as the core world does: the body is still cut in two, and no landing
/// waited for its thread.
#[test]
fn a_cut_that_lands_when_ready_never_waits_in_the_plugin() {
    let (mut app, bodies, world) = scene_app(CYLINDERS);
    app.world_mut().resource_mut::<SoftTissueConfig>().cut = CutOptions {
        background_steps: 1,
        land_when_ready: true,
        ..CutOptions::default()
    };
    // The blade through the whole body in one step (one cut, prepared while the frames,
    // here much faster than real time, go on).
    let mut script = through_cut(&world, "Model A");
    let dt = world.config().dt;
    script.waypoints[2].t = 0.2 + dt;
    script.events[1].t = 0.2 + 2.0 * dt;
    let tool = spawn_tool(&mut app, &script);
    app.update();
    let a = bodies[0];
    let mut piece = None;
    for k in 1..=5000 {
        drive_tool(&mut app, tool, &script, k, dt);
        app.update();
        let waited = app.world().resource::<SoftTissueStatus>().times.cut_wait_us;
        assert_eq!(waited, 0.0, "frame {k} waited for the cut");
        let mut q = app.world_mut().query::<(Entity, &CutPiece)>();
        piece = q.iter(app.world()).next().map(|(e, _)| e);
        if piece.is_some() {
            break;
        }
    }
    let piece = piece.expect("the cut made a piece");
    for e in [a, piece] {
        let sim = app.world().get::<SoftBodyState>(e).unwrap();
        let r = sim.body().cut_record().expect("a cut body");
        assert_eq!(r.wait_us, 0.0, "a landing waited {} us", r.wait_us);
        assert!(r.closed);
    }
}

/// A blade driven by a haptic device through the haptic thread, cutting tissue with a
/// toughness: after each step the thread is handed the cut (breakaway at the toughness times
/// the edge's length in the body, its whole height here, and the edge's direction), the
/// hand stroking across the edge is held back against its stroke by about that force and
/// not along the edge; with the button released no cut is handed over and the force goes.
#[cfg(feature = "haptics")]
#[test]
fn a_haptic_blade_hands_its_cut_to_the_haptic_thread_and_the_hand_is_held_back() {
    use bevy_soft_tissue::core::haptics::{CUT_BUTTON, CutModel, VirtualDevice};
    use bevy_soft_tissue::haptics::{HapticTool, SoftTissueHapticsPlugin};
    let (mut app, bodies, world) = scene_app(CYLINDERS);
    app.add_plugins(SoftTissueHapticsPlugin);
    let a = bodies[0];
    app.world_mut()
        .get_mut::<TissueMaterial>(a)
        .unwrap()
        .toughness = TOUGHNESS;
    let script = through_cut(&world, "Model A");
    let (lo, hi) = world.bodies()[0].collider().bounds();
    let expected = TOUGHNESS * (hi.y - lo.y);
    let (start, _) = script.pose_at(0.2);
    let middle = bevy_soft_tissue::core::Vec3::new(start.x, start.y, 0.5 * (lo.z + hi.z));
    let (device, handle) = VirtualDevice::new(start, 1e3);
    let mut config = haptic_config();
    // The device limit above the breakaway force.
    config.coupling.max_force = 100.0;
    let haptic = HapticTool::start(Box::new(device), config, 0.0).unwrap();
    // An identity rotation: the edge stands along +y from the tool's position.
    let tool = app
        .world_mut()
        .spawn((soft_tool(script.tool), Transform::default(), haptic))
        .id();
    app.update();
    // Stroke across the edge (+z) into the middle of A with the cut button held, a little
    // each step.
    let mut held = Vec::new();
    let (mut rendering, mut dropped) = (0, 0);
    let steps = 400;
    for k in 1..=steps {
        let s = k as f64 / steps as f64;
        handle.set(start + (middle - start) * s, CUT_BUTTON);
        app.update();
        std::thread::sleep(Duration::from_millis(2));
        let h = app.world().get::<HapticTool>(tool).unwrap();
        let core = app.world().get::<ToolState>(tool).unwrap().tool();
        let cut = *h.cut();
        // What was handed over is the core tool's strength, and the thread has it.
        if core.cutting() && core.cutting_strength() > 0.0 {
            assert_eq!(cut.strength, core.cutting_strength(), "step {k}");
            assert!((cut.edge - bevy_soft_tissue::core::Vec3::y()).norm() < 1e-6);
        } else {
            assert_eq!(cut, CutModel::NONE, "step {k}");
        }
        assert_eq!(h.shared().cut_model(), cut);
        // The hand has been held by a cut for the last 8 steps (the physics finds the edge
        // in tissue in runs of steps: see below).
        rendering = if cut.strength > 1.0 { rendering + 1 } else { 0 };
        dropped += usize::from(core.cutting() && s > 0.3 && cut.strength <= 1.0);
        if rendering > 8 {
            held.push((cut.strength, handle.force()));
        }
    }
    assert!(!held.is_empty(), "the blade never cut A");
    let (last, force) = *held.last().unwrap();
    let strength = held.iter().map(|h| h.0).fold(0.0, f64::max);
    println!(
        "haptic blade in A: breakaway {last:.4} at the end of the stroke, {strength:.4} at \
         most (toughness times A's height {expected:.4}), hand force {force:.4} at the end; \
         held in {} steps, the physics found no edge in A in {dropped} steps of the stroke's \
         last 70 %",
        held.len()
    );
    // Where the edge crosses A whole the length in A is its height, as the tissue deforms a
    // little under the pull. (At the end of the stroke the edge may stand partly outside the
    // tissue it dragged: the proxy the physics steps follows the hand through the haptic
    // thread, whose ticks between two steps depend on the machine's load.)
    assert!((strength - expected).abs() < 0.05 * expected, "{strength}");
    for (strength, force) in &held {
        assert!(force.z < -0.5 * strength, "{force} vs {strength}");
        assert!(force.norm() < 1.5 * strength, "{force} vs {strength}");
        assert!(force.y.abs() < 0.1 * strength, "along the edge {force}");
    }
    // Released: no cut handed over, and the hand is let go.
    let end = handle.force();
    handle.set(middle, 0);
    for _ in 0..100 {
        app.update();
        std::thread::sleep(Duration::from_millis(2));
    }
    let h = app.world().get::<HapticTool>(tool).unwrap();
    assert_eq!(*h.cut(), CutModel::NONE);
    assert!(
        handle.force().norm() < 0.05 * end.norm(),
        "{} after release (from {end}): {:?}, {:?}, {:?}",
        handle.force(),
        h.shared().tool(),
        h.shared().model(),
        h.shared().cut_model()
    );
}

/// A haptic tool's cut stiffness out of range (not finite, or not above 0) is refused where
/// it is set, naming `cut_stiffness` and the value, and the stiffness is kept (it was a
/// public field, and the physics warned of a bad one at every step).
#[cfg(feature = "haptics")]
#[test]
fn a_haptic_cut_stiffness_out_of_range_is_refused_where_it_is_set() {
    use bevy_soft_tissue::core::haptics::{CutModel, HapticError, VirtualDevice};
    use bevy_soft_tissue::haptics::HapticTool;
    let (device, _handle) = VirtualDevice::new(Default::default(), 8.0);
    let config = haptic_config();
    let mut haptic = HapticTool::start(Box::new(device), config, 0.0).unwrap();
    let default = haptic.cut_stiffness();
    assert_eq!(
        default,
        CutModel::STIFFNESS_PER_COUPLING * config.coupling.stiffness
    );
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let e = haptic.set_cut_stiffness(bad).unwrap_err();
        assert!(
            matches!(
                e,
                HapticError::BadConfig { what: "cut_stiffness", value, .. }
                    if value.to_bits() == bad.to_bits()
            ),
            "{e:?}"
        );
        assert!(e.to_string().contains("`cut_stiffness`"), "{e}");
        assert_eq!(haptic.cut_stiffness(), default);
    }
    haptic.set_cut_stiffness(2.0 * default).unwrap();
    assert_eq!(haptic.cut_stiffness(), 2.0 * default);
}
