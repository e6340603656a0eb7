//! What the example apps share: window, scene spawning, orbit camera, the mouse tool, keys,
//! the controls panel and the scripted screenshot mode.
//!
//! Controls (also listed in the app):
//! - right mouse drag: orbit the camera; shift + wheel: zoom;
//! - the tool follows the mouse in the screen plane; the wheel moves it nearer or farther;
//!   moving it into a body pokes it;
//! - left button held: pick (grab what the tool touches and drag it); release lets go;
//! - C: toggle the electrocautery (heats what the tool touches);
//! - P: pause / resume, N: single step, R: reset, F12: save a screenshot (the `--screenshot`
//!   file, else `screenshot.png`; later presses add `-2`, `-3`, ...).
//!
//! The mouse moves a virtual haptic device: the tool follows it through the 1 kHz haptic
//! thread's virtual coupling (`HapticTool`), as a force-feedback device would drive it; the
//! force it would render is shown in the controls panel.
//!
//! `--screenshot FILE --frames N` drives the tool with a built-in script instead of the mouse,
//! renders N frames and saves a PNG of the window, then exits (with `--mouse`, the mouse keeps
//! driving the tool: `scripts/mouse-check.sh` moves it with xdotool under Xvfb). `--smooth L` draws each body
//! with its simulation surface refined by L rounds of Loop subdivision and embedded in its
//! tetrahedra (default 2; 0 draws the simulation surface itself).

use std::path::{Path, PathBuf};

use bevy::input::mouse::{AccumulatedMouseMotion, AccumulatedMouseScroll, MouseScrollUnit};
use bevy::prelude::*;
use bevy::render::view::screenshot::{Screenshot, save_to_disk};
use bevy_egui::input::egui_wants_any_pointer_input;
use bevy_egui::{EguiContexts, EguiPrimaryContextPass, egui};
use bevy_soft_tissue::core::haptics::{HapticConfig, VirtualDevice, VirtualDeviceHandle};
use bevy_soft_tissue::core::scenario::Scene;
use bevy_soft_tissue::core::world::{Script, ScriptAction, SoftTissueWorld};
use bevy_soft_tissue::haptics::{CAUTERY_BUTTON, GRAB_BUTTON, HapticTool};
use bevy_soft_tissue::prelude::*;

/// Command-line options of the examples.
#[derive(Resource, Clone, Debug, Default)]
pub struct ExampleOptions {
    /// Save a PNG here after `frames` frames, then exit.
    pub screenshot: Option<PathBuf>,
    /// Frames to render before the screenshot.
    pub frames: u32,
    /// Rounds of subdivision of the drawn surface (0: the simulation surface).
    pub smooth: u8,
    /// With `--screenshot`: the mouse drives the tool instead of the built-in script.
    pub mouse: bool,
    /// `--scene FILE` (relative to the assets folder, or a path): a scene RON file shown
    /// instead of the example's own; `--large` is `scenes/organs-large.scene.ron`.
    pub scene: Option<PathBuf>,
    /// `--surface FILE` (relative to the assets folder): a closed triangle surface (.obj,
    /// .stl, .ply, .gltf, .glb) meshed on load and added as a body beside the scene, drawn with the
    /// surface itself.
    pub surface: Option<String>,
}

impl ExampleOptions {
    /// Parses `--screenshot FILE --frames N --smooth L --mouse --scene FILE --large`.
    pub fn from_args() -> Result<Self, String> {
        let mut o = ExampleOptions {
            screenshot: None,
            frames: 240,
            smooth: 2,
            mouse: false,
            scene: None,
            surface: None,
        };
        let mut args = std::env::args().skip(1);
        while let Some(a) = args.next() {
            match a.as_str() {
                "--screenshot" => {
                    o.screenshot = Some(args.next().ok_or("--screenshot needs a file")?.into())
                }
                "--frames" => {
                    o.frames = args
                        .next()
                        .ok_or("--frames needs a number")?
                        .parse()
                        .map_err(|e| format!("--frames: {e}"))?
                }
                "--mouse" => o.mouse = true,
                "--scene" => o.scene = Some(args.next().ok_or("--scene needs a file")?.into()),
                "--large" => o.scene = Some("scenes/organs-large.scene.ron".into()),
                "--surface" => o.surface = Some(args.next().ok_or("--surface needs a file")?),
                "--smooth" => {
                    o.smooth = args
                        .next()
                        .ok_or("--smooth needs a number")?
                        .parse()
                        .map_err(|e| format!("--smooth: {e}"))?;
                    if o.smooth > 4 {
                        return Err(format!("--smooth {} is more than 4", o.smooth));
                    }
                }
                other => {
                    return Err(format!(
                        "unknown option {other} (--screenshot FILE --frames N --smooth L --mouse \
                         --scene FILE --large --surface FILE)"
                    ));
                }
            }
        }
        Ok(o)
    }
}

