//! The smallest app: the plugin, one organ from `assets/` with every default, and a tool
//! that follows the mouse (hold the left button to push it into the liver).
//!
//! Run: `cargo run --profile test --example minimal` (the build the tests made; see
//! docs/plugin.md, "Running the examples").

use bevy::prelude::*;
use bevy_soft_tissue::prelude::*;

fn main() {
    App::new()
        .add_plugins((DefaultPlugins, SoftTissuePlugins::default()))
        .add_systems(Startup, setup)
        .add_systems(Update, follow_mouse)
        .run();
}

fn setup(mut commands: Commands, assets: Res<AssetServer>) {
    let liver = SoftBody::new(assets.load("meshes/liver.vtk"));
    commands.spawn((liver, MeshMaterial3d::<StandardMaterial>::default()));
    commands.spawn((SoftTool::sphere(0.08), Transform::from_xyz(0.8, 0.9, 0.6)));
    let eye = Transform::from_xyz(0.8, 0.9, 4.0).looking_at(Vec3::new(0.8, 0.9, 0.0), Vec3::Y);
    commands.spawn((Camera3d::default(), eye));
    let sun = Transform::from_xyz(1.0, 3.0, 2.0).looking_at(Vec3::ZERO, Vec3::Y);
    commands.spawn((DirectionalLight::default(), sun));
}

fn follow_mouse(
    window: Single<&Window>,
    camera: Single<(&Camera, &GlobalTransform)>,
    buttons: Res<ButtonInput<MouseButton>>,
    mut tool: Single<&mut Transform, With<SoftTool>>,
) {
    let (camera, eye) = *camera;
    let cursor = window.cursor_position();
    let Some(ray) = cursor.and_then(|c| camera.viewport_to_world(eye, c).ok()) else {
        return;
    };
    // In front of the liver (its front is at z = 0.42); pressed, it moves in, 0.01 a frame.
    let target = if buttons.pressed(MouseButton::Left) {
        0.2
    } else {
        0.55
    };
    let z = tool.translation.z + (target - tool.translation.z).clamp(-0.01, 0.01);
    if let Some(d) = ray.intersect_plane(Vec3::Z * z, InfinitePlane3d::new(Vec3::Z)) {
        tool.translation = ray.get_point(d);
    }
}
