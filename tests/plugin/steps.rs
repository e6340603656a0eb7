//! Stepping: a tool raising a body, parity with the core world, determinism, threads,
//! the schedule, pause, reset and a failing stage.

use super::*;

#[test]
fn a_tool_raises_a_body_its_release_returns_it_and_the_mesh_follows() {
    let (mut app, bodies, world) = scene_app(CYLINDERS);
    let (script, tool, dt) = scripted_tool(&mut app, &world, "poke-a");
    let (a, b) = (bodies[0], bodies[1]);
    app.update();
    let handle = app.world().get::<Mesh3d>(a).unwrap().0.clone();
    let initial = positions(&app, &handle);
    let mut raised = false;
    let mut changes = Vec::new();
    let mut moved: f32 = 0.0;
    for k in 1..=900 {
        drive_tool(&mut app, tool, &script, k, dt);
        app.update();
        raised |= level(&app, a) == Level::Precise;
        assert_eq!(level(&app, b), Level::Cage, "B is never touched");
        let now = positions(&app, &handle);
        moved = moved.max(
            now.iter()
                .zip(&initial)
                .map(|(p, q)| Vec3::from_array(*p).distance(Vec3::from_array(*q)))
                .fold(0.0, f32::max),
        );
        let msgs = app.world().resource::<Messages<LevelChanged>>();
        changes.extend(msgs.iter_current_update_messages().copied());
    }
    assert!(raised, "the poke raised A");
    assert_eq!(level(&app, a), Level::Cage, "A returned to its cage");
    assert!(
        moved > 0.01,
        "the rendered mesh followed the poke ({moved})"
    );
    assert_eq!(changes.len(), 2, "{changes:?}");
    assert_eq!((changes[0].entity, changes[0].to), (a, Level::Precise));
    assert_eq!((changes[1].entity, changes[1].to), (a, Level::Cage));
    assert!(changes.iter().all(|c| c.jump_ratio < 0.005));
    let reaction = app.world().get::<ToolReaction>(tool).unwrap();
    assert!(reaction.force.is_finite());
}

fn run_plugin(file: &str, script_name: &str, steps: usize) -> Vec<Vec<Vec<[f32; 3]>>> {
    run_plugin_on(file, script_name, steps, None)
}

/// [`run_plugin`] with `SoftTissueConfig::threads` set (`None`: the default).
fn run_plugin_on(
    file: &str,
    script_name: &str,
    steps: usize,
    threads: Option<usize>,
) -> Vec<Vec<Vec<[f32; 3]>>> {
    let (mut app, bodies, world) = scene_app(file);
    if let Some(n) = threads {
        app.world_mut().resource_mut::<SoftTissueConfig>().threads = n;
    }
    let (script, tool, dt) = scripted_tool(&mut app, &world, script_name);
    let mut out = Vec::new();
    app.update();
    for k in 1..=steps {
        drive_tool(&mut app, tool, &script, k, dt);
        app.update();
        out.push(surfaces(&app, &bodies));
    }
    out
}

#[test]
fn the_plugin_and_the_core_world_give_the_same_states() {
    let (mut app, bodies, mut world) = scene_app(CYLINDERS);
    let (script, tool, dt) = scripted_tool(&mut app, &world, "push-a-into-b");
    let ti = add_core_tool(&mut world, &script);
    // The first update builds the bodies (and steps once with the tool at its start).
    app.update();
    world.step_fixed().unwrap();
    let mut precise_steps = 0;
    for k in 1..=600 {
        step_both(&mut app, &mut world, (tool, ti), &script, k, dt);
        for (e, b) in bodies.iter().zip(world.bodies()) {
            let plugin = app.world().get::<SoftBodyState>(*e).unwrap().body();
            assert_eq!(
                plugin.surface_positions(),
                b.surface_positions(),
                "{} differs at step {k}",
                b.name()
            );
            assert_eq!(plugin.model().level(), b.model().level());
            if b.model().level() == bevy_soft_tissue::core::precision::Level::Precise {
                precise_steps += 1;
            }
        }
    }
    assert!(precise_steps > 100, "the push must raise the bodies");
    assert_eq!(
        app.world().resource::<SoftTissueStatus>().steps,
        world.step_count()
    );
}

