//! The components of the design card. A user spawns [`SoftBody`] (and, for a tool,
//! [`SoftTool`] with a `Transform`); the plugin adds the rest when the body is built, and only
//! what the body uses: [`FemState`] for a FEM body, [`MsdState`] for an MSD body,
//! [`Temperature`] when the body has heat parameters.
//!
//! The physics state of a body is one core [`SimBody`] in [`SimulatedBody`]; the stage
//! systems hand those to the core's stage functions. The other components are what the
//! Writeback stage reads out of it for games, the inspector and the renderer.

use bevy::prelude::*;
use soft_tissue_core::contact::{Tool, ToolShape};
use soft_tissue_core::heat::HeatParams;
use soft_tissue_core::precision::BodySettings;
use soft_tissue_core::state::NodalBody;
use soft_tissue_core::world::SimBody;

use crate::assets::TetMeshAsset;

/// A soft body: its tetrahedral mesh and its settings. What a user spawns; the plugin builds
/// the simulation once the mesh asset is loaded.
///
/// The entity's `Transform` at that moment places the mesh (its scale, rotation and
/// translation are baked into the simulation mesh) and is then set to identity: from then on
/// the simulation owns the shape, and the rendered mesh is written in world coordinates.
#[derive(Component, Reflect, Clone, Debug)]
#[reflect(Component, from_reflect = false)]
#[require(Transform)]
pub struct SoftBody {
    /// The tetrahedral mesh.
    pub mesh: Handle<TetMeshAsset>,
    /// The precise method the body rises to when touched. Change it at run time: the body
    /// switches solver without a jump.
    pub method: PreciseMethod,
    /// Material, cage, boundary, gravity and step (`method` overrides `settings.precise`).
    /// The step must equal the plugin's [`crate::SoftTissueConfig::dt`].
    #[reflect(ignore)]
    pub settings: BodySettings,
    /// Heat parameters: `Some` gives the body a temperature field (and a [`Temperature`]).
    #[reflect(ignore)]
    pub heat: Option<HeatParams>,
}

impl SoftBody {
    /// A body of `mesh` with `settings` (its precise method taken from them), no heat.
    pub fn new(mesh: Handle<TetMeshAsset>, settings: BodySettings) -> Self {
        SoftBody {
            mesh,
            method: settings.precise,
            settings,
            heat: None,
        }
    }

    /// The same body with a temperature field.
    pub fn with_heat(mut self, heat: HeatParams) -> Self {
        self.heat = Some(heat);
        self
    }
}

pub use soft_tissue_core::precision::{Level, PreciseMethod};

/// The level a body runs at now and what its switches did (written by the switcher).
#[derive(Component, Reflect, Clone, Copy, Debug, PartialEq, Default)]
#[reflect(Component)]
pub struct PrecisionLevel {
    /// Current level.
    pub level: Level,
    /// The precise method the body rises to.
    pub method: PreciseMethod,
    /// Switches so far.
    pub switches: u64,
    /// Largest surface-vertex jump of the last switch, as a fraction of the body's smallest
    /// bounding-box dimension.
    pub last_jump_ratio: Option<f64>,
}

/// Pins a body to a level while present (the switcher leaves it there); remove it to let the
/// body switch again.
#[derive(Component, Reflect, Clone, Copy, Debug, PartialEq, Eq)]
#[reflect(Component)]
pub struct PinnedLevel(pub Level);

/// The body's cage: its triangles and current vertex positions (world coordinates, updated
/// while the body is at the cage level), for display.
#[derive(Component, Reflect, Clone, Debug, Default)]
#[reflect(Component)]
pub struct GreenCage {
    /// Cage vertex positions.
    pub vertices: Vec<Vec3>,
    /// Cage triangles (indices into `vertices`).
    pub triangles: Vec<[u32; 3]>,
    /// Whether the cage drives the body now.
    pub active: bool,
}