/// The scene to show and how.
pub struct ExampleScene {
    /// Window title.
    pub title: &'static str,
    /// The scene file, relative to the assets folder (spawned through the asset server).
    pub scene: &'static str,
    /// Body colours, in scene order (cycled).
    pub colours: Vec<Color>,
    /// Built-in script for the screenshot mode.
    pub script: &'static str,
    /// Cautery power of the C key, W.
    pub cautery_watts: f64,
    /// Extra lines for the controls panel.
    pub extra_controls: Vec<&'static str>,
}

/// Where the tool is driven from.
#[derive(Resource)]
struct ToolDriver {
    tool: Entity,
    /// Distance of the tool from the camera along the mouse ray.
    depth: f32,
    cautery_on: bool,
    cautery_watts: f64,
    script: Option<Script>,
    dt: f64,
    frames: u32,
    shot_requested: bool,
    /// Pictures saved with F12 so far.
    key_shots: u32,
    /// Whether the tool touched something at the last frame (screenshot-mode log).
    touching: bool,
}

/// The orbit camera's state.
#[derive(Component)]
struct Orbit {
    focus: Vec3,
    yaw: f32,
    pitch: f32,
    distance: f32,
}

#[derive(Resource)]
struct Controls(Vec<&'static str>);

/// The virtual haptic device the mouse moves (not in the scripted screenshot mode).
#[derive(Resource)]
struct MouseDevice(VirtualDeviceHandle);

fn assets_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets")
}