#[test]
fn two_runs_are_bit_identical() {
    let a = run_plugin(CYLINDERS, "poke-a", 300);
    let b = run_plugin(CYLINDERS, "poke-a", 300);
    assert_eq!(a, b);
}

/// The organs under a poke of the liver, every body at its precise level most of the time:
/// the same surfaces at every step on one thread and on two (and the pool is used).
#[test]
fn one_and_two_threads_give_bit_identical_states() {
    let one = run_plugin_on(ORGANS, "poke-liver", 200, Some(1));
    let two = run_plugin_on(ORGANS, "poke-liver", 200, Some(2));
    assert_eq!(one.len(), 200);
    assert_eq!(one, two);
    let (mut app, _, _) = scene_app(ORGANS);
    app.world_mut().resource_mut::<SoftTissueConfig>().threads = 2;
    app.update();
    app.update();
    assert_eq!(app.world().resource::<SoftTissueThreads>().count(), 2);
}

#[test]
fn the_step_has_no_system_order_ambiguity() {
    let (mut app, _, _) = scene_app(CYLINDERS);
    let labels = [
        SoftTissueSchedule.intern(),
        FixedUpdate.intern(),
        PostUpdate.intern(),
    ];
    for label in labels {
        app.edit_schedule(label, |s| {
            s.set_build_settings(ScheduleBuildSettings {
                ambiguity_detection: LogLevel::Error,
                ..default()
            });
        });
    }
    let world = app.world_mut();
    for label in labels {
        world.schedule_scope(label, |world, schedule| {
            schedule
                .initialize(world)
                .unwrap_or_else(|e| panic!("{label:?}: {e}"));
        });
    }
}

#[test]
fn pause_single_step_method_change_and_reset() {
    let (mut app, bodies, _) = scene_app(CYLINDERS);
    app.update();
    let steps = |app: &App| app.world().resource::<SoftTissueStatus>().steps;
    assert_eq!(steps(&app), 1);
    fn clock(app: &mut App) -> Mut<'_, Time<SoftPhysics>> {
        app.world_mut().resource_mut::<Time<SoftPhysics>>()
    }
    clock(&mut app).pause();
    app.update();
    app.update();
    assert_eq!(steps(&app), 1, "paused");
    clock(&mut app).step_once();
    app.update();
    app.update();
    assert_eq!(steps(&app), 2, "exactly one step");
    clock(&mut app).unpause();
    // Method changed at run time.
    app.world_mut()
        .get_mut::<SoftBody>(bodies[0])
        .unwrap()
        .method = PreciseMethod::CorotationalFem;
    app.update();
    let pl = *app.world().get::<PrecisionLevel>(bodies[0]).unwrap();
    assert_eq!(pl.method, PreciseMethod::CorotationalFem);
    // Pinned up, then reset.
    app.world_mut()
        .entity_mut(bodies[1])
        .insert(PinnedLevel(Level::Precise));
    app.update();
    assert_eq!(level(&app, bodies[1]), Level::Precise);
    // Unpinned it stays up until it rests; a reset brings everything back to the start.
    app.world_mut()
        .entity_mut(bodies[1])
        .remove::<PinnedLevel>();
    app.update();
    app.world_mut().write_message(ResetSimulation);
    app.update();
    assert_eq!(steps(&app), 1, "reset, then one step");
    assert_eq!(level(&app, bodies[1]), Level::Cage);
    assert!(app.world().resource::<SoftTissueStatus>().error.is_none());
    // The read-out components follow the reset though the body now sleeps: its cage is the
    // active level again, at rest.
    let cage = app.world().get::<GreenCage>(bodies[1]).unwrap();
    assert!(
        cage.active,
        "the cage component still shows the precise level"
    );
    let sim = app.world().get::<SoftBodyState>(bodies[1]).unwrap().body();
    let rest = sim.model().cage().cage().vertices();
    for (v, r) in cage.vertices.iter().zip(rest) {
        assert!((*v - bevy_soft_tissue::convert::to_bevy(r)).length() < 1e-5);
    }
}

