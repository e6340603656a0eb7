//! The controls panel: the keys, the example's own lines, the cautery and the haptic force.

use bevy::prelude::*;
use bevy_egui::{EguiContexts, egui};

use super::tool::{MouseDevice, ToolDriver};

#[derive(Resource)]
pub(super) struct Controls(pub(super) Vec<&'static str>);

pub(super) fn controls_panel(
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
