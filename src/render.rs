//! The rendered surface of every body: a `Mesh` created when the body is built and written
//! once per rendered frame (in `PostUpdate`, after the fixed-step loop), not once per fixed
//! step, and only when the body changed. Bodies with a temperature field get vertex colours:
//! warm tissue turns red toward 60 C, coagulated tissue white-grey, tissue that reached
//! boiling dark (charred).
//!
//! A body with a [`VisualMesh`] is drawn with a finer mesh embedded in its tetrahedra
//! ([`soft_tissue_core::mesh::embed`]): every visual vertex is the barycentric combination of
//! its tetrahedron's four nodes, whatever level the body is at (the cage level evaluates every
//! node). Its temperature, damage and char come from the heat field's samples at those
//! vertices (`HeatField::set_samples`, registered here on the first draw), so an electrode's
//! millimetre spot shows at the visual mesh's resolution, not as a tint over elements.
//!
//! When the body's mesh changes, a subdivided visual mesh is made again from the new
//! surface, an app's own follows a carve (`carve.rs`: the crater shows as a dent) but not a
//! blade's cut, whose sides it has no triangles for (the body is drawn with its simulation
//! surface from then on, until a reset makes it whole).

use bevy::asset::RenderAssetUsages;
use bevy::mesh::{
    Indices, Mesh, Mesh3d, MeshVertexAttribute, PrimitiveTopology, VertexAttributeValues,
};
use bevy::prelude::*;

use soft_tissue_core::heat::HeatSample;
use soft_tissue_core::mesh::cut::Ball;
use soft_tissue_core::mesh::embed::Embedding;
use soft_tissue_core::mesh::subdivide::loop_subdivide;

use crate::components::{SoftBodyState, Temperature, VisualMesh, VisualMeshError};

mod carve;
pub(crate) use carve::MeshChanges;

/// Creates and updates the bodies' render meshes.
#[derive(Default)]
pub struct SoftTissueMeshPlugin;

