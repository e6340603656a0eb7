//! # bevy_soft_tissue
//!
//! Real-time simulation of many soft organs at once, each at its own level of precision:
//! a precise method (tetrahedral FEM or mass-spring-damper) while a tool touches it, and a
//! cheap Green-coordinate cage when it rests (Fernandes e Silva et al., "A Levels-of-Precision
//! Approach for Simulating Multiple Physics-based Soft Tissues").
//!
//! All physics and geometry live in the engine-free [`soft_tissue_core`] crate (re-exported
//! as [`core`]). This crate is the Bevy plugin: components, the step's system sets, assets,
//! render meshes, gizmos and the inspector. Its systems are thin adapters that hand the
//! bodies' core state, held in components, to the core's stage functions; there is no second
//! world kept in sync.
//!
//! ```no_run
//! use bevy::prelude::*;
//! use bevy_soft_tissue::prelude::*;
//!
//! fn setup(mut commands: Commands, assets: Res<AssetServer>) {
//!     let settings = BodySettings::new(
//!         bevy_soft_tissue::core::scenario::ORGAN_FEM.params,
//!         bevy_soft_tissue::core::scenario::CYLINDER_MSD.params,
//!         0.02,
//!     );
//!     commands.spawn((
//!         Name::new("liver"),
//!         SoftBody::new(assets.load("meshes/liver.vtk"), settings),
//!         MeshMaterial3d::<StandardMaterial>::default(),
//!     ));
//!     commands.spawn((SoftTool::sphere(0.05), Transform::from_xyz(0.0, 1.0, 0.0)));
//! }
//!
//! App::new()
//!     .add_plugins((DefaultPlugins, SoftTissuePlugins::default()))
//!     .add_systems(Startup, setup)
//!     .run();
//! ```
//!
//! ## Features
//! - `render` (default): windowed 3D rendering for the example apps.
//! - `inspector` (default): the egui panel ([`inspector`]).
//! - `debug-render` (default): gizmos for cages, contacts and tools ([`mod@debug`]).
//! - `haptics` (default): [`haptics::HapticTool`], a tool driven by a force-feedback device
//!   through the 1 kHz haptic thread (no thread runs unless a `HapticTool` is spawned).
//! - `serialize`: Bevy's reflection serialisation.
//!
//! A headless build (`default-features = false`) needs only Bevy's ECS, assets and meshes.

use std::path::Path;

use bevy::app::PluginGroupBuilder;
use bevy::ecs::schedule::{InternedScheduleLabel, ScheduleLabel};
use bevy::prelude::*;

pub use soft_tissue_core as core;

pub mod assets;
pub mod components;
pub mod convert;
#[cfg(feature = "debug-render")]
pub mod debug;
#[cfg(feature = "haptics")]
pub mod haptics;
#[cfg(feature = "inspector")]
pub mod inspector;
pub mod messages;
pub mod physics;
pub mod render;

pub use assets::{
    SceneAsset, SceneLoadError, SceneLoader, SceneLoaderSettings, SoftTissueAssetPlugin,
    TetMeshAsset,
};
pub use components::*;
pub use messages::{BodyTouched, LevelChanged};
pub use physics::{
    ResetSimulation, SoftBodyError, SoftTissueConfig, SoftTissueContacts, SoftTissuePhysicsPlugin,
    SoftTissueSchedule, SoftTissueStatus, SoftTissueStep, SoftTissueSystems, SoftTissueThreads,
};
pub use render::{EmbeddedVisual, SoftBodyMesh, SoftTissueMeshPlugin, SoftTissueMeshSystems};

/// What a game needs in one `use`.
pub mod prelude {
    pub use crate::components::*;
    pub use crate::core::precision::BodySettings;
    pub use crate::messages::{BodyTouched, LevelChanged};
    pub use crate::physics::{
        ResetSimulation, SoftTissueConfig, SoftTissueSchedule, SoftTissueStatus, SoftTissueStep,
        SoftTissueSystems,
    };
    pub use crate::{SoftTissuePlugins, TetMeshAsset, spawn_scene};
}

/// Every plugin of the crate (each replaceable through `PluginGroupBuilder`): assets,
/// physics (its [`SoftTissueSchedule`] run from `schedule`, `FixedUpdate` by default), render
/// meshes, and with their features
/// the debug gizmos and the inspector.
pub struct SoftTissuePlugins {
    schedule: InternedScheduleLabel,
}

impl SoftTissuePlugins {
    /// The plugins with the physics step in `schedule`.
    pub fn new(schedule: impl ScheduleLabel) -> Self {
        SoftTissuePlugins {
            schedule: schedule.intern(),
        }
    }
}

impl Default for SoftTissuePlugins {
    fn default() -> Self {
        Self::new(FixedUpdate)
    }
}

impl PluginGroup for SoftTissuePlugins {
    fn build(self) -> PluginGroupBuilder {
        let group = PluginGroupBuilder::start::<Self>()
            .add(SoftTissueAssetPlugin)
            .add(SoftTissuePhysicsPlugin::new(self.schedule))
            .add(SoftTissueMeshPlugin);
        #[cfg(feature = "debug-render")]
        let group = group.add(debug::SoftTissueDebugPlugin);
        #[cfg(feature = "inspector")]
        let group = group.add(inspector::SoftTissueInspectorPlugin);
        #[cfg(feature = "haptics")]
        let group = group.add(haptics::SoftTissueHapticsPlugin);
        group
    }
}

/// Spawns the bodies of a scene (mesh files relative to `assets_dir`, or generated) with their
/// names, and sets [`SoftTissueConfig`] to the scene's step and contact scale. Returns the
/// entities in scene order. The meshes are added to `Assets<TetMeshAsset>` directly.
pub fn spawn_scene(
    world: &mut World,
    scene: &core::scenario::Scene,
    assets_dir: &Path,
) -> Result<Vec<Entity>, core::world::WorldError> {
    let (config, bodies) = core::world::scene_bodies(scene, assets_dir)?;
    let threads = world
        .get_resource::<SoftTissueConfig>()
        .map_or(0, |c| c.threads);
    world.insert_resource(SoftTissueConfig {
        dt: config.dt,
        contact: config.contact,
        threads,
    });
    let mut entities = Vec::with_capacity(bodies.len());
    for b in bodies {
        let handle = world
            .resource_mut::<Assets<TetMeshAsset>>()
            .add(TetMeshAsset::from(b.mesh));
        let mut body = SoftBody::new(handle, b.settings);
        body.heat = b.heat.map(|(p, _)| p);
        entities.push(world.spawn((Name::new(b.name), body)).id());
    }
    Ok(entities)
}
