//! Building bodies and tools from their components, and why a body was not built.

use super::*;

/// A body that could not be built, and why (the entity keeps its [`SoftBody`]; writing
/// any of its inputs tries again). Each variant names the body's entity, which the error
/// sits on, and its display name (its [`Name`], else the entity) for messages: two bodies
/// of one name are told apart by `body`.
#[derive(Component, Debug, thiserror::Error)]
pub enum SoftBodyError {
    /// The mesh could not be placed at the entity's global transform.
    #[error("soft body `{name}` (entity {body}): placing its mesh: {message}")]
    Placement {
        /// The body's entity.
        body: Entity,
        /// The body's name (its [`Name`], else the entity).
        name: String,
        /// What is wrong.
        message: String,
    },
    /// A setting is out of range (the message names it).
    #[error("soft body `{name}` (entity {body}): {message}")]
    Settings {
        /// The body's entity.
        body: Entity,
        /// The body's name (its [`Name`], else the entity).
        name: String,
        /// What is wrong.
        message: String,
    },
    /// The core refused to build it (its error names the level and what failed).
    #[error("soft body `{name}` (entity {body}): {source}")]
    Build {
        /// The body's entity.
        body: Entity,
        /// The body's name (its [`Name`], else the entity).
        name: String,
        /// The core's error.
        source: WorldError,
    },
}

impl SoftBodyError {
    /// The entity of the body that was not built.
    pub fn body(&self) -> Entity {
        match self {
            SoftBodyError::Placement { body, .. }
            | SoftBodyError::Settings { body, .. }
            | SoftBodyError::Build { body, .. } => *body,
        }
    }

    /// The body's name as the message gives it (its [`Name`], else the entity).
    pub fn name(&self) -> &str {
        match self {
            SoftBodyError::Placement { name, .. }
            | SoftBodyError::Settings { name, .. }
            | SoftBodyError::Build { name, .. } => name,
        }
    }
}

/// The body's mesh with `placement` applied (the same `Arc` when it is the identity).
fn placed(mesh: &Arc<TetMesh>, placement: &GlobalTransform) -> Result<Arc<TetMesh>, String> {
    if placement.affine() == bevy::math::Affine3A::IDENTITY {
        return Ok(mesh.clone());
    }
    mapped(mesh, placement.to_matrix().as_dmat4())
}

/// The mesh with every node mapped by `m`.
pub(super) fn mapped(mesh: &TetMesh, m: bevy::math::DMat4) -> Result<Arc<TetMesh>, String> {
    let map = |p: &soft_tissue_core::Vec3| {
        let q = m.transform_point3(bevy::math::DVec3::new(p.x, p.y, p.z));
        soft_tissue_core::Vec3::new(q.x, q.y, q.z)
    };
    // A placement keeps the topology (linear time); one that mirrors or flattens elements
    // builds the mesh anew (turned elements re-oriented, flat ones refused by name).
    if let Ok(moved) = mesh.mapped(map) {
        return Ok(Arc::new(moved));
    }
    let positions = mesh.positions().iter().map(map).collect();
    let tets = mesh.tets().iter().map(|t| t.map(|i| i as usize)).collect();
    TetMesh::new(positions, tets)
        .map(Arc::new)
        .map_err(|e| e.to_string())
}

/// The core settings of a body from its components.
fn body_settings(
    spec: &SoftBody,
    material: &TissueMaterial,
    tuning: Option<&SoftBodyTuning>,
    mesh: &TetMesh,
    dt: f64,
    gravity: bevy::math::DVec3,
) -> Result<BodySettings, String> {
    spec.anchor.validate()?;
    let (msd, springs) = material.msd_params(mesh.node_count());
    let mut s = BodySettings::new(material.fem, msd, dt);
    s.precise = spec.method;
    s.msd_spring_stiffness = springs;
    s.cage = spec.cage;
    s.boundary = spec.anchor.boundary(mesh);
    s.gravity = soft_tissue_core::Vec3::new(gravity.x, gravity.y, gravity.z);
    if let Some(t) = tuning {
        s.fem_integrator = t.fem_integrator;
        s.cage_dynamics = t.cage_dynamics;
        s.cage_msd = t.cage_msd;
        s.policy = t.policy;
    }
    Ok(s)
}

