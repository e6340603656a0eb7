//! The scripted screenshot mode: after `--frames` frames a PNG of the window, then exit
//! (with a log of the tool's contacts on the way).

use bevy::prelude::*;
use bevy::render::view::screenshot::{Screenshot, save_to_disk};
use bevy_soft_tissue::prelude::*;

use super::options::ExampleOptions;
use super::tool::{MouseDevice, ToolDriver};

pub(super) fn screenshot(
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
