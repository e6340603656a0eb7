//! The tool: driven by the mouse through a virtual haptic device, or by a built-in script in
//! the screenshot mode.

use bevy::input::mouse::{AccumulatedMouseScroll, MouseScrollUnit};
use bevy::prelude::*;
use bevy_soft_tissue::core::haptics::VirtualDeviceHandle;
use bevy_soft_tissue::core::world::{Script, ScriptAction};
use bevy_soft_tissue::haptics::{CAUTERY_BUTTON, GRAB_BUTTON};
use bevy_soft_tissue::prelude::*;

use super::camera::Orbit;

/// Where the tool is driven from.
#[derive(Resource)]
pub(super) struct ToolDriver {
    pub(super) tool: Entity,
    /// Distance of the tool from the camera along the mouse ray.
    pub(super) depth: f32,
    pub(super) cautery_on: bool,
    pub(super) cautery_watts: f64,
    pub(super) script: Option<Script>,
    pub(super) dt: f64,
    pub(super) frames: u32,
    pub(super) shot_requested: bool,
    /// Pictures saved with F12 so far.
    pub(super) key_shots: u32,
    /// Whether the tool touched something at the last frame (screenshot-mode log).
    pub(super) touching: bool,
    /// The probe's radius while the tool is a scalpel (X).
    pub(super) probe_radius: f64,
}

/// The virtual haptic device the mouse moves (not in the scripted screenshot mode).
#[derive(Resource)]
pub(super) struct MouseDevice(pub(super) VirtualDeviceHandle);

#[allow(clippy::too_many_arguments)]
pub(super) fn mouse_tool(
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
    // The left button grabs with the probe, cuts with the scalpel.
    let blade = matches!(tool.shape, ToolShape::Blade { .. });
    tool.grab = grab && !blade;
    tool.cut = grab && blade;
}

pub(super) fn scripted_tool(
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
            ScriptAction::Cut(on) => tool.cut = on,
        }
    }
}
