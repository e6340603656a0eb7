//! Headless benchmark of the plugin against the engine-free core world: the same scene and
//! tool script stepped by `SoftTissueWorld` and by the plugin in a `MinimalPlugins` app (one
//! fixed step per update), runs alternating so that the machine's drift hits both alike. Prints
//! one JSON object: the core's whole step, the plugin's whole physics step (from its `First` to
//! its `Last` set), the plugin's whole frame (`App::update` of `MinimalPlugins` and ours, the
//! render-mesh writes included), each stage of both (median, 99th percentile, largest, mean,
//! microseconds) and the ratios. The plugin's first step, which builds the bodies, is left
//! out (the core world builds them before stepping).
//!
//! Run (release, no renderer needed):
//! `cargo run --release --no-default-features --example plugin_bench -- [--scene organs]
//! [--script poke-liver] [--steps 700] [--runs 3] [--threads N]` (`--scene` names a built-in
//! scene or a scene file relative to the assets folder; `--threads` sets
//! `SoftTissueConfig::threads`, 0 for every core, the default)

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use bevy::prelude::*;
use bevy::time::TimeUpdateStrategy;
use bevy_soft_tissue::core::contact::Tool;
use bevy_soft_tissue::core::scenario::Scene;
use bevy_soft_tissue::core::timing::{StageRecorder, StageTimes, TimeStats};
use bevy_soft_tissue::core::world::{Script, ScriptAction, SoftTissueWorld};
use bevy_soft_tissue::prelude::*;
use bevy_soft_tissue::{SoftTissueAssetPlugin, SoftTissueMeshPlugin, SoftTissuePhysicsPlugin};

struct Args {
    scene: String,
    script: String,
    steps: usize,
    runs: usize,
    /// `SoftTissueConfig::threads` (0: every core).
    threads: usize,
    assets: PathBuf,
}

fn args() -> Result<Args, String> {
    let mut a = Args {
        scene: "organs".into(),
        script: "poke-liver".into(),
        steps: 700,
        runs: 3,
        threads: 0,
        assets: Path::new(env!("CARGO_MANIFEST_DIR")).join("assets"),
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let value = it.next().ok_or_else(|| format!("{flag} needs a value"))?;
        let number = |v: &str| {
            v.parse::<usize>()
                .map_err(|e| format!("{flag} {v}: {e}"))
                .and_then(|n| {
                    (n > 0 && n <= 1_000_000)
                        .then_some(n)
                        .ok_or_else(|| format!("{flag} {v}: out of range (1 ..= 1000000)"))
                })
        };
        match flag.as_str() {
            "--scene" => a.scene = value,
            "--script" => a.script = value,
            "--steps" => a.steps = number(&value)?,
            "--runs" => a.runs = number(&value)?,
            "--threads" => {
                a.threads = value
                    .parse()
                    .map_err(|e| format!("--threads {value}: {e}"))?
            }
            "--assets" => a.assets = value.into(),
            other => return Err(format!("unknown flag {other}")),
        }
    }
    Ok(a)
}

/// The scene file, relative to the assets folder.
fn scene_file(a: &Args) -> String {
    match a.scene.as_str() {
        "organs" | "cylinders" => format!("scenes/{}.scene.ron", a.scene),
        file => file.to_owned(),
    }
}

fn load_scene(a: &Args) -> Result<Scene, Box<dyn std::error::Error>> {
    let path = a.assets.join(scene_file(a));
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(Scene::from_ron(&text, &path.display().to_string())?)
}

fn load_script(a: &Args, world: &SoftTissueWorld) -> Result<Script, Box<dyn std::error::Error>> {
    if a.script.ends_with(".ron") {
        let text = std::fs::read_to_string(&a.script).map_err(|e| format!("{}: {e}", a.script))?;
        Ok(Script::from_ron(&text, &a.script)?)
    } else {
        Ok(Script::builtin(&a.script, world)?)
    }
}