/// Builds and runs an example app.
pub fn run(example: ExampleScene, configure: impl FnOnce(&mut App)) -> AppExit {
    let options = match ExampleOptions::from_args() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("{e}");
            return AppExit::error();
        }
    };
    let scene_file = options
        .scene
        .clone()
        .unwrap_or_else(|| PathBuf::from(example.scene));
    // The scene is read here too: the core world of the same scene places the built-in
    // script and the camera around the bodies. The app's bodies come through the asset
    // server.
    let scene = {
        let path = assets_dir().join(&scene_file);
        let loaded = std::fs::read_to_string(&path)
            .map_err(|e| e.to_string())
            .and_then(|text| {
                Scene::from_ron(&text, &path.display().to_string()).map_err(|e| e.to_string())
            });
        match loaded {
            Ok(scene) => scene,
            Err(e) => {
                eprintln!("{}: {e}", path.display());
                return AppExit::error();
            }
        }
    };
    let world = match SoftTissueWorld::from_scene(&scene, &assets_dir()) {
        Ok(w) => w,
        Err(e) => {
            eprintln!("building the scene: {e}");
            return AppExit::error();
        }
    };
    let script = if options.screenshot.is_some() && !options.mouse {
        match Script::builtin(example.script, &world) {
            Ok(s) => Some(s),
            Err(e) => {
                eprintln!("script {}: {e}", example.script);
                return AppExit::error();
            }
        }
    } else {
        None
    };
    let (lo, hi) = world.bodies().iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(lo, hi), b| {
            let bb = b.mesh().bbox();
            let (a, c) = (
                bevy_soft_tissue::convert::to_bevy(&bb.min),
                bevy_soft_tissue::convert::to_bevy(&bb.max),
            );
            (lo.min(a), hi.max(c))
        },
    );
    let scale = (hi - lo).length().max(1e-3);
    let radius = world
        .bodies()
        .iter()
        .map(|b| b.mesh().bbox().smallest_dimension())
        .fold(f64::INFINITY, f64::min)
        * 0.09;
    let dt = world.config().dt;
    drop(world);
    drop(scene);

    let mut app = App::new();
    app.add_plugins(
        DefaultPlugins
            .set(WindowPlugin {
                primary_window: Some(Window {
                    title: example.title.into(),
                    resolution: (1280u32, 720u32).into(),
                    ..default()
                }),
                ..default()
            })
            .set(AssetPlugin {
                file_path: assets_dir().display().to_string(),
                ..default()
            }),
    )
    .add_plugins(SoftTissuePlugins::default())
    // One simulation step per fixed run, at the scene's step.
    .insert_resource(SoftTissueConfig {
        drive_fixed_timestep: true,
        ..default()
    })
    .insert_resource(options.clone())
    .insert_resource(Controls(example.extra_controls.clone()))
    .insert_resource(ClearColor(Color::srgb(0.08, 0.09, 0.11)));

    if options.screenshot.is_some() && !options.mouse {
        // Scripted mode: every frame advances 1/60 s of simulated time however slowly it
        // renders (software Vulkan), so frame N shows the script at N/60 s. (With the mouse,
        // time is real: the haptic thread moves the tool in real time.)
        app.insert_resource(bevy::time::TimeUpdateStrategy::ManualDuration(
            std::time::Duration::from_secs_f64(1.0 / 60.0),
        ));
    }
    let tool_shape = script.as_ref().map(|s| s.tool);
    let colours = example.colours.clone();
    let surface_file = options.surface.clone();
    let cautery_watts = example.cautery_watts;
    let smooth = options.smooth;
    app.add_systems(Startup, move |world: &mut World| {
        let handle = world
            .resource::<AssetServer>()
            .load(scene_file.to_string_lossy().into_owned());
        world.spawn((Name::new("scene"), SoftTissueSceneRoot(handle)));
        if let Some(file) = &surface_file {
            // The user's organ, beside the scene, drawn with its own surface.
            let server = world.resource::<AssetServer>().clone();
            let material = world
                .resource_mut::<Assets<StandardMaterial>>()
                .add(StandardMaterial {
                    base_color: Color::srgb(0.75, 0.5, 0.45),
                    perceptual_roughness: 0.55,
                    ..default()
                });
            world.spawn((
                Name::new(file.clone()),
                SoftBody::new(server.load(file.clone())),
                VisualMesh::mesh(server.load(format!("{file}#Surface"))),
                MeshMaterial3d(material),
                Transform::from_translation(Vec3::new(
                    hi.x + 0.3 * scale,
                    lo.y,
                    0.5 * (lo.z + hi.z),
                )),
            ));
        }
        // The orbit centre sits left of the scene's centre so the bodies clear the inspector.
        let focus = 0.5 * (lo + hi) - Vec3::X * 0.3 * scale;
        let distance = 1.6 * scale;
        let mut tool = SoftTool::sphere(radius);
        if let Some(shape) = tool_shape {
            tool.shape = shape;
        }
        let start = focus + Vec3::new(0.0, 0.0, 0.9 * scale);
        let tool = world
            .spawn((Name::new("tool"), tool, Transform::from_translation(start)))
            .id();
        if tool_shape.is_none() {
            // Mouse mode: the mouse moves a virtual device; the haptic thread (sleeping most
            // of each period, to leave the CPU to the renderer) drives the tool.
            // The hand holding it stops pushing at half the device's 8 N, as a user who
            // feels the tissue would, so a wheel pushed on does not drive the tool through.
            let (device, handle) =
                VirtualDevice::new(bevy_soft_tissue::convert::to_core(start), 8.0);
            let device = device.with_hand(4.0);
            let config = HapticConfig {
                spin_us: 300.0,
                record_seconds: 0.0,
                ..HapticConfig::default()
            };
            match HapticTool::start(Box::new(device), config, cautery_watts) {
                Ok(h) => {
                    world.entity_mut(tool).insert(h);
                    world.insert_resource(MouseDevice(handle));
                }
                Err(e) => error!("haptic thread not started ({e}); the mouse moves the tool"),
            }
        }
        world.spawn((
            Camera3d::default(),
            Orbit {
                focus,
                yaw: 0.0,
                pitch: -0.35,
                distance,
            },
            Transform::default(),
        ));
        world.spawn((
            DirectionalLight {
                illuminance: 9000.0,
                shadow_maps_enabled: true,
                ..default()
            },
            Transform::from_xyz(2.0, 4.0, 3.0).looking_at(Vec3::ZERO, Vec3::Y),
        ));
        world.insert_resource(GlobalAmbientLight {
            brightness: 350.0,
            ..default()
        });
        world.insert_resource(ToolDriver {
            tool,
            depth: distance * 0.75,
            cautery_on: false,
            cautery_watts,
            script: script.clone(),
            dt,
            frames: 0,
            shot_requested: false,
            key_shots: 0,
            touching: false,
        });
    });
    app.insert_resource(BodyLook { colours, smooth });
    app.add_systems(
        Update,
        (
            paint_bodies,
            orbit_camera.run_if(not(egui_wants_any_pointer_input)),
            mouse_tool.run_if(not(egui_wants_any_pointer_input)),
            scripted_tool,
            keys,
            screenshot,
        )
            .chain(),
    )
    .add_systems(EguiPrimaryContextPass, controls_panel);
    configure(&mut app);
    app.run()
}

