//! The rendered surface of every body: a `Mesh` created when the body is built and written
//! once per rendered frame (in `PostUpdate`, after the fixed-step loop), not once per fixed
//! step, and only when the body changed. Bodies with a temperature field get vertex colours:
//! warm tissue turns red toward 60 C, thermally damaged tissue turns a coagulated grey-brown.

use bevy::asset::RenderAssetUsages;
use bevy::mesh::{
    Indices, Mesh, Mesh3d, MeshVertexAttribute, PrimitiveTopology, VertexAttributeValues,
};
use bevy::prelude::*;

use crate::components::{SimulatedBody, Temperature};

/// Creates and updates the bodies' render meshes.
#[derive(Default)]
pub struct SoftTissueMeshPlugin;

impl Plugin for SoftTissueMeshPlugin {
    fn build(&self, app: &mut App) {
        if !app.world().contains_resource::<Assets<Mesh>>() {
            app.init_asset::<Mesh>();
        }
        app.add_systems(
            PostUpdate,
            (create_meshes, upload_meshes)
                .chain()
                .in_set(SoftTissueMeshSystems),
        );
    }
}

/// The set in `PostUpdate` that writes the bodies' render meshes.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SoftTissueMeshSystems;

/// Marks the mesh the plugin writes for a body.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct SoftBodyMesh;

/// The colour of tissue at `celsius` with `damage` (0..1).
pub fn tissue_colour(celsius: f32, damage: f32) -> [f32; 4] {
    let warm = ((celsius - 37.0) / (60.0 - 37.0)).clamp(0.0, 1.0);
    let base = [1.0, 1.0 - 0.75 * warm, 1.0 - 0.8 * warm];
    let charred = [0.55, 0.45, 0.40];
    let d = damage.clamp(0.0, 1.0);
    [
        base[0] + (charred[0] - base[0]) * d,
        base[1] + (charred[1] - base[1]) * d,
        base[2] + (charred[2] - base[2]) * d,
        1.0,
    ]
}

/// Area-weighted vertex normals of a triangle surface.
fn normals(positions: &[[f32; 3]], triangles: &[[u32; 3]], out: &mut Vec<[f32; 3]>) {
    out.clear();
    out.resize(positions.len(), [0.0; 3]);
    for t in triangles {
        let [a, b, c] = t.map(|i| Vec3::from_array(positions[i as usize]));
        let n = (b - a).cross(c - a);
        for &i in t {
            let o = &mut out[i as usize];
            o[0] += n.x;
            o[1] += n.y;
            o[2] += n.z;
        }
    }
    for o in out.iter_mut() {
        *o = Vec3::from_array(*o).normalize_or(Vec3::Y).to_array();
    }
}

fn create_meshes(
    mut commands: Commands,
    mut meshes: ResMut<Assets<Mesh>>,
    new: Query<(Entity, &SimulatedBody, Option<&Temperature>), Without<SoftBodyMesh>>,
) {
    for (entity, sim, temp) in &new {
        let b = sim.body();
        let positions = b.surface_positions().to_vec();
        let mut n = Vec::new();
        normals(&positions, b.surface_triangles(), &mut n);
        let mut mesh = Mesh::new(
            PrimitiveTopology::TriangleList,
            RenderAssetUsages::default(),
        );
        mesh.insert_attribute(Mesh::ATTRIBUTE_POSITION, positions);
        mesh.insert_attribute(Mesh::ATTRIBUTE_NORMAL, n);
        if temp.is_some() {
            mesh.insert_attribute(
                Mesh::ATTRIBUTE_COLOR,
                vec![tissue_colour(37.0, 0.0); b.surface_positions().len()],
            );
        }
        mesh.insert_indices(Indices::U32(
            b.surface_triangles().iter().flatten().copied().collect(),
        ));
        commands
            .entity(entity)
            .insert((Mesh3d(meshes.add(mesh)), SoftBodyMesh));
    }
}

fn upload_meshes(
    mut meshes: ResMut<Assets<Mesh>>,
    mut bodies: Query<(&mut SimulatedBody, &Mesh3d, Option<&Temperature>), With<SoftBodyMesh>>,
    mut scratch: Local<Vec<[f32; 3]>>,
) {
    for (mut sim, handle, temp) in &mut bodies {
        if !sim.dirty {
            continue;
        }
        sim.dirty = false;
        let Some(mut mesh) = meshes.get_mut(&handle.0) else {
            continue;
        };
        let b = sim.body();
        normals(b.surface_positions(), b.surface_triangles(), &mut scratch);
        // Written in place: the attribute buffers keep their allocation.
        write3(&mut mesh, Mesh::ATTRIBUTE_POSITION, b.surface_positions());
        write3(&mut mesh, Mesh::ATTRIBUTE_NORMAL, &scratch);
        if let Some(t) = temp
            && let Some(VertexAttributeValues::Float32x4(colours)) =
                mesh.attribute_mut(Mesh::ATTRIBUTE_COLOR)
            && colours.len() == t.surface.len()
        {
            for ((c, &celsius), &damage) in colours.iter_mut().zip(&t.surface).zip(&t.damage) {
                *c = tissue_colour(celsius, damage);
            }
        }
    }
}

/// Copies `values` into a three-component attribute (replacing it if its size differs).
fn write3(mesh: &mut Mesh, attribute: MeshVertexAttribute, values: &[[f32; 3]]) {
    if let Some(VertexAttributeValues::Float32x3(v)) = mesh.attribute_mut(attribute)
        && v.len() == values.len()
    {
        v.copy_from_slice(values);
        return;
    }
    mesh.insert_attribute(attribute, values.to_vec());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normals_of_a_tetrahedron_point_outward() {
        let p = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ];
        // Outward-oriented faces (counter-clockwise seen from outside).
        let t = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
        let mut n = Vec::new();
        normals(&p, &t, &mut n);
        let centre = Vec3::splat(0.25);
        for (q, m) in p.iter().zip(&n) {
            let out = Vec3::from_array(*q) - centre;
            assert!(out.dot(Vec3::from_array(*m)) > 0.0);
            assert!((Vec3::from_array(*m).length() - 1.0).abs() < 1e-6);
        }
    }

    #[test]
    fn tissue_colours_go_from_white_to_red_to_grey() {
        assert_eq!(tissue_colour(37.0, 0.0), [1.0, 1.0, 1.0, 1.0]);
        let hot = tissue_colour(60.0, 0.0);
        assert!(hot[0] > hot[1] && hot[0] > hot[2]);
        let burnt = tissue_colour(60.0, 1.0);
        assert!((burnt[0] - 0.55).abs() < 1e-6 && (burnt[2] - 0.40).abs() < 1e-6);
    }
}