/// The core world's steps: whole-step wall time and stage times.
fn run_core(
    scene: &Scene,
    script: &Script,
    a: &Args,
    out: &mut StageRecorder,
) -> Result<(), Box<dyn std::error::Error>> {
    let mut world = SoftTissueWorld::from_scene(scene, &a.assets)?;
    let tool = world.add_tool(Tool::new("tool", script.tool)?);
    let dt = world.config().dt;
    for k in 1..=a.steps {
        let t = k as f64 * dt;
        let (p, r) = script.pose_rotation_at(t);
        let tl = &mut world.tools_mut()[tool];
        tl.set_pose_rotation(p, r)?;
        for e in script.events_in(t - dt, t) {
            e.action.apply(tl)?;
        }
        world.step_fixed()?;
        out.push(&world.stage_times());
    }
    Ok(())
}

/// Wall time of the plugin's physics step, from its `First` set to its `Last` set.
#[derive(Resource, Default)]
struct PhysicsClock {
    start: Option<Instant>,
    last_us: f64,
}

fn clock_start(mut c: ResMut<PhysicsClock>) {
    c.start = Some(Instant::now());
}

fn clock_stop(mut c: ResMut<PhysicsClock>) {
    if let Some(s) = c.start.take() {
        c.last_us = s.elapsed().as_secs_f64() * 1e6;
    }
}

fn tool_transform(script: &Script, t: f64) -> Transform {
    let (p, r) = script.pose_rotation_at(t);
    Transform::from_xyz(p.x as f32, p.y as f32, p.z as f32).with_rotation(Quat::from_xyzw(
        r.i as f32, r.j as f32, r.k as f32, r.w as f32,
    ))
}

/// The plugin's steps: its physics step (`First`..`Last`, as stage times with the whole
/// step measured around them) and its whole frame.
fn run_plugin(
    script: &Script,
    dt: f64,
    a: &Args,
    physics: &mut StageRecorder,
    frames: &mut Vec<f64>,
) -> Result<(), Box<dyn std::error::Error>> {
    let mut app = App::new();
    app.add_plugins((
        MinimalPlugins,
        TransformPlugin,
        AssetPlugin {
            file_path: a.assets.display().to_string(),
            ..default()
        },
        SoftTissueAssetPlugin,
        SoftTissuePhysicsPlugin::default(),
        SoftTissueMeshPlugin,
    ));
    app.insert_resource(Time::<Fixed>::from_seconds(dt));
    app.insert_resource(TimeUpdateStrategy::ManualDuration(Duration::from_secs_f64(
        dt,
    )));
    app.init_resource::<PhysicsClock>();
    app.add_systems(
        SoftTissueSchedule,
        (
            clock_start.in_set(SoftTissueSystems::First),
            clock_stop.in_set(SoftTissueSystems::Last),
        ),
    );
    app.update();
    bevy_soft_tissue::spawn_scene_and_wait(&mut app, &scene_file(a))?;
    app.world_mut()
        .resource_mut::<bevy_soft_tissue::SoftTissueConfig>()
        .threads = a.threads;
    let tool = app
        .world_mut()
        .spawn((
            SoftTool {
                shape: script.tool,
                grab: false,
                cautery_watts: 0.0,
                electrode_radius: Some(1e-3),
                jaws: 0.0,
                cut: false,
                friction: Default::default(),
            },
            tool_transform(script, 0.0),
        ))
        .id();
    for k in 1..=a.steps {
        let t = k as f64 * dt;
        let tf = tool_transform(script, t);
        {
            let mut e = app.world_mut().entity_mut(tool);
            *e.get_mut::<Transform>().ok_or("tool transform")? = tf;
            let mut spec = e.get_mut::<SoftTool>().ok_or("tool")?;
            for ev in script.events_in(t - dt, t) {
                match ev.action {
                    ScriptAction::Grab => spec.grab = true,
                    ScriptAction::Release => spec.grab = false,
                    ScriptAction::Cautery(w) => spec.cautery_watts = w,
                    ScriptAction::Jaws(w) => spec.jaws = w,
                    ScriptAction::Cut(on) => spec.cut = on,
                }
            }
        }
        let start = Instant::now();
        app.update();
        let frame_us = start.elapsed().as_secs_f64() * 1e6;
        let status = app.world().resource::<SoftTissueStatus>();
        if let Some(e) = &status.error {
            return Err(format!("step {k}: {e}").into());
        }
        // The stages as the plugin timed them; the whole step as the clock around them saw
        // it (ECS scheduling between the stages included), in the prepare slot's place.
        let mut times = status.times;
        let whole = app.world().resource::<PhysicsClock>().last_us;
        times.prepare_us += (whole - times.total_us()).max(0.0);
        // The first step builds the bodies (the core world builds them before its first
        // step): not a step's cost.
        if k > 1 {
            physics.push(&times);
            frames.push(frame_us);
        }
    }
    Ok(())
}

