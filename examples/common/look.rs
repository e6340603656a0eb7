//! How the scene's bodies are drawn: their colours and smoothed surfaces.

use bevy::prelude::*;
use bevy_soft_tissue::prelude::*;

/// How the scene's bodies are drawn.
#[derive(Resource)]
pub(super) struct BodyLook {
    pub(super) colours: Vec<Color>,
    pub(super) smooth: u8,
}

/// Gives a scene's bodies their colours (in scene order) and smoothed surfaces once the
/// scene has spawned them.
pub(super) fn paint_bodies(
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