/// How the scene's bodies are drawn.
#[derive(Resource)]
struct BodyLook {
    colours: Vec<Color>,
    smooth: u8,
}

/// Gives a scene's bodies their colours (in scene order) and smoothed surfaces once the
/// scene has spawned them.
fn paint_bodies(
    mut commands: Commands,
    look: Res<BodyLook>,
    scenes: Query<&SceneBodies, Added<SceneBodies>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
) {
    for bodies in &scenes {
        for (i, e) in bodies.0.iter().enumerate() {
            let material = materials.add(StandardMaterial {
                base_color: look.colours[i % look.colours.len()],
                perceptual_roughness: 0.55,
                ..default()
            });
            let mut body = commands.entity(*e);
            body.insert(MeshMaterial3d(material));
            if look.smooth > 0 {
                body.insert(VisualMesh::Subdivided {
                    levels: look.smooth,
                });
            }
        }
    }
}

fn orbit_camera(
    buttons: Res<ButtonInput<MouseButton>>,
    keys: Res<ButtonInput<KeyCode>>,
    motion: Res<AccumulatedMouseMotion>,
    scroll: Res<AccumulatedMouseScroll>,
    mut cams: Query<(&mut Orbit, &mut Transform)>,
) {
    for (mut o, mut t) in &mut cams {
        if buttons.pressed(MouseButton::Right) {
            o.yaw -= motion.delta.x * 0.005;
            o.pitch = (o.pitch - motion.delta.y * 0.005).clamp(-1.5, 1.5);
        }
        if keys.pressed(KeyCode::ShiftLeft) || keys.pressed(KeyCode::ShiftRight) {
            o.distance *= (1.0 - 0.1 * scroll.delta.y).clamp(0.5, 2.0);
        }
        let rot = Quat::from_rotation_y(o.yaw) * Quat::from_rotation_x(o.pitch);
        *t = Transform::from_translation(o.focus + rot * Vec3::new(0.0, 0.0, o.distance))
            .looking_at(o.focus, Vec3::Y);
    }
}