/// Frames of a bare `MinimalPlugins` app (the same time settings, no soft tissue): what the
/// engine costs per frame on this machine whatever runs in it.
fn run_bare(dt: f64, steps: usize, frames: &mut Vec<f64>) {
    let mut app = App::new();
    app.add_plugins((MinimalPlugins, TransformPlugin));
    app.insert_resource(Time::<Fixed>::from_seconds(dt));
    app.insert_resource(TimeUpdateStrategy::ManualDuration(Duration::from_secs_f64(
        dt,
    )));
    app.update();
    for _ in 0..steps {
        let start = Instant::now();
        app.update();
        frames.push(start.elapsed().as_secs_f64() * 1e6);
    }
}

fn stats_json(s: &TimeStats) -> serde_json::Value {
    serde_json::json!({
        "median_us": s.median_us, "p99_us": s.p99_us, "max_us": s.max_us, "mean_us": s.mean_us,
        "count": s.count,
    })
}

fn recorder_json(r: &StageRecorder) -> serde_json::Value {
    let s = r.summary();
    let stages: serde_json::Map<String, serde_json::Value> = StageTimes::NAMES
        .iter()
        .zip(&s.stages)
        .map(|(n, t)| (n.to_string(), stats_json(t)))
        .collect();
    serde_json::json!({ "step": stats_json(&s.step), "stages": stages })
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a = args()?;
    let scene = load_scene(&a)?;
    let probe = SoftTissueWorld::from_scene(&scene, &a.assets)?;
    let script = load_script(&a, &probe)?;
    let dt = probe.config().dt;
    drop(probe);
    let mut core = StageRecorder::with_capacity(a.steps * a.runs);
    let mut plugin = StageRecorder::with_capacity(a.steps * a.runs);
    let mut frames = Vec::with_capacity(a.steps * a.runs);
    let mut bare = Vec::with_capacity(a.steps * a.runs);
    for _ in 0..a.runs {
        run_core(&scene, &script, &a, &mut core)?;
        run_plugin(&script, dt, &a, &mut plugin, &mut frames)?;
        run_bare(dt, a.steps, &mut bare);
    }
    let (c, p) = (core.summary(), plugin.summary());
    let frame = TimeStats::of(&frames);
    let bare = TimeStats::of(&bare);
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let out = serde_json::json!({
        "scene": scene.name,
        "script": script.name,
        "steps_per_run": a.steps,
        "runs": a.runs,
        "cores": cores,
        "build": if cfg!(debug_assertions) { "debug" } else { "optimised" },
        "core": recorder_json(&core),
        "plugin": recorder_json(&plugin),
        "plugin_frame": stats_json(&frame),
        "bare_minimal_frame": stats_json(&bare),
        "plugin_over_core": {
            "median": p.step.median_us / c.step.median_us,
            "mean": p.step.mean_us / c.step.mean_us,
            "p99": p.step.p99_us / c.step.p99_us,
        },
        "frame_over_core_mean": frame.mean_us / c.step.mean_us,
        "frame_beyond_bare_over_core_mean": (frame.mean_us - bare.mean_us) / c.step.mean_us,
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}
