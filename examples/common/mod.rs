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
//! tetrahedra (default 2; 0 draws the simulation surface itself). `--close-up` puts the camera
//! close above where the scripted tool works, without the inspector (the burn it leaves).

mod camera;
mod keys;
mod look;
mod options;
mod panel;
mod screenshot;
mod tool;

use std::path::{Path, PathBuf};

use bevy::prelude::*;
use bevy_egui::EguiPrimaryContextPass;
use bevy_egui::input::egui_wants_any_pointer_input;
use bevy_soft_tissue::core::haptics::{HapticConfig, VirtualDevice};
use bevy_soft_tissue::core::scenario::Scene;
use bevy_soft_tissue::core::world::{Script, SoftTissueWorld};
use bevy_soft_tissue::haptics::HapticTool;
use bevy_soft_tissue::prelude::*;

use camera::{Orbit, orbit_camera};
use keys::keys;
use look::{BodyLook, paint_bodies};
use options::ExampleOptions;
use panel::{Controls, controls_panel};
use screenshot::screenshot;
use tool::{MouseDevice, ToolDriver, mouse_tool, scripted_tool};

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
    // The close-up leaves the inspector out (egui stays, for the controls panel): the burn
    // (or cut) fills the view.
    .add_plugins(if options.close_up {
        SoftTissuePlugins::default()
            .build()
            .disable::<bevy_soft_tissue::inspector::SoftTissueInspectorPlugin>()
            .add(bevy_egui::EguiPlugin::default())
    } else {
        SoftTissuePlugins::default().build()
    })
    // The simulation steps at the fixed timestep: the scene's step (the scene root sets it
    // too, once the scene has loaded).
    .insert_resource(Time::<Fixed>::from_seconds(dt))
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
    // Where the scripted tool works at half its script (for `--close-up`).
    let work_at = script.as_ref().map(|s| {
        let end = s.waypoints.last().map_or(0.0, |w| w.t);
        let (p, _) = s.pose_at(0.5 * end);
        Vec3::new(p.x as f32, p.y as f32, p.z as f32)
    });
    let close_up = options.close_up;
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
            match work_at.filter(|_| close_up) {
                Some(at) => Orbit {
                    focus: at,
                    yaw: 0.0,
                    pitch: -1.1,
                    distance: 0.35 * scale,
                },
                None => Orbit {
                    focus,
                    yaw: 0.0,
                    pitch: -0.35,
                    distance,
                },
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
            probe_radius: radius,
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