/// The clock owns pause, speed and the step: the step is the fixed timestep, one step per
/// fixed run at speed 1, one every second run at 0.5, two a run at 2; a refused speed keeps
/// the speed; `step_once` queues steps while paused; simulated time is the steps run times
/// the step, and the step's systems read that clock as `Res<Time>`; a new fixed timestep
/// builds the bodies again at it.
#[test]
fn the_clock_owns_pause_speed_and_the_step() {
    #[derive(Resource, Default)]
    struct Seen(Vec<f64>);
    let (mut app, bodies, world) = scene_app(CYLINDERS);
    let dt = world.config().dt;
    app.init_resource::<Seen>();
    app.add_systems(
        SoftTissueSchedule,
        (|t: Res<Time>, mut seen: ResMut<Seen>| seen.0.push(t.delta_secs_f64()))
            .in_set(SoftTissueSystems::First),
    );
    fn clock(app: &mut App) -> Mut<'_, Time<SoftPhysics>> {
        app.world_mut().resource_mut::<Time<SoftPhysics>>()
    }
    let run = |app: &mut App, n: usize| {
        let before = app.world().resource::<SoftTissueStatus>().steps;
        for _ in 0..n {
            app.update();
        }
        app.world().resource::<SoftTissueStatus>().steps - before
    };
    assert_eq!(run(&mut app, 4), 4, "one step per fixed run");
    assert_eq!(clock(&mut app).timestep().as_secs_f64(), dt);
    clock(&mut app).set_relative_speed(0.5).unwrap();
    assert_eq!(run(&mut app, 10), 5, "half speed");
    clock(&mut app).set_relative_speed(2.0).unwrap();
    assert_eq!(run(&mut app, 3), 6, "double speed");
    let refused = clock(&mut app).set_relative_speed(-1.0);
    assert_eq!(refused, Err(bevy_soft_tissue::BadSpeed(-1.0)));
    assert_eq!(clock(&mut app).relative_speed(), 2.0);
    clock(&mut app).set_relative_speed(1.0).unwrap();
    clock(&mut app).pause();
    assert_eq!(run(&mut app, 3), 0, "paused");
    clock(&mut app).step_once();
    clock(&mut app).step_once();
    assert_eq!(run(&mut app, 1), 2, "two steps asked for");
    assert_eq!(run(&mut app, 2), 0, "paused again");
    clock(&mut app).unpause();
    assert_eq!(run(&mut app, 2), 2);
    let steps = app.world().resource::<SoftTissueStatus>().steps;
    let elapsed = clock(&mut app).elapsed_secs_f64();
    assert!((elapsed - steps as f64 * dt).abs() < 1e-9, "{elapsed} s");
    let seen = &app.world().resource::<Seen>().0;
    assert_eq!(seen.len() as u64, steps, "every step");
    assert!(seen.iter().all(|&d| d == dt), "{seen:?}");
    // A new fixed timestep is the step: the bodies are built again at it.
    app.world_mut()
        .resource_mut::<Time<Fixed>>()
        .set_timestep(Duration::from_secs_f64(dt / 2.0));
    run(&mut app, 2);
    assert_eq!(clock(&mut app).timestep().as_secs_f64(), dt / 2.0);
    for b in bodies {
        let sim = app.world().get::<SoftBodyState>(b).unwrap();
        assert_eq!(sim.body().model().settings().dt, dt / 2.0);
    }
}