impl Plugin for SoftTissueMeshPlugin {
    fn build(&self, app: &mut App) {
        if !app.world().contains_resource::<Assets<Mesh>>() {
            app.init_asset::<Mesh>();
        }
        app.register_type::<VisualMesh>()
            .register_type::<VisualMeshError>();
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

/// The colour of tissue at `celsius` with `damage` (0..1): warm tissue reddens toward 60 C,
/// coagulated tissue turns white-grey.
pub fn tissue_colour(celsius: f32, damage: f32) -> [f32; 4] {
    burn_colour(celsius, damage, 0.0)
}

/// [`tissue_colour`], then darkened toward char by `charred` (0..1: how far the tissue went
/// toward boiling, see [`charred_fraction`]).
pub fn burn_colour(celsius: f32, damage: f32, charred: f32) -> [f32; 4] {
    let warm = ((celsius - 37.0) / (60.0 - 37.0)).clamp(0.0, 1.0);
    let base = [1.0, 1.0 - 0.75 * warm, 1.0 - 0.8 * warm];
    let coagulated = [0.86, 0.82, 0.78];
    let char = [0.10, 0.08, 0.07];
    let d = damage.clamp(0.0, 1.0);
    let c = charred.clamp(0.0, 1.0);
    std::array::from_fn(|i| {
        if i == 3 {
            return 1.0;
        }
        let tissue = base[i] + (coagulated[i] - base[i]) * d;
        tissue + (char[i] - tissue) * c
    })
}

/// How charred tissue looks whose largest temperature was `peak` C: none below 90 C, fully
/// at the boiling point (where it dries and chars) and above.
pub fn charred_fraction(peak: f64, boiling: f64) -> f32 {
    ((peak - (boiling - 10.0)) / 10.0).clamp(0.0, 1.0) as f32
}

/// Sample points of a heat field at the vertices of a visual mesh: each vertex's rest
/// position and its tetrahedron's nodes and weights.
fn heat_samples(embedding: &Embedding, rest: &[soft_tissue_core::Vec3]) -> Vec<HeatSample> {
    embedding
        .corners()
        .iter()
        .zip(embedding.weights())
        .map(|(c, w)| HeatSample {
            position: (0..4).map(|k| rest[c[k] as usize] * w[k]).sum(),
            nodes: std::array::from_fn(|k| (c[k], w[k])),
        })
        .collect()
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

/// A body drawn with an embedded visual mesh: the embedding, the mesh's triangles and its
/// vertices' rest positions.
#[derive(Component)]
pub struct EmbeddedVisual {
    embedding: Embedding,
    triangles: Vec<[u32; 3]>,
    /// Where each vertex is embedded (rest, the coordinates of the body's mesh).
    rest: Vec<soft_tissue_core::Vec3>,
    /// The distance limit it was embedded with.
    limit: f64,
    /// The balls carved out of the body that its vertices were moved out of.
    carved: Vec<soft_tissue_core::mesh::cut::Ball>,
}

impl EmbeddedVisual {
    /// The embedding of the visual vertices in the simulation's tetrahedra.
    pub fn embedding(&self) -> &Embedding {
        &self.embedding
    }

    /// Where each visual vertex is embedded, in the rest shape (the coordinates of the
    /// body's mesh, `WorldBody::mesh`): where it was given, or, for a vertex that was inside
    /// tissue a carve removed, on the crater's wall (see `render/carve.rs`).
    pub fn rest_positions(&self) -> &[soft_tissue_core::Vec3] {
        &self.rest
    }

    /// The balls carved out of the body since the visual mesh was made whose vertices were
    /// moved onto their walls (rest shape).
    pub fn carved(&self) -> &[soft_tissue_core::mesh::cut::Ball] {
        &self.carved
    }
}

/// The triangles of a `TriangleList` mesh (consecutive vertices when it has no indices).
fn mesh_triangles(mesh: &Mesh) -> Result<Vec<[u32; 3]>, String> {
    if mesh.primitive_topology() != PrimitiveTopology::TriangleList {
        return Err(format!(
            "it is a {:?} mesh, a TriangleList is needed",
            mesh.primitive_topology()
        ));
    }
    let n = mesh.count_vertices();
    let flat: Vec<u32> = match mesh.indices() {
        Some(i) => i.iter().map(|v| v as u32).collect(),
        None => (0..n as u32).collect(),
    };
    if !flat.len().is_multiple_of(3) {
        return Err(format!(
            "its {} indices are not whole triangles",
            flat.len()
        ));
    }
    if let Some(&bad) = flat.iter().find(|&&v| v as usize >= n) {
        return Err(format!("an index {bad} is past its {n} vertices"));
    }
    Ok(flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect())
}

/// The render mesh and embedding of a body's [`VisualMesh`]; `Ok(None)` while its asset
/// is still loading. An app's own mesh has its vertices in the `carved` balls moved onto
/// their walls first (`render/carve.rs`; a subdivided one is made from the carved surface).
fn visual_mesh(
    visual: &VisualMesh,
    sim: &SoftBodyState,
    meshes: &Assets<Mesh>,
    entity: Entity,
    name: &str,
    carved: &[Ball],
) -> Result<Option<(Mesh, EmbeddedVisual)>, VisualMeshError> {
    let bad = |message: String| VisualMeshError::BadMesh {
        body: entity,
        name: name.to_owned(),
        message,
    };
    let embed = |message: String| VisualMeshError::Embedding {
        body: entity,
        name: name.to_owned(),
        message,
    };
    let body = sim.body();
    let tets = body.mesh();
    let (mut mesh, points, limit) = match visual {
        VisualMesh::Mesh { mesh, max_distance } => {
            let Some(source) = meshes.get(mesh) else {
                return Ok(None);
            };
            let Some(VertexAttributeValues::Float32x3(p)) =
                source.attribute(Mesh::ATTRIBUTE_POSITION)
            else {
                return Err(bad("the mesh has no Float32x3 positions".into()));
            };
            let place = sim.placement().to_matrix().as_dmat4();
            let points: Vec<_> = p
                .iter()
                .map(|q| {
                    let q = place.transform_point3(Vec3::from_array(*q).as_dvec3());
                    soft_tissue_core::Vec3::new(q.x, q.y, q.z)
                })
                .collect();
            let limit = max_distance.map_or(0.25 * tets.bbox().smallest_dimension(), f64::from);
            (source.clone(), points, limit)
        }
        VisualMesh::Subdivided { levels } => {
            let (points, triangles) = loop_subdivide(
                tets.positions(),
                tets.surface().triangles(),
                u32::from(*levels),
            )
            .map_err(|e| embed(e.to_string()))?;
            let mut mesh = Mesh::new(
                PrimitiveTopology::TriangleList,
                RenderAssetUsages::default(),
            );
            let p: Vec<[f32; 3]> = points
                .iter()
                .map(|q| [q.x as f32, q.y as f32, q.z as f32])
                .collect();
            mesh.insert_attribute(Mesh::ATTRIBUTE_POSITION, p);
            mesh.insert_indices(Indices::U32(triangles.into_iter().flatten().collect()));
            let limit = 0.1 * tets.bbox().smallest_dimension();
            (mesh, points, limit)
        }
    };
    let triangles = mesh_triangles(&mesh).map_err(bad)?;
    let carved = match visual {
        VisualMesh::Mesh { .. } => carved.to_vec(),
        VisualMesh::Subdivided { .. } => Vec::new(),
    };
    let points = if carved.is_empty() {
        points
    } else {
        carve::onto_crater(&points, &triangles, &carved).0
    };
    let embedding = Embedding::new(tets, &points, limit).map_err(|e| embed(e.to_string()))?;
    let n = embedding.len();
    let mut scratch = vec![[0.0; 3]; n];
    embedding
        .apply(body.model().node_positions(), &mut scratch)
        .map_err(|e| embed(e.to_string()))?;
    to_local(sim, &mut scratch);
    let mut normal = Vec::new();
    normals(&scratch, &triangles, &mut normal);
    mesh.insert_attribute(Mesh::ATTRIBUTE_POSITION, scratch);
    mesh.insert_attribute(Mesh::ATTRIBUTE_NORMAL, normal);
    if body.heat().is_some() {
        mesh.insert_attribute(Mesh::ATTRIBUTE_COLOR, vec![tissue_colour(37.0, 0.0); n]);
    }
    Ok(Some((
        mesh,
        EmbeddedVisual {
            embedding,
            triangles,
            rest: points,
            limit,
            carved,
        },
    )))
}

/// Maps world positions into the body entity's own frame (the rendered mesh is drawn with
/// the entity's transform).
fn to_local(sim: &SoftBodyState, positions: &mut [[f32; 3]]) {
    if let Some(m) = sim.to_local {
        for p in positions {
            *p = m.transform_point3(Vec3::from_array(*p)).to_array();
        }
    }
}

/// The colour of the inside of the tissue (the sides of a cut): a deep red, multiplying
/// the material's base colour.
pub const INSIDE_COLOUR: [f32; 4] = [0.62, 0.14, 0.16, 1.0];

/// How a body's rendered mesh is made from its simulation surface: for a cut body, the
/// sides of the cuts get vertices of their own (so they can be coloured as the inside of
/// the tissue and keep their own normals), which `sources` maps back to the surface
/// vertices; `shape` is the body's mesh the rendered mesh was made for.
#[derive(Component, Default, Debug)]
pub struct RenderedSurface {
    shape: u64,
    /// Surface vertex of each rendered vertex (empty: the rendered vertices are the
    /// surface vertices).
    sources: Vec<u32>,
    /// Rendered triangles (empty: the surface triangles).
    triangles: Vec<[u32; 3]>,
    /// The first rendered vertex of a cut side.
    inside_from: usize,
}

impl RenderedSurface {
    /// Rendered vertices that belong to the sides of cuts.
    pub fn inside_vertices(&self) -> std::ops::Range<usize> {
        self.inside_from.min(self.sources.len())..self.sources.len()
    }
}

/// The rendered surface of `sim` (see [`RenderedSurface`]).
fn rendered_surface(sim: &SoftBodyState) -> RenderedSurface {
    let b = sim.body();
    let Some(cut) = b.cut_record().filter(|c| !c.surface_faces.is_empty()) else {
        return RenderedSurface {
            shape: sim.shape,
            ..Default::default()
        };
    };
    let n = b.surface_positions().len();
    let mut sources: Vec<u32> = (0..n as u32).collect();
    let mut copy = vec![u32::MAX; n];
    let mut triangles = b.surface_triangles().to_vec();
    for &f in &cut.surface_faces {
        let t = &mut triangles[f as usize];
        for v in t.iter_mut() {
            let c = &mut copy[*v as usize];
            if *c == u32::MAX {
                *c = sources.len() as u32;
                sources.push(*v);
            }
            *v = *c;
        }
    }
    RenderedSurface {
        shape: sim.shape,
        sources,
        triangles,
        inside_from: n,
    }
}

/// The rendered positions of `sim` into `out` (through `r`'s sources).
fn rendered_positions(sim: &SoftBodyState, r: &RenderedSurface, out: &mut Vec<[f32; 3]>) {
    let surface = sim.body().surface_positions();
    out.clear();
    if r.sources.is_empty() {
        out.extend_from_slice(surface);
    } else {
        out.extend(r.sources.iter().map(|&v| surface[v as usize]));
    }
    to_local(sim, out);
}

/// The simulation surface as a render mesh, and how it was made.
fn surface_mesh(sim: &SoftBodyState) -> (Mesh, RenderedSurface) {
    let b = sim.body();
    let r = rendered_surface(sim);
    let mut positions = Vec::new();
    rendered_positions(sim, &r, &mut positions);
    let triangles = if r.triangles.is_empty() {
        b.surface_triangles()
    } else {
        &r.triangles
    };
    let mut n = Vec::new();
    normals(&positions, triangles, &mut n);
    let mut mesh = Mesh::new(
        PrimitiveTopology::TriangleList,
        RenderAssetUsages::default(),
    );
    let count = positions.len();
    mesh.insert_attribute(Mesh::ATTRIBUTE_POSITION, positions);
    mesh.insert_attribute(Mesh::ATTRIBUTE_NORMAL, n);
    if b.heat().is_some() || !r.sources.is_empty() {
        let skin = if b.heat().is_some() {
            tissue_colour(37.0, 0.0)
        } else {
            [1.0; 4]
        };
        let mut colours = vec![skin; count];
        for c in &mut colours[r.inside_vertices()] {
            *c = INSIDE_COLOUR;
        }
        mesh.insert_attribute(Mesh::ATTRIBUTE_COLOR, colours);
    }
    mesh.insert_indices(Indices::U32(triangles.iter().flatten().copied().collect()));
    (mesh, r)
}

#[allow(clippy::type_complexity)]
fn create_meshes(
    mut commands: Commands,
    mut meshes: ResMut<Assets<Mesh>>,
    new: Query<
        (
            Entity,
            &SoftBodyState,
            Option<&VisualMesh>,
            Option<&Name>,
            Has<VisualMeshError>,
        ),
        Without<SoftBodyMesh>,
    >,
) {
    for (entity, sim, visual, name, failed) in &new {
        let mut e = commands.entity(entity);
        if let Some(visual) = visual
            && !failed
        {
            let name = name.map_or_else(|| format!("{entity}"), |n| n.to_string());
            match visual_mesh(visual, sim, &meshes, entity, &name, &[]) {
                Ok(None) => continue,
                Ok(Some((mesh, embedded))) => {
                    let rendered = RenderedSurface {
                        shape: sim.shape,
                        ..Default::default()
                    };
                    e.insert((Mesh3d(meshes.add(mesh)), embedded, rendered, SoftBodyMesh));
                    continue;
                }
                Err(why) => {
                    error!("{why}; drawing its simulation surface");
                    e.insert(why);
                }
            }
        }
        let (mesh, rendered) = surface_mesh(sim);
        e.insert((Mesh3d(meshes.add(mesh)), rendered, SoftBodyMesh));
    }
}

/// The visual mesh of a body whose tetrahedral mesh changed (by `changes` since it was
/// drawn), embedded in the new tetrahedra, its mesh asset written where it was made again;
/// `Ok(None)`: the body is drawn with its simulation surface from now on.
///
/// - A subdivided visual mesh is made again from the new surface (its burn starts from the
///   heat field's marks), and so is any visual mesh of a body a reset made whole again.
/// - An app's own mesh after carves only keeps its vertices, triangles and attributes:
///   those in the tissue the carves removed move onto the craters' walls, and all are
///   embedded again (`render/carve.rs`). After a reset and carves since, it is made again
///   from the mesh as it was given, fitted to those carves alone.
/// - An app's own mesh after a blade's cut no longer fits: the cut opens the surface, and
///   the mesh has no triangles for its sides.
#[allow(clippy::too_many_arguments)]
fn refit_visual(
    sim: &SoftBodyState,
    changes: &MeshChanges,
    visual: Option<&EmbeddedVisual>,
    kind: Option<&VisualMesh>,
    name: Option<&Name>,
    entity: Entity,
    meshes: &mut Assets<Mesh>,
    handle: &Mesh3d,
) -> Result<Option<EmbeddedVisual>, VisualMeshError> {
    let Some(kind) = kind else {
        return Ok(None);
    };
    let name = name.map_or_else(|| format!("{entity}"), |n| n.to_string());
    let whole = sim.body().cut_record().is_none();
    let subdivided = matches!(kind, VisualMesh::Subdivided { .. });
    // Made again from what it was given: whole, subdivided, or carved since a reset (the
    // mesh drawn is of the body before the reset).
    let again = if whole || (visual.is_some() && subdivided) {
        Some(&[][..])
    } else {
        changes.only_carves().filter(|_| changes.since_reset())
    };
    let embedded = if let Some(carved) = again {
        let Some((m, embedded)) = visual_mesh(kind, sim, meshes, entity, &name, carved)? else {
            return Ok(None);
        };
        if let Some(mut mesh) = meshes.get_mut(&handle.0) {
            *mesh = m;
        }
        embedded
    } else if let (Some(v), Some(balls)) = (visual, changes.only_carves()) {
        carve::refit(v, balls, sim.body().mesh()).map_err(|e| VisualMeshError::Embedding {
            body: entity,
            name,
            message: format!("after a carve: {e}"),
        })?
    } else {
        return Ok(None);
    };
    // The heat field, made again with the mesh, has no samples: the next draw registers
    // them at the new vertices.
    Ok(Some(embedded))
}

/// Per-frame scratch buffers of [`upload_meshes`].
#[derive(Default)]
struct Scratch {
    positions: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    celsius: Vec<f32>,
    damage: Vec<f32>,
    charred: Vec<f32>,
}

#[allow(clippy::type_complexity)]
fn upload_meshes(
    mut commands: Commands,
    mut meshes: ResMut<Assets<Mesh>>,
    mut bodies: Query<
        (
            Entity,
            &mut SoftBodyState,
            &Mesh3d,
            &mut RenderedSurface,
            Option<&Temperature>,
            Option<&EmbeddedVisual>,
            Option<&VisualMesh>,
            Option<&Name>,
        ),
        With<SoftBodyMesh>,
    >,
    mut s: Local<Scratch>,
) {
    for (entity, mut sim, handle, mut rendered, temp, visual, kind, name) in &mut bodies {
        if !sim.dirty {
            continue;
        }
        sim.dirty = false;
        // A cut, a carve (or a reset that undid one) changed the body's mesh.
        if rendered.shape != sim.shape {
            let changes = std::mem::take(&mut sim.reshaped);
            let refit = refit_visual(
                &sim,
                &changes,
                visual,
                kind,
                name,
                entity,
                &mut meshes,
                handle,
            );
            let embedded = match refit {
                Ok(embedded) => embedded,
                Err(why) => {
                    error!("{why}; drawing its simulation surface");
                    commands.entity(entity).insert(why);
                    None
                }
            };
            if let Some(embedded) = embedded {
                commands
                    .entity(entity)
                    .insert(embedded)
                    .remove::<VisualMeshError>();
                *rendered = RenderedSurface {
                    shape: sim.shape,
                    ..Default::default()
                };
                sim.dirty = true;
                continue;
            }
            if visual.is_some() {
                info!("body {entity} was cut: drawn with its simulation surface from now on");
                commands.entity(entity).remove::<EmbeddedVisual>();
            }
            let Some(mut mesh) = meshes.get_mut(&handle.0) else {
                continue;
            };
            let (m, r) = surface_mesh(&sim);
            *mesh = m;
            *rendered = r;
            continue;
        }
        let Some(mut mesh) = meshes.get_mut(&handle.0) else {
            continue;
        };
        // A body with heat follows its temperature and damage at the visual vertices, finer
        // than its mesh (an electrode's millimetre spot shows as one).
        if let Some(v) = visual
            && sim
                .body()
                .heat()
                .is_some_and(|h| h.sample_temperatures().len() != v.embedding.len())
        {
            let samples = heat_samples(&v.embedding, sim.body().mesh().positions());
            if let Some(h) = sim.body_mut().heat_mut()
                && let Err(e) = h.set_samples(samples)
            {
                warn!("body {entity}: its burn is drawn from the nodes: {e}");
            }
        }
        let b = sim.body();
        let Scratch {
            positions,
            normals: normal,
            celsius,
            damage,
            charred,
        } = &mut *s;
        if let Some(v) = visual {
            let n = v.embedding.len();
            positions.resize(n, [0.0; 3]);
            // Sizes match by construction (the embedding was built from this body's mesh).
            if v.embedding
                .apply(b.model().node_positions(), positions)
                .is_err()
            {
                continue;
            }
            to_local(&sim, positions);
            normals(positions, &v.triangles, normal);
            write3(&mut mesh, Mesh::ATTRIBUTE_POSITION, positions);
            write3(&mut mesh, Mesh::ATTRIBUTE_NORMAL, normal);
            if let Some(heat) = b.heat() {
                celsius.resize(n, 0.0);
                damage.resize(n, 0.0);
                charred.clear();
                let boiling = heat.params().vaporization.boiling_temperature;
                if heat.sample_temperatures().len() == n {
                    for (k, (&t, &d)) in heat
                        .sample_temperatures()
                        .iter()
                        .zip(heat.sample_damage())
                        .enumerate()
                    {
                        celsius[k] = t as f32;
                        damage[k] = (1.0 - (-d.max(0.0)).exp()) as f32;
                    }
                    charred.extend(
                        heat.sample_peaks()
                            .iter()
                            .map(|&p| charred_fraction(p, boiling)),
                    );
                    write_burn_colours(&mut mesh, celsius, damage, charred);
                } else if v
                    .embedding
                    .interpolate(heat.temperatures(), celsius)
                    .is_ok()
                    && v.embedding.interpolate(heat.damage(), damage).is_ok()
                {
                    // Interpolated Arrhenius integral to damaged fraction.
                    for d in damage.iter_mut() {
                        *d = 1.0 - (-d.max(0.0)).exp();
                    }
                    write_colours(&mut mesh, celsius, damage);
                }
            }
            continue;
        }
        let triangles = if rendered.triangles.is_empty() {
            b.surface_triangles()
        } else {
            &rendered.triangles
        };
        let surface: &[[f32; 3]] = if sim.to_local.is_some() || !rendered.sources.is_empty() {
            rendered_positions(&sim, &rendered, positions);
            positions
        } else {
            b.surface_positions()
        };
        normals(surface, triangles, normal);
        // Written in place: the attribute buffers keep their allocation.
        write3(&mut mesh, Mesh::ATTRIBUTE_POSITION, surface);
        write3(&mut mesh, Mesh::ATTRIBUTE_NORMAL, normal);
        if let Some(t) = temp {
            if rendered.sources.is_empty() {
                write_colours(&mut mesh, &t.surface, &t.damage);
            } else {
                // The skin by its temperature, the cut sides as the inside.
                celsius.clear();
                damage.clear();
                for &v in &rendered.sources {
                    celsius.push(t.surface.get(v as usize).copied().unwrap_or(37.0));
                    damage.push(t.damage.get(v as usize).copied().unwrap_or(0.0));
                }
                write_colours(&mut mesh, celsius, damage);
                if let Some(VertexAttributeValues::Float32x4(c)) =
                    mesh.attribute_mut(Mesh::ATTRIBUTE_COLOR)
                    && c.len() == rendered.sources.len()
                {
                    for c in &mut c[rendered.inside_vertices()] {
                        *c = INSIDE_COLOUR;
                    }
                }
            }
        }
    }
}

/// [`write_colours`] with each vertex's char.
fn write_burn_colours(mesh: &mut Mesh, celsius: &[f32], damage: &[f32], charred: &[f32]) {
    if let Some(VertexAttributeValues::Float32x4(colours)) =
        mesh.attribute_mut(Mesh::ATTRIBUTE_COLOR)
        && colours.len() == celsius.len()
        && charred.len() == celsius.len()
    {
        for (((c, &t), &d), &ch) in colours.iter_mut().zip(celsius).zip(damage).zip(charred) {
            *c = burn_colour(t, d, ch);
        }
    }
}

/// Writes the tissue colours of `celsius` and `damage` into the mesh's colour attribute.
fn write_colours(mesh: &mut Mesh, celsius: &[f32], damage: &[f32]) {
    if let Some(VertexAttributeValues::Float32x4(colours)) =
        mesh.attribute_mut(Mesh::ATTRIBUTE_COLOR)
        && colours.len() == celsius.len()
    {
        for ((c, &t), &d) in colours.iter_mut().zip(celsius).zip(damage) {
            *c = tissue_colour(t, d.clamp(0.0, 1.0));
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
    fn tissue_colours_go_from_white_to_red_to_white_grey_to_char() {
        assert_eq!(tissue_colour(37.0, 0.0), [1.0, 1.0, 1.0, 1.0]);
        let hot = tissue_colour(60.0, 0.0);
        assert!(hot[0] > hot[1] && hot[0] > hot[2]);
        // Coagulated: white-grey whatever the temperature.
        let coagulated = tissue_colour(60.0, 1.0);
        assert_eq!(coagulated, tissue_colour(37.0, 1.0));
        assert!(coagulated[..3].iter().all(|&c| (0.7..0.9).contains(&c)));
        // Charred: dark, from 90 C up to boiling.
        assert_eq!(charred_fraction(89.0, 100.0), 0.0);
        assert_eq!(charred_fraction(100.0, 100.0), 1.0);
        let char = burn_colour(100.0, 1.0, charred_fraction(100.0, 100.0));
        assert!(char[..3].iter().all(|&c| c < 0.15));
        assert_eq!(burn_colour(50.0, 0.3, 0.0), tissue_colour(50.0, 0.3));
    }
}
