//! The orbit camera: right drag orbits, shift + wheel zooms.

use bevy::input::mouse::{AccumulatedMouseMotion, AccumulatedMouseScroll};
use bevy::prelude::*;

/// The orbit camera's state.
#[derive(Component)]
pub(super) struct Orbit {
    pub(super) focus: Vec3,
    pub(super) yaw: f32,
    pub(super) pitch: f32,
    pub(super) distance: f32,
}

pub(super) fn orbit_camera(
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
