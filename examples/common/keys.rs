//! The keys: C (cautery), X (scalpel: the left button cuts), P (pause), N (step), R (reset),
//! F12 (screenshot).

use std::path::PathBuf;

use bevy::prelude::*;
use bevy::render::view::screenshot::{Screenshot, save_to_disk};
use bevy_soft_tissue::prelude::*;

use super::options::ExampleOptions;
use super::tool::ToolDriver;

pub(super) fn keys(
    mut commands: Commands,
    keys: Res<ButtonInput<KeyCode>>,
    options: Res<ExampleOptions>,
    driver: Option<ResMut<ToolDriver>>,
    mut clock: ResMut<Time<SoftPhysics>>,
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
    if keys.just_pressed(KeyCode::KeyX)
        && driver.script.is_none()
        && let Ok(mut t) = tools.get_mut(driver.tool)
    {
        // The probe becomes a scalpel whose edge stands up from the tip (six of its
        // radii long), and back.
        t.shape = match t.shape {
            ToolShape::Sphere { radius } => {
                driver.probe_radius = radius;
                ToolShape::Blade {
                    length: 6.0 * radius,
                }
            }
            _ => ToolShape::Sphere {
                radius: driver.probe_radius,
            },
        };
        t.cut = false;
        info!("tool: {:?}", t.shape);
    }
    if keys.just_pressed(KeyCode::KeyP) {
        if clock.is_paused() {
            clock.unpause();
        } else {
            clock.pause();
        }
    }
    if keys.just_pressed(KeyCode::KeyN) {
        clock.pause();
        clock.step_once();
    }
    if keys.just_pressed(KeyCode::KeyR) {
        reset.write(ResetSimulation);
    }
}