/// Read-out of a FEM body's solver (only on bodies whose precise method is FEM).
#[derive(Component, Reflect, Clone, Copy, Debug, Default, PartialEq)]
#[reflect(Component)]
pub struct FemState {
    /// Whether the model is corotational (otherwise linear).
    pub corotational: bool,
    /// Conjugate-gradient iterations of the last precise step (0 for the direct solve).
    pub cg_iterations: u32,
    /// Final relative residual of that solve (0 for the direct solve).
    pub cg_residual: f64,
    /// Whether that solve met its tolerance within its iteration cap.
    pub cg_converged: bool,
}

/// Read-out of an MSD body's solver (only on bodies whose precise method is MSD).
#[derive(Component, Reflect, Clone, Copy, Debug, Default, PartialEq)]
#[reflect(Component)]
pub struct MsdState {
    /// The integrator.
    pub integrator: PreciseMethod,
    /// Substeps of the last precise step (explicit integrators).
    pub substeps: u32,
    /// Conjugate-gradient iterations of the last precise step (implicit integrator; 0
    /// otherwise).
    pub cg_iterations: u32,
    /// Whether that solve met its tolerance within its iteration cap (true without one).
    pub cg_converged: bool,
}

/// Temperatures and thermal damage of a body with a heat field (only on those).
#[derive(Component, Reflect, Clone, Debug, Default)]
#[reflect(Component)]
pub struct Temperature {
    /// Temperature of every surface vertex (in the order of the rendered mesh), C.
    pub surface: Vec<f32>,
    /// Damaged fraction (0..1, Arrhenius) of every surface vertex.
    pub damage: Vec<f32>,
    /// Lowest node temperature, C.
    pub min: f64,
    /// Highest node temperature, C.
    pub max: f64,
    /// The heat field's version these values were read at (see `HeatField::version`).
    #[reflect(ignore)]
    pub(crate) version: Option<u64>,
}

/// Per-body timings and counts of the last fixed step.
#[derive(Component, Reflect, Clone, Copy, Debug, Default, PartialEq)]
#[reflect(Component)]
pub struct SoftBodyDiagnostics {
    /// Wall time of this body's solver step (level and heat), microseconds.
    pub step_us: f64,
    /// Contacts found this step.
    pub contacts: u32,
    /// Largest surface displacement from the settled shape, scene units.
    pub max_displacement: f64,
    /// Distance of the cage level from a shadow precise simulation, as a fraction of the
    /// smallest dimension (only with [`ShadowSimulation`]).
    pub shadow_error_ratio: Option<f64>,
    /// Precise steps since the body was built or reset whose iterative solve (corotational
    /// FEM, implicit MSD) stopped at its iteration cap above its tolerance and went on with
    /// its last iterate.
    pub unconverged_solves: u64,
}

/// What the body is drawn with, when not its simulation surface: a finer visual mesh whose
/// vertices are embedded in the simulation's tetrahedra (each follows the tetrahedron that
/// contains it, or the nearest one for vertices slightly outside) and written every frame.
/// Without this component the body is drawn with its simulation surface.
#[derive(Component, Reflect, Clone, Debug)]
#[reflect(Component)]
pub enum VisualMesh {
    /// A mesh of your own (any `TriangleList` mesh, indexed or not; its other attributes,
    /// such as UVs, are kept), in the coordinates of the body's tetrahedral mesh file (the
    /// body's placement `Transform` is applied to it too).
    Mesh {
        /// The mesh to deform; the asset itself is left untouched (a copy is deformed).
        mesh: Handle<Mesh>,
        /// Largest distance of a vertex from the tetrahedra, scene units; farther vertices
        /// are refused ([`VisualMeshError`]). `None`: 25 % of the body's smallest dimension.
        max_distance: Option<f32>,
    },
    /// The simulation surface smoothed and refined by `levels` rounds of Loop subdivision
    /// (four times the triangles per level; 1 to 3 is typical).
    Subdivided {
        /// Rounds of subdivision.
        levels: u8,
    },
}

impl VisualMesh {
    /// A mesh of your own, with the default distance limit.
    pub fn mesh(mesh: Handle<Mesh>) -> Self {
        VisualMesh::Mesh {
            mesh,
            max_distance: None,
        }
    }
}