/// What a built body was built from, beyond what changes in place (method, material,
/// heat, pin, shadow): a change of any of it builds the body again.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BuiltFrom {
    pub(super) mesh: AssetId<TetMeshAsset>,
    pub(super) cage: soft_tissue_core::scenario::CageKind,
    pub(super) anchor: soft_tissue_core::scenario::Anchor,
    pub(super) tuning: Option<SoftBodyTuning>,
    pub(super) dt: f64,
    pub(super) gravity: bevy::math::DVec3,
}

impl BuiltFrom {
    /// What a body of `spec` and `tuning` is built from at step `dt` under `config`.
    pub(super) fn of(
        spec: &SoftBody,
        tuning: Option<&SoftBodyTuning>,
        dt: f64,
        config: &SoftTissueConfig,
    ) -> Self {
        BuiltFrom {
            mesh: spec.mesh.id(),
            cage: spec.cage,
            anchor: spec.anchor,
            tuning: tuning.copied(),
            dt,
            gravity: config.gravity,
        }
    }
}

/// Builds the simulation of every [`SoftBody`] whose mesh has loaded.
#[allow(clippy::type_complexity)]
pub(super) fn build_bodies(
    mut commands: Commands,
    config: Res<SoftTissueConfig>,
    clock: Res<Time<SoftPhysics>>,
    meshes: Res<Assets<TetMeshAsset>>,
    new: Query<
        (
            Entity,
            &SoftBody,
            &TissueMaterial,
            Option<&TissueHeat>,
            Option<&SoftBodyTuning>,
            Option<&Name>,
            Has<ShadowSimulation>,
            Option<&PinnedLevel>,
            Option<&CutShare>,
        ),
        (Without<SoftBodyState>, Without<SoftBodyError>),
    >,
    poses: TransformHelper,
    mut next: ResMut<NextBodyOrder>,
) {
    let dt = clock.timestep().as_secs_f64();
    for (entity, spec, material, heat, tuning, name, shadow, pin, share) in &new {
        // A cut body or piece built again: its share of the masses.
        let material = &CutShare::of(share, material);
        let Some(asset) = meshes.get(&spec.mesh) else {
            continue;
        };
        let name = name.map_or_else(|| format!("{entity}"), |n| n.as_str().to_owned());
        // Computed now, not the one propagated at the end of the last frame.
        let placement = poses.compute_global_transform(entity).unwrap_or_default();
        // Built once per body, not per step: the error's size (the core's error beside the
        // entity and name) costs nothing here.
        #[allow(clippy::result_large_err)]
        let result = (|| -> Result<WorldBody, SoftBodyError> {
            let settings_err = |message| SoftBodyError::Settings {
                body: entity,
                name: name.clone(),
                message,
            };
            let build_err = |source| SoftBodyError::Build {
                body: entity,
                name: name.clone(),
                source,
            };
            let mesh =
                placed(&asset.0, &placement).map_err(|message| SoftBodyError::Placement {
                    body: entity,
                    name: name.clone(),
                    message,
                })?;
            let settings = body_settings(spec, material, tuning, &mesh, dt, config.gravity)
                .map_err(settings_err)?;
            let heat = heat.map(|h| (h.0, HeatBoundary::insulated()));
            let mut body = WorldBody::new(name.clone(), mesh, settings, heat).map_err(build_err)?;
            body.set_friction(material.friction)
                .map_err(|e| settings_err(format!("friction: {e}")))?;
            body.set_toughness(material.toughness)
                .map_err(|e| settings_err(format!("toughness: {e}")))?;
            if shadow {
                body.set_shadow(true).map_err(build_err)?;
            }
            if let Some(p) = pin {
                body.model_mut()
                    .pin(Some(p.0))
                    .map_err(|e| settings_err(format!("pinning: {e}")))?;
            }
            Ok(body)
        })();
        match result {
            Ok(body) => {
                let method = body.model().settings().precise;
                let mut e = commands.entity(entity);
                e.insert((
                    PrecisionLevel {
                        level: body.model().level(),
                        method,
                        switches: 0,
                        last_jump_ratio: None,
                    },
                    GreenCage::default(),
                    SoftBodyDiagnostics::default(),
                ));
                if method.is_fem() {
                    e.insert(FemState::default()).remove::<MsdState>();
                } else {
                    e.insert(MsdState::default()).remove::<FemState>();
                }
                if body.heat().is_some() {
                    e.insert(Temperature::default());
                } else {
                    e.remove::<Temperature>();
                }
                let mut state = SoftBodyState {
                    body,
                    order: next.0,
                    dirty: true,
                    placement,
                    pose: placement,
                    to_local: None,
                    built_from: BuiltFrom::of(spec, tuning, dt, &config),
                    shape: 0,
                    reshaped: Default::default(),
                };
                state.set_pose(placement);
                e.insert(state);
                next.0 += 1;
            }
            Err(error) => {
                error!("{error}; the body is not simulated");
                commands.entity(entity).insert(error);
            }
        }
    }
}