#[allow(clippy::too_many_arguments)]
fn mouse_tool(
    windows: Query<&Window>,
    cams: Query<(&Camera, &Transform, &Orbit), Without<SoftTool>>,
    buttons: Res<ButtonInput<MouseButton>>,
    keys: Res<ButtonInput<KeyCode>>,
    scroll: Res<AccumulatedMouseScroll>,
    driver: Option<ResMut<ToolDriver>>,
    device: Option<Res<MouseDevice>>,
    mut tools: Query<(&mut Transform, &mut SoftTool)>,
) {
    let Some(mut driver) = driver else { return };
    if driver.script.is_some() {
        return;
    }
    let (Ok(window), Ok((camera, cam_pose, orbit))) = (windows.single(), cams.single()) else {
        return;
    };
    // The camera has no parent and `orbit_camera` placed it just before: its `Transform` is
    // this frame's pose (its `GlobalTransform` is last frame's, identity on the first).
    let cam_pose = GlobalTransform::from(*cam_pose);
    let shift = keys.pressed(KeyCode::ShiftLeft) || keys.pressed(KeyCode::ShiftRight);
    if !shift {
        // One wheel line moves the tool 1 % of the camera distance (a fraction of an organ's
        // thickness, so a poke can be dosed); wheel down is farther. Pixel scrolling
        // (touchpads) counts 40 pixels as a line.
        let lines = match scroll.unit {
            MouseScrollUnit::Line => scroll.delta.y,
            MouseScrollUnit::Pixel => scroll.delta.y / 40.0,
        };
        if lines != 0.0 {
            driver.depth = (driver.depth - 0.01 * orbit.distance * lines)
                .clamp(0.2 * orbit.distance, 1.8 * orbit.distance);
        }
    }
    let Ok((mut pose, mut tool)) = tools.get_mut(driver.tool) else {
        return;
    };
    let target = window
        .cursor_position()
        .and_then(|cursor| camera.viewport_to_world(&cam_pose, cursor).ok())
        .map(|ray| ray.origin + *ray.direction * driver.depth);
    let grab = buttons.pressed(MouseButton::Left);
    if let Some(device) = device {
        // Through the haptic thread: the device goes where the mouse is.
        let position = target.unwrap_or(pose.translation);
        let mut bits = 0;
        if grab {
            bits |= GRAB_BUTTON;
        }
        if driver.cautery_on {
            bits |= CAUTERY_BUTTON;
        }
        device
            .0
            .set(bevy_soft_tissue::convert::to_core(position), bits);
        return;
    }
    if let Some(p) = target {
        pose.translation = p;
    }
    tool.grab = grab;
}

fn scripted_tool(
    driver: Option<Res<ToolDriver>>,
    status: Res<SoftTissueStatus>,
    mut tools: Query<(&mut Transform, &mut SoftTool)>,
) {
    let Some(driver) = driver else { return };
    let Some(script) = &driver.script else { return };
    let Ok((mut pose, mut tool)) = tools.get_mut(driver.tool) else {
        return;
    };
    // The pose for the next step (physics time), and every event up to it.
    let t = (status.steps + 1) as f64 * driver.dt;
    let (p, r) = script.pose_rotation_at(t);
    pose.translation = Vec3::new(p.x as f32, p.y as f32, p.z as f32);
    pose.rotation = Quat::from_xyzw(r.i as f32, r.j as f32, r.k as f32, r.w as f32);
    for e in script.events_in(f64::NEG_INFINITY, t) {
        match e.action {
            ScriptAction::Grab => tool.grab = true,
            ScriptAction::Release => tool.grab = false,
            ScriptAction::Cautery(w) => tool.cautery_watts = w,
            ScriptAction::Jaws(w) => tool.jaws = w,
        }
    }
}

fn keys(
    mut commands: Commands,
    keys: Res<ButtonInput<KeyCode>>,
    options: Res<ExampleOptions>,
    driver: Option<ResMut<ToolDriver>>,
    mut status: ResMut<SoftTissueStatus>,
    mut tools: Query<&mut SoftTool>,
    mut reset: MessageWriter<ResetSimulation>,
) {
    let Some(mut driver) = driver else { return };
    if keys.just_pressed(KeyCode::F12) {
        // The screenshot file (or `screenshot.png`), then `-2`, `-3`, ... for later presses.
        driver.key_shots += 1;
        let base = options
            .screenshot
            .clone()
            .unwrap_or_else(|| PathBuf::from("screenshot.png"));
        let path = if driver.key_shots == 1 {
            base
        } else {
            let stem = base.file_stem().unwrap_or_default().to_string_lossy();
            base.with_file_name(format!("{stem}-{}.png", driver.key_shots))
        };
        info!("frame {}: F12, saving {}", driver.frames, path.display());
        commands
            .spawn(Screenshot::primary_window())
            .observe(save_to_disk(path));
    }
    if keys.just_pressed(KeyCode::KeyC) && driver.script.is_none() {
        driver.cautery_on = !driver.cautery_on;
        if let Ok(mut t) = tools.get_mut(driver.tool) {
            t.cautery_watts = if driver.cautery_on {
                driver.cautery_watts
            } else {
                0.0
            };
        }
    }
    if keys.just_pressed(KeyCode::KeyP) {
        status.paused = !status.paused;
    }
    if keys.just_pressed(KeyCode::KeyN) {
        status.paused = true;
        status.step_once = true;
    }
    if keys.just_pressed(KeyCode::KeyR) {
        reset.write(ResetSimulation);
    }
}