/// Why a body's [`VisualMesh`] could not be used (the body is drawn with its simulation
/// surface instead; the reason is also logged).
#[derive(Component, Reflect, Clone, Debug, PartialEq)]
#[reflect(Component)]
pub struct VisualMeshError(pub String);

/// Runs a shadow precise simulation beside the body's cage level while present, to measure
/// the cage level's error ([`SoftBodyDiagnostics::shadow_error_ratio`]). Costs a precise step
/// per step.
#[derive(Component, Reflect, Clone, Copy, Debug, Default)]
#[reflect(Component)]
pub struct ShadowSimulation;

/// Energies of a body, computed when asked for ([`SimulatedBody::energies`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Energies {
    /// Kinetic energy (scene units).
    pub kinetic: f64,
    /// Elastic (strain or spring) energy, anchors included.
    pub elastic: f64,
}

/// The physics state of a built body: the core body the stage functions step.
#[derive(Component)]
pub struct SimulatedBody {
    pub(crate) body: SimBody,
    /// Build order: bodies are handed to the stage functions in this order every step.
    pub(crate) order: u64,
    /// The surface changed since the rendered mesh was last written.
    pub(crate) dirty: bool,
    /// The entity's `Transform` baked into the simulation mesh when the body was built.
    pub(crate) placement: Transform,
}

impl SimulatedBody {
    /// The core body.
    pub fn body(&self) -> &SimBody {
        &self.body
    }

    /// The entity's `Transform` when the body was built, baked into the simulation mesh
    /// (it maps the mesh file's coordinates to the simulation's).
    pub fn placement(&self) -> Transform {
        self.placement
    }

    /// Kinetic and elastic energy of the body now, computed on this call (nothing is
    /// computed per step for them): at the precise level the solver's (strain energy of its
    /// model plus its anchors), at the cage level the cage's own (its vertices' kinetic
    /// energy and its springs').
    pub fn energies(&self) -> Energies {
        let b = self.body.body();
        match b.level() {
            Level::Precise => {
                let elastic = match (b.fem(), b.msd()) {
                    (Some(f), _) => f.elastic_energy(),
                    (_, Some(m)) => m.elastic_energy(),
                    _ => 0.0,
                };
                Energies {
                    kinetic: b.precise().kinetic_energy(),
                    elastic,
                }
            }
            Level::Cage => {
                let c = b.cage().msd();
                Energies {
                    kinetic: c.kinetic_energy(),
                    elastic: c.elastic_energy(),
                }
            }
        }
    }
}

/// A kinematic tool driven by its entity's `Transform` (position: translation; axis: the
/// local +Y axis, for capsules).
#[derive(Component, Reflect, Clone, Copy, Debug)]
#[reflect(Component, from_reflect = false)]
#[require(Transform, ToolReaction)]
pub struct SoftTool {
    /// Tip shape.
    #[reflect(ignore)]
    pub shape: ToolShape,
    /// Hold: grabs the surface points under the tip on the step it turns on, releases them
    /// when it turns off.
    pub grab: bool,
    /// Electrocautery power delivered at the contact, W (0: off).
    pub cautery_watts: f64,
}

impl SoftTool {
    /// A sphere of `radius` (scene units).
    pub fn sphere(radius: f64) -> Self {
        SoftTool {
            shape: ToolShape::Sphere { radius },
            grab: false,
            cautery_watts: 0.0,
        }
    }
}

/// What the tissue does back to a tool (written every step).
#[derive(Component, Reflect, Clone, Copy, Debug, Default, PartialEq)]
#[reflect(Component)]
pub struct ToolReaction {
    /// Reaction force on the tool, N (scene units).
    pub force: Vec3,
    /// Surface triangles in contact.
    pub contacts: u32,
    /// Grabbed surface points.
    pub grips: u32,
}

/// The core tool of a [`SoftTool`].
#[derive(Component)]
pub struct ToolState {
    pub(crate) tool: Tool,
    pub(crate) order: u64,
    pub(crate) grabbing: bool,
}

impl ToolState {
    /// The core tool.
    pub fn tool(&self) -> &Tool {
        &self.tool
    }
}