#[test]
fn a_failed_stage_stops_the_step_there_and_no_nan_reaches_a_mesh() {
    let (mut app, bodies, world) = scene_app(CYLINDERS);
    let (script, tool, dt) = scripted_tool(&mut app, &world, "poke-a");
    let a = bodies[0];
    app.update();
    let mut k = 0;
    while level(&app, a) != Level::Precise {
        k += 1;
        assert!(k < 400, "the poke never raised A");
        drive_tool(&mut app, tool, &script, k, dt);
        app.update();
    }
    let status = |app: &App| app.world().resource::<SoftTissueStatus>().clone();
    let handle = app.world().get::<Mesh3d>(a).unwrap().0.clone();
    let mesh_before = positions(&app, &handle);
    let surfaces_before = surfaces(&app, &bodies);
    let steps = status(&app).steps;
    // The tool's pose goes bad: the prepare stage fails on it.
    app.world_mut()
        .get_mut::<Transform>(tool)
        .unwrap()
        .translation
        .x = f32::NAN;
    app.update();
    let s = status(&app);
    let error = s.error.clone().expect("the step failed");
    assert!(error.to_string().contains("tool"), "{error}");
    assert_eq!(error.body, Some(tool), "the error names the tool's entity");
    assert_eq!(error.stage, bevy_soft_tissue::SoftTissueStage::Prepare);
    // The core's error comes typed: the tool refused a position that is not finite.
    use bevy_soft_tissue::core::contact::ContactError;
    let source = error
        .downcast_ref::<ContactError>()
        .unwrap_or_else(|| panic!("not a ContactError: {:?}", error.error));
    assert!(
        matches!(
            source,
            ContactError::BadTool {
                what: "position (not finite)",
                ..
            }
        ),
        "{source:?}"
    );
    // The display ends with that error's; the chain goes on from its own source (none).
    assert!(error.to_string().ends_with(&source.to_string()), "{error}");
    assert!(std::error::Error::source(&error).is_none());
    assert!(
        app.world().resource::<Time<SoftPhysics>>().is_paused(),
        "the failure paused the clock"
    );
    // The stages after the failing one did not run: no step was counted, no state moved,
    // and the rendered mesh kept its finite positions.
    assert_eq!(s.steps, steps);
    assert_eq!(surfaces(&app, &bodies), surfaces_before);
    let mesh_now = positions(&app, &handle);
    assert_eq!(mesh_now, mesh_before);
    assert!(mesh_now.iter().flatten().all(|c| c.is_finite()));
    // Unpaused with the error still set, nothing runs.
    app.world_mut()
        .resource_mut::<Time<SoftPhysics>>()
        .unpause();
    app.update();
    assert_eq!(status(&app).steps, steps);
    // A reset clears the error though the simulation is stopped, and steps run again.
    drive_tool(&mut app, tool, &script, 0, dt);
    app.world_mut().write_message(ResetSimulation);
    app.update();
    let s = status(&app);
    assert!(s.error.is_none(), "{:?}", s.error);
    assert_eq!(s.steps, 1);
    assert!(
        positions(&app, &handle)
            .iter()
            .flatten()
            .all(|c| c.is_finite())
    );
}

/// Two copies of one scene in an app have bodies of the same names: a failure of a body of
/// the second copy names that body's entity, not its namesake's in the first.
#[test]
fn a_failure_names_the_failing_body_among_namesakes() {
    let (mut app, first, _) = scene_app(CYLINDERS);
    let second = bevy_soft_tissue::spawn_scene_and_wait(&mut app, CYLINDERS).unwrap();
    app.update();
    let name = |app: &App, e: Entity| {
        app.world()
            .get::<SoftBodyState>(e)
            .unwrap()
            .body()
            .name()
            .to_string()
    };
    assert_eq!(name(&app, first[0]), name(&app, second[0]), "namesakes");
    let culprit = second[0];
    app.world_mut()
        .entity_mut(culprit)
        .insert(PinnedLevel(Level::Precise));
    for _ in 0..3 {
        app.update();
    }
    assert_eq!(level(&app, culprit), Level::Precise);
    assert!(app.world().resource::<SoftTissueStatus>().error.is_none());
    // A non-finite position in its precise state: the step refuses it, naming the body.
    {
        let mut sim = app.world_mut().get_mut::<SoftBodyState>(culprit).unwrap();
        let body = sim.body_mut().model_mut();
        body.precise_mut().positions_mut()[0].x = f64::NAN;
    }
    app.update();
    let error = app
        .world()
        .resource::<SoftTissueStatus>()
        .error
        .clone()
        .expect("the step failed");
    assert_eq!(error.body, Some(culprit), "{error}");
    assert_eq!(error.stage, bevy_soft_tissue::SoftTissueStage::StepSolvers);
}
