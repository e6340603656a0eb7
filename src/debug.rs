//! Debug gizmos (feature `debug-render`): the cage of every body at the cage level (the
//! paper's Fig. 1), tools, their contact count and reaction force.

use bevy::prelude::*;

use crate::components::{GreenCage, SoftBodyState, SoftTool, ToolReaction};
use crate::convert::to_bevy;
use crate::physics::SoftTissueContacts;

/// What the debug gizmos draw (a resource; toggle at run time).
#[derive(Resource, Clone, Copy, Debug)]
pub struct SoftTissueDebugSettings {
    /// Cage edges of bodies at the cage level.
    pub cages: bool,
    /// Tool shapes (green when free, orange in contact) and reaction forces.
    pub tools: bool,
    /// Contact points of the last step with their normals (tool contacts yellow, body
    /// contacts magenta).
    pub contacts: bool,
    /// Length of the drawn reaction force per newton, scene units.
    pub force_scale: f32,
    /// Length of a drawn contact normal, scene units.
    pub contact_size: f32,
}

impl Default for SoftTissueDebugSettings {
    fn default() -> Self {
        SoftTissueDebugSettings {
            cages: true,
            tools: true,
            contacts: true,
            force_scale: 0.05,
            contact_size: 0.08,
        }
    }
}

/// Adds the debug gizmos (needs Bevy's gizmo plugin, part of `DefaultPlugins`).
#[derive(Default)]
pub struct SoftTissueDebugPlugin;

impl Plugin for SoftTissueDebugPlugin {
    fn build(&self, app: &mut App) {
        app.init_resource::<SoftTissueDebugSettings>()
            .init_gizmo_group::<SoftTissueContactGizmos>()
            .add_systems(Startup, configure_contact_gizmos)
            .add_systems(Update, (draw_cages, draw_tools, draw_contacts));
    }
}

/// The gizmo group of contact points: drawn over the meshes (a contact lies on the simulation
/// surface, which a smoothed visual mesh may cover) with thicker lines.
#[derive(Default, Reflect, GizmoConfigGroup)]
pub struct SoftTissueContactGizmos;

fn configure_contact_gizmos(mut store: ResMut<GizmoConfigStore>) {
    let (config, _) = store.config_mut::<SoftTissueContactGizmos>();
    config.depth_bias = -1.0;
    config.line.width = 3.0;
}

fn draw_cages(
    settings: Res<SoftTissueDebugSettings>,
    cages: Query<&GreenCage>,
    mut gizmos: Gizmos,
) {
    if !settings.cages {
        return;
    }
    let colour = Color::srgb(0.3, 0.7, 1.0);
    for cage in &cages {
        if !cage.active {
            continue;
        }
        for t in &cage.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                // Each edge once (the other triangle has it the other way round).
                if a < b {
                    gizmos.line(cage.vertices[a as usize], cage.vertices[b as usize], colour);
                }
            }
        }
    }
}

fn draw_tools(
    settings: Res<SoftTissueDebugSettings>,
    tools: Query<(
        &SoftTool,
        &GlobalTransform,
        &ToolReaction,
        Option<&crate::components::ToolState>,
    )>,
    mut gizmos: Gizmos,
) {
    if !settings.tools {
        return;
    }
    for (tool, pose, reaction, state) in &tools {
        let colour = if reaction.contacts > 0 {
            Color::srgb(1.0, 0.55, 0.1)
        } else {
            Color::srgb(0.2, 0.9, 0.3)
        };
        let p = pose.translation();
        match tool.shape {
            crate::core::contact::ToolShape::Sphere { radius } => {
                gizmos.sphere(Isometry3d::from_translation(p), radius as f32, colour);
            }
            crate::core::contact::ToolShape::Capsule { radius, length } => {
                let q = p + pose.up() * length as f32;
                gizmos.sphere(Isometry3d::from_translation(p), radius as f32, colour);
                gizmos.sphere(Isometry3d::from_translation(q), radius as f32, colour);
                gizmos.line(p, q, colour);
            }
            crate::core::contact::ToolShape::Blade { length } => {
                // The edge, red while it cuts.
                let cutting = state.as_ref().is_some_and(|s| s.tool().cutting());
                let colour = if cutting {
                    Color::srgb(0.95, 0.1, 0.1)
                } else {
                    colour
                };
                gizmos.line(p, p + pose.up() * length as f32, colour);
            }
            crate::core::contact::ToolShape::Grasper { jaw, .. } => {
                // The jaws where the simulation has them (the opening moves over steps).
                let Some(state) = state else { continue };
                for k in 0..2 {
                    let part = state.tool().part_pose(k);
                    let centre = crate::convert::to_bevy(&part.translation.vector);
                    let rotation = {
                        let q = part.rotation;
                        Quat::from_xyzw(q.i as f32, q.j as f32, q.k as f32, q.w as f32)
                    };
                    match jaw {
                        crate::core::contact::JawShape::Capsule { radius, length } => {
                            let q = centre + rotation * Vec3::Y * length as f32;
                            gizmos.sphere(
                                Isometry3d::from_translation(centre),
                                radius as f32,
                                colour,
                            );
                            gizmos.sphere(Isometry3d::from_translation(q), radius as f32, colour);
                            gizmos.line(centre, q, colour);
                        }
                        crate::core::contact::JawShape::Box {
                            thickness,
                            width,
                            length,
                        } => {
                            gizmos.cube(
                                Transform::from_translation(centre)
                                    .with_rotation(rotation)
                                    .with_scale(Vec3::new(
                                        thickness as f32,
                                        length as f32,
                                        width as f32,
                                    )),
                                colour,
                            );
                        }
                    }
                }
            }
        }
        if reaction.force.length_squared() > 0.0 {
            gizmos.arrow(
                p,
                p + reaction.force * settings.force_scale,
                Color::srgb(1.0, 0.2, 0.2),
            );
        }
    }
}

fn draw_contacts(
    settings: Res<SoftTissueDebugSettings>,
    contacts: Res<SoftTissueContacts>,
    bodies: Query<&SoftBodyState>,
    mut gizmos: Gizmos<SoftTissueContactGizmos>,
) {
    if !settings.contacts {
        return;
    }
    let size = settings.contact_size;
    let point = |body: u32, vertices: [u32; 3], weights: [f64; 3]| -> Option<Vec3> {
        let sim = bodies.get(contacts.body_entity(body)?).ok()?;
        let p = sim.body().collider().positions();
        let mut x = Vec3::ZERO;
        for (v, w) in vertices.iter().zip(weights) {
            x += to_bevy(p.get(*v as usize)?) * w as f32;
        }
        Some(x)
    };
    let c = contacts.core();
    for t in c.tool_contacts.iter().filter(|t| t.depth > 0.0) {
        if let Some(x) = point(t.body, t.vertices, t.weights) {
            let colour = Color::srgb(1.0, 0.9, 0.2);
            gizmos.sphere(Isometry3d::from_translation(x), 0.2 * size, colour);
            gizmos.line(x, x + to_bevy(&t.normal) * size, colour);
        }
    }
    for b in c.body_contacts.iter().filter(|b| b.depth > 0.0) {
        if let Some(x) = point(b.b, b.vertices, b.weights) {
            let colour = Color::srgb(1.0, 0.3, 0.9);
            gizmos.sphere(Isometry3d::from_translation(x), 0.2 * size, colour);
            gizmos.line(x, x + to_bevy(&b.normal) * size, colour);
        }
    }
}
