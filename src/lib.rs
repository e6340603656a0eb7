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
//!     // A liver with the default organ material, a box cage and corotational FEM.
//!     commands.spawn((
//!         SoftBody::new(assets.load("meshes/liver.vtk")),
//!         Transform::from_xyz(0.0, 0.5, 0.0),
//!     ));
//!     // A whole scene file, its bodies children of this entity, 3 units to the side.
//!     commands.spawn((
//!         SoftTissueSceneRoot(assets.load("scenes/organs.scene.ron")),
//!         Transform::from_xyz(3.0, 0.0, 0.0),
//!     ));
//!     commands.spawn((SoftTool::sphere(0.05), Transform::from_xyz(0.0, 1.2, 0.0)));
//! }
//!
//! App::new()
//!     .add_plugins((DefaultPlugins, SoftTissuePlugins::default()))
//!     .add_systems(Startup, setup)
//!     .run();
//! ```
//!
//! Optional components change a body: [`TissueMaterial`], [`TissueHeat`],
//! [`SoftBodyTuning`], [`PinnedLevel`], [`ShadowSimulation`], [`VisualMesh`]. Written at
//! run time, they take effect at the next step. The simulation steps in `FixedUpdate` at the
//! app's fixed timestep on its own clock, `Time<`[`SoftPhysics`]`>`, which owns pause, speed
//! and the step ([`SoftPhysicsTime`]); moving a body's entity moves the whole body rigidly,
//! deformation and heat kept; contacts name entities
//! ([`SoftTissueContacts`]), and so do the messages [`LevelChanged`] and [`BodyTouched`].
//!
//! ## Where to read more
//! The repository's `docs/` folder has one page per part, as the README links them:
//! solvers (FEM, MSD, BDF2), the cage level, world and contact, the plugin (this crate:
//! components, schedule, time, scenes, apps), haptics, the measured report and the
//! formats. In this crate:
//! - [`components`]: what a user spawns ([`SoftBody`], [`SoftTool`]) and writes
//!   ([`TissueMaterial`], [`TissueHeat`], [`SoftBodyTuning`], [`PinnedLevel`]), and what the
//!   plugin writes back ([`PrecisionLevel`], [`GreenCage`], [`FemState`], [`MsdState`],
//!   [`Temperature`], [`SoftBodyDiagnostics`]).
//! - [`physics`]: the step's schedule and sets, [`SoftTissueConfig`], the clock, the status,
//!   contacts by entity.
//! - [`assets`]: mesh and scene loaders, [`SoftTissueSceneRoot`].
//! - [`render`]: render meshes and [`VisualMesh`]es; [`messages`]: [`LevelChanged`],
//!   [`BodyTouched`].
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
    SceneAsset, SceneBodies, SceneLoadError, SceneLoader, SceneLoaderSettings,
    SoftTissueAssetPlugin, SoftTissueSceneRoot, SurfaceLoadError, SurfaceLoader,
    SurfaceLoaderSettings, TetMeshAsset, spawn_scene_and_wait,
};
pub use components::*;
pub use messages::{BodyTouched, LevelChanged};
pub use physics::{
    BadSpeed, ContactPartner, ResetSimulation, SoftBodyError, SoftContact, SoftPhysics,
    SoftPhysicsTime, SoftTissueConfig, SoftTissueContacts, SoftTissueError, SoftTissueObstacles,
    SoftTissuePhysicsPlugin, SoftTissueSchedule, SoftTissueStage, SoftTissueStatus, SoftTissueStep,
    SoftTissueStepError, SoftTissueSystems, SoftTissueThreads,
};
pub use render::{
    EmbeddedVisual, INSIDE_COLOUR, RenderedSurface, SoftBodyMesh, SoftTissueMeshPlugin,
    SoftTissueMeshSystems,
};

/// What a game needs in one `use`.
pub mod prelude {
    pub use crate::SoftTissuePlugins;
    pub use crate::assets::{SceneAsset, SceneBodies, SoftTissueSceneRoot, TetMeshAsset};
    pub use crate::components::*;
    pub use crate::core::contact::{Friction, FrictionCombine, JawShape, ToolShape};
    pub use crate::core::heat::HeatParams;
    pub use crate::core::material::{FemParams, MsdParams};
    pub use crate::core::msd::SpringStiffness;
    pub use crate::core::scenario::{Anchor, CageKind};
    pub use crate::messages::{BodyTouched, LevelChanged};
    pub use crate::physics::{
        ContactPartner, ResetSimulation, SoftContact, SoftPhysics, SoftPhysicsTime,
        SoftTissueConfig, SoftTissueContacts, SoftTissueObstacles, SoftTissueSchedule,
        SoftTissueStatus, SoftTissueStep, SoftTissueSystems,
    };
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