/// A body whose inputs changed after an error is tried again.
#[allow(clippy::type_complexity)]
pub(super) fn retry_failed_bodies(
    mut commands: Commands,
    failed: Query<
        Entity,
        (
            With<SoftBodyError>,
            Or<(
                Changed<SoftBody>,
                Changed<TissueMaterial>,
                Changed<SoftBodyTuning>,
                Changed<Transform>,
            )>,
        ),
    >,
) {
    for e in &failed {
        commands.entity(e).remove::<SoftBodyError>();
    }
}

/// The pose of a tool entity now: position and frame orientation (local +Y the shaft) in
/// core types.
pub(super) fn tool_pose(
    poses: &TransformHelper,
    entity: Entity,
) -> Option<(soft_tissue_core::Vec3, nalgebra::UnitQuaternion<f64>)> {
    // Computed now, not the one propagated at the end of the last frame.
    let pose = poses.compute_global_transform(entity).ok()?;
    let (_, rotation, translation) = pose.to_scale_rotation_translation();
    Some((
        to_core(translation),
        crate::convert::to_core_rotation(rotation),
    ))
}

/// Builds the core obstacles of every [`SoftObstacle`] again when one was added, changed,
/// moved or removed (sorted by entity, so the order does not depend on the query's).
#[allow(clippy::type_complexity)]
pub(super) fn build_obstacles(
    changed: Query<
        (),
        (
            With<SoftObstacle>,
            Or<(Changed<SoftObstacle>, Changed<GlobalTransform>)>,
        ),
    >,
    all: Query<(Entity, &SoftObstacle, Option<&Name>)>,
    mut removed: RemovedComponents<SoftObstacle>,
    poses: TransformHelper,
    mut obstacles: ResMut<SoftTissueObstacles>,
    mut status: ResMut<SoftTissueStatus>,
) {
    let removed = removed.read().count() > 0;
    let count = all.iter().count();
    if !removed && changed.is_empty() && count == obstacles.entities.len() {
        return;
    }
    let mut list: Vec<_> = all.iter().collect();
    list.sort_unstable_by_key(|(e, ..)| *e);
    obstacles.obstacles.clear();
    obstacles.entities.clear();
    for (entity, spec, name) in list {
        let name = name.map_or_else(|| format!("{entity}"), |n| n.as_str().to_owned());
        let Some((position, rotation)) = tool_pose(&poses, entity) else {
            continue;
        };
        let pose = soft_tissue_core::contact::Pose::from_parts(
            nalgebra::Translation3::from(position),
            rotation,
        );
        match Obstacle::new(name, spec.collider.shape(), pose, spec.friction) {
            Ok(o) => {
                obstacles.obstacles.push(o);
                obstacles.entities.push(entity);
            }
            Err(e) => fail(
                &mut status,
                stage_error(SoftTissueStage::Prepare, "an obstacle", Some(entity), e),
            ),
        }
    }
}

pub(super) fn build_tools(
    mut commands: Commands,
    new: Query<(Entity, &SoftTool, Option<&Name>), Without<ToolState>>,
    poses: TransformHelper,
    mut next: Local<u64>,
) {
    for (entity, spec, name) in &new {
        let name = name.map_or_else(|| format!("{entity}"), |n| n.as_str().to_owned());
        // The tool starts where its entity is (not at the origin).
        let built = Tool::new(name.clone(), spec.shape).and_then(|mut t| {
            if let Some((p, r)) = tool_pose(&poses, entity) {
                t.set_pose_rotation(p, r)?;
            }
            t.set_friction(spec.friction)?;
            if let ToolShape::Grasper { .. } = spec.shape {
                t.set_opening(spec.jaws)?;
            }
            Ok(t)
        });
        match built {
            Ok(tool) => {
                commands.entity(entity).insert(ToolState {
                    tool,
                    order: *next,
                    grabbing: false,
                    incision: None,
                });
                *next += 1;
            }
            Err(e) => {
                error!("tool `{name}` was not built: {e}");
                commands.entity(entity).despawn();
            }
        }
    }
}