fn screenshot(
    mut commands: Commands,
    options: Res<ExampleOptions>,
    driver: Option<ResMut<ToolDriver>>,
    tools: Query<(&Transform, &ToolReaction)>,
    windows: Query<&Window>,
    device: Option<Res<MouseDevice>>,
    mut exit: MessageWriter<AppExit>,
) {
    let (Some(path), Some(mut driver)) = (&options.screenshot, driver) else {
        return;
    };
    driver.frames += 1;
    if let Ok((pose, reaction)) = tools.get(driver.tool) {
        let touching = reaction.contacts > 0;
        if touching != driver.touching {
            driver.touching = touching;
            info!(
                "frame {}: tool {} at {} ({} contacts)",
                driver.frames,
                if touching { "touches" } else { "leaves" },
                pose.translation,
                reaction.contacts
            );
        }
        if touching && let Some(device) = &device {
            info!(
                "frame {}: touching, tool at {}, tissue force {}, device force {:.2}",
                driver.frames,
                pose.translation,
                reaction.force,
                device.0.force().norm()
            );
        }
        if driver.frames % 50 == 0 {
            let cursor = windows.single().ok().and_then(|w| w.cursor_position());
            info!(
                "frame {}: cursor {cursor:?}, depth {:.3}, tool at {}, {} contacts, force {}",
                driver.frames, driver.depth, pose.translation, reaction.contacts, reaction.force
            );
        }
    }
    if driver.frames == options.frames && !driver.shot_requested && driver.key_shots > 0 {
        // Pictures were taken with F12: leave them.
        info!("frame {}: done", driver.frames);
        exit.write(AppExit::Success);
        return;
    }
    if driver.frames == options.frames && !driver.shot_requested {
        driver.shot_requested = true;
        let _ = std::fs::remove_file(path);
        commands
            .spawn(Screenshot::primary_window())
            .observe(save_to_disk(path.clone()));
    }
    // Exit once the file is written (a few frames later).
    if driver.shot_requested && path.exists() && driver.frames > options.frames + 2 {
        info!("saved {}", path.display());
        exit.write(AppExit::Success);
    }
    if driver.frames > options.frames + 600 {
        error!("the screenshot was not written");
        exit.write(AppExit::error());
    }
}

fn controls_panel(
    mut contexts: EguiContexts,
    controls: Res<Controls>,
    driver: Option<Res<ToolDriver>>,
    device: Option<Res<MouseDevice>>,
) -> Result {
    let ctx = contexts.ctx_mut()?;
    egui::Window::new("Controls")
        .anchor(egui::Align2::RIGHT_TOP, [-10.0, 10.0])
        .resizable(false)
        .show(ctx, |ui| {
            for line in [
                "right drag: orbit, shift + wheel: zoom",
                "mouse: move the tool, wheel: nearer / farther",
                "left button held: pick and drag",
                "C: electrocautery on / off",
                "P: pause, N: step, R: reset, F12: screenshot",
            ]
            .into_iter()
            .chain(controls.0.iter().copied())
            {
                ui.label(line);
            }
            if let Some(d) = driver {
                if d.script.is_some() {
                    ui.strong("scripted interaction (screenshot mode)");
                } else if d.cautery_on {
                    ui.colored_label(egui::Color32::LIGHT_RED, "cautery ON");
                }
            }
            if let Some(device) = device {
                let f = device.0.force();
                ui.label(format!(
                    "haptic force (virtual device, 1 kHz): {:.2} (x {:.2}, y {:.2}, z {:.2})",
                    f.norm(),
                    f.x,
                    f.y,
                    f.z
                ));
            }
        });
    Ok(())
}
