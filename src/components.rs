//! The components of the design card. A user spawns [`SoftBody`] (and, for a tool,
//! [`SoftTool`] with a `Transform`); the plugin adds the rest when the body is built, and only
//! what the body uses: [`FemState`] for a FEM body, [`MsdState`] for an MSD body,
//! [`Temperature`] when the body has heat parameters.
//!
//! The physics state of a body is one core [`WorldBody`] in [`SoftBodyState`]; the stage
//! systems hand those to the core's stage functions. The other components are what the
//! Writeback stage reads out of it for games, the inspector and the renderer.

use bevy::prelude::*;
use soft_tissue_core::cage::CageDynamics;
use soft_tissue_core::contact::{
    DEFAULT_ELECTRODE_RADIUS, Friction, JawShape, MeshShape, RigidShape, Tool, ToolShape,
};
use soft_tissue_core::fem::FemIntegrator;
use soft_tissue_core::heat::HeatParams;
use soft_tissue_core::material::{FemParams, MsdParams};
use soft_tissue_core::msd::SpringStiffness;
use soft_tissue_core::precision::{BodySettings, PrecisionPolicy};
use soft_tissue_core::scenario::{Anchor, CageKind, ORGAN_FEM};
use soft_tissue_core::state::NodalModel;
use soft_tissue_core::world::WorldBody;

use crate::assets::TetMeshAsset;

/// A soft body: what a user spawns. `SoftBody::new(mesh)` is a whole body: the default
/// [`TissueMaterial`] (an organ), corotational FEM when touched, a box cage at rest, free
/// (no supports). The plugin builds the simulation once the mesh asset has loaded.
///
/// The entity's global transform at that moment places the mesh (scale, rotation and
/// translation are baked into the simulation, which runs in world coordinates); the
/// rendered mesh is written in the entity's own frame, so parents and the `Transform` stay
/// as the user set them. Moving or turning the entity (or a parent) later moves the whole
/// body rigidly with it at the next step (a teleport): its deformation, velocities (turned),
/// level, temperatures and damage are kept, and nothing springs back
/// ([`soft_tissue_core::world::WorldBody::teleport`]); a change of scale builds it again at
/// rest.
///
/// Every field, and the optional components [`TissueMaterial`], [`TissueHeat`],
/// [`SoftBodyTuning`] and [`PinnedLevel`], may be written at run time and takes effect at
/// the next step: the method and the material without a jump, the cage, anchor and tuning
/// by building the body again.
#[derive(Component, Reflect, Clone, Debug)]
#[reflect(Component, from_reflect = false)]
#[require(Transform, TissueMaterial)]
pub struct SoftBody {
    /// The tetrahedral mesh.
    pub mesh: Handle<TetMeshAsset>,
    /// The precise method the body rises to when touched (default corotational FEM).
    pub method: PreciseMethod,
    /// The cage of the cheap level (default the mesh's bounding box).
    pub cage: CageKind,
    /// How the body is held (default free).
    pub anchor: Anchor,
}

impl SoftBody {
    /// A body of `mesh` with the defaults: corotational FEM, a box cage, free.
    pub fn new(mesh: Handle<TetMeshAsset>) -> Self {
        SoftBody {
            mesh,
            method: PreciseMethod::CorotationalFem,
            cage: CageKind::BoundingBox,
            anchor: Anchor::Free,
        }
    }

    /// The same body with another precise method.
    pub fn with_method(mut self, method: PreciseMethod) -> Self {
        self.method = method;
        self
    }

    /// The same body with another cage.
    pub fn with_cage(mut self, cage: CageKind) -> Self {
        self.cage = cage;
        self
    }

    /// The same body held by `anchor`.
    pub fn with_anchor(mut self, anchor: Anchor) -> Self {
        self.anchor = anchor;
        self
    }
}

/// The tissue's material: the FEM parameters, and what an MSD method uses. Units are the
/// scene's: lengths in scene units (our organs: 1 unit is about 10 cm), masses in mass
/// units, time in seconds, so Young's modulus is mass / (unit s^2).
///
/// The default is the paper's organ (section IV-B): Young's modulus 140, Poisson ratio
/// 0.23, total mass 10, damping 10 / s, and for an MSD springs fitted to that material with
/// the same mass and damping. Written at run time, it takes effect at the next step without
/// a jump (the precise solver is built again).
#[derive(Component, Reflect, Clone, Copy, Debug, PartialEq)]
#[reflect(Component)]
pub struct TissueMaterial {
    /// Young's modulus, Poisson ratio, total mass and (mass-proportional) damping.
    pub fem: FemParams,
    /// What an MSD precise method uses.
    pub msd: MsdMaterial,
    /// Surface friction against tools, obstacles and other bodies (combined with theirs).
    pub friction: Friction,
    /// Fracture toughness, energy per area of cut (force per length in the scene's units;
    /// liver about 164 J/m^2 in metres): a cutting blade is held back by it, and
    /// [`SoftTool`]'s force includes that resistance. 0 (the default): a blade cuts freely.
    pub toughness: f64,
}

impl Default for TissueMaterial {
    fn default() -> Self {
        TissueMaterial {
            fem: ORGAN_FEM.params,
            msd: MsdMaterial::FromFem,
            friction: Friction::default(),
            toughness: 0.0,
        }
    }
}

/// The springs, mass and damping of a body whose precise method is MSD.
#[derive(Reflect, Clone, Copy, Debug, PartialEq, Default)]
pub enum MsdMaterial {
    /// Springs fitted to the FEM material's Young's modulus and Poisson ratio
    /// ([`SpringStiffness::Material`]), the FEM mass, and per-node damping equal to the FEM
    /// damping rate times the node's share of the mass.
    #[default]
    FromFem,
    /// Parameters of their own (the paper's MSD: one stiffness for every spring).
    Own {
        /// Spring stiffness, mass and per-node damping.
        params: MsdParams,
        /// Where the spring stiffnesses come from.
        springs: SpringStiffness,
    },
}

impl TissueMaterial {
    /// The MSD parameters and springs this material gives a mesh of `nodes` nodes.
    pub fn msd_params(&self, nodes: usize) -> (MsdParams, SpringStiffness) {
        match self.msd {
            MsdMaterial::FromFem => (
                MsdParams {
                    // Not used by fitted springs; a valid value.
                    stiffness: self.fem.young_modulus,
                    mass: self.fem.mass,
                    damping: self.fem.damping * self.fem.mass / nodes.max(1) as f64,
                },
                SpringStiffness::Material {
                    young_modulus: self.fem.young_modulus,
                    poisson_ratio: self.fem.poisson_ratio,
                },
            ),
            MsdMaterial::Own { params, springs } => (params, springs),
        }
    }
}

/// Gives a body a temperature field with these parameters (and a [`Temperature`]): an
/// electrocautery tool heats it and it shows thermal damage. Added, changed or removed at
/// run time, the field starts again at the initial temperature.
#[derive(Component, Reflect, Clone, Copy, Debug, PartialEq)]
#[reflect(Component)]
pub struct TissueHeat(pub HeatParams);

impl Default for TissueHeat {
    fn default() -> Self {
        TissueHeat(HeatParams::liver())
    }
}

/// Settings most bodies never need (defaults: those of [`BodySettings::new`]). Written at
/// run time, the body is built again.
#[derive(Component, Reflect, Clone, Copy, Debug, PartialEq)]
#[reflect(Component)]
pub struct SoftBodyTuning {
    /// Time integrator of the FEM methods (default backward Euler).
    #[reflect(ignore)]
    pub fem_integrator: FemIntegrator,
    /// How the cage moves: calibrated against the precise model (default) or the paper's
    /// cage MSD.
    #[reflect(ignore)]
    pub cage_dynamics: CageDynamics,
    /// The paper's cage MSD parameters (used with [`CageDynamics::Paper`] only).
    pub cage_msd: MsdParams,
    /// When the body may return to its cage.
    #[reflect(ignore)]
    pub policy: PrecisionPolicy,
}

impl Default for SoftBodyTuning {
    fn default() -> Self {
        let s = BodySettings::new(ORGAN_FEM.params, PLACEHOLDER_MSD, 0.01);
        SoftBodyTuning {
            fem_integrator: s.fem_integrator,
            cage_dynamics: s.cage_dynamics,
            cage_msd: s.cage_msd,
            policy: s.policy,
        }
    }
}

/// Placeholder MSD parameters for settings built only to read their defaults.
const PLACEHOLDER_MSD: MsdParams = MsdParams {
    stiffness: 1.0,
    mass: 1.0,
    damping: 0.0,
};

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
    /// Highest temperature, C: at a node or at a cautery electrode's spot (its millimetre
    /// field, see `soft_tissue_core::heat`).
    pub max: f64,
    /// Tissue coagulated (Arrhenius damage at least 1) at the electrodes' scale, mm^3.
    pub coagulated_mm3: f64,
    /// Tissue that reached boiling (charred) at the electrodes' scale, mm^3.
    pub charred_mm3: f64,
    /// Tissue whose water boiled away (vaporized) at the electrodes' scale, mm^3.
    pub vaporized_mm3: f64,
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
    /// Contacts of this step's contact solve with a force on the body.
    pub contacts: u32,
    /// Deepest penetration of its contacts after this step, scene units.
    pub max_penetration: f64,
    /// The same as a fraction of the body's smallest bounding-box dimension.
    pub penetration_ratio: f64,
    /// Largest surface displacement from the settled shape, scene units.
    pub max_displacement: f64,
    /// Distance of the cage level from a shadow precise simulation, as a fraction of the
    /// smallest dimension (only with [`ShadowSimulation`]).
    pub shadow_error_ratio: Option<f64>,
    /// Precise steps since the body was built or reset whose iterative solve (corotational
    /// FEM, implicit MSD) stopped at its iteration cap above its tolerance and went on with
    /// its last iterate.
    pub unconverged_solves: u64,
    /// Surface triangles that are sides of cuts (drawn as the inside of the tissue).
    pub cut_faces: u32,
    /// Their area at rest, scene units squared.
    pub cut_area: f64,
}

/// What the body is drawn with, when not its simulation surface: a finer visual mesh whose
/// vertices are embedded in the simulation's tetrahedra (each follows the tetrahedron that
/// contains it, or the nearest one for vertices slightly outside) and written every frame.
/// Without this component the body is drawn with its simulation surface. When tissue
/// leaves the mesh, a subdivided one is made again from the new surface; a mesh of your own
/// follows a carve (its vertices in the vaporized tissue move onto the crater's wall) but
/// not a blade's cut (drawn with the simulation surface from then on). A piece a cut takes
/// off gets a subdivided one (the body's levels, 2 for a mesh of your own).
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
/// surface instead; the reason is also logged). Each variant names the body's entity, which
/// the error sits on, and its display name (its [`Name`], else the entity) for messages.
#[derive(Component, Reflect, Clone, Debug, PartialEq, thiserror::Error)]
#[reflect(Component)]
pub enum VisualMeshError {
    /// The mesh is not a triangle list, or its indices or positions are unusable.
    #[error("visual mesh of soft body `{name}` (entity {body}): {message}")]
    BadMesh {
        /// The body's entity.
        body: Entity,
        /// The body's name (its [`Name`], else the entity).
        name: String,
        /// What is wrong.
        message: String,
    },
    /// Vertices could not be embedded in the body's tetrahedra (too far, or the
    /// subdivision failed).
    #[error(
        "visual mesh of soft body `{name}` (entity {body}) cannot follow its tetrahedra: \
         {message}"
    )]
    Embedding {
        /// The body's entity.
        body: Entity,
        /// The body's name (its [`Name`], else the entity).
        name: String,
        /// What is wrong.
        message: String,
    },
}

impl VisualMeshError {
    /// The entity of the body whose visual mesh was refused.
    pub fn body(&self) -> Entity {
        match self {
            VisualMeshError::BadMesh { body, .. } | VisualMeshError::Embedding { body, .. } => {
                *body
            }
        }
    }

    /// The body's name as the message gives it (its [`Name`], else the entity).
    pub fn name(&self) -> &str {
        match self {
            VisualMeshError::BadMesh { name, .. } | VisualMeshError::Embedding { name, .. } => name,
        }
    }
}

/// Runs a shadow precise simulation beside the body's cage level while present, to measure
/// the cage level's error ([`SoftBodyDiagnostics::shadow_error_ratio`]). Costs a precise step
/// per step.
#[derive(Component, Reflect, Clone, Copy, Debug, Default)]
#[reflect(Component)]
pub struct ShadowSimulation;

/// Energies of a body, computed when asked for ([`SoftBodyState::energies`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Energies {
    /// Kinetic energy (scene units).
    pub kinetic: f64,
    /// Elastic (strain or spring) energy, anchors included.
    pub elastic: f64,
}

/// The physics state of a built body: the core body the stage functions step.
#[derive(Component)]
pub struct SoftBodyState {
    pub(crate) body: WorldBody,
    /// Build order: bodies are handed to the stage functions in this order every step.
    pub(crate) order: u64,
    /// The surface changed since the rendered mesh was last written.
    pub(crate) dirty: bool,
    /// The entity's global transform baked into the simulation mesh when the body was built.
    pub(crate) placement: GlobalTransform,
    /// The entity's global transform the simulation is at now: `placement` until the entity
    /// moves, then where its moves (teleports) took it.
    pub(crate) pose: GlobalTransform,
    /// The inverse of `pose`: world to the entity's frame, for the rendered mesh (`None`:
    /// identity).
    pub(crate) to_local: Option<bevy::math::Affine3A>,
    /// What it was built from, beyond what changes in place.
    pub(crate) built_from: crate::physics::BuiltFrom,
    /// Counts the changes of its mesh (cuts, a reset that undoes them): the rendered mesh
    /// is made again when it changes.
    pub(crate) shape: u64,
    /// What changed its mesh since the rendered mesh was made (the carves a visual mesh of
    /// the app's own follows; a reset that makes the body whole starts it again).
    pub(crate) reshaped: crate::render::MeshChanges,
}

impl SoftBodyState {
    /// The core body.
    pub fn body(&self) -> &WorldBody {
        &self.body
    }

    /// The core body, to act on it where no component does (external loads, for example
    /// `body_mut().model_mut().add_force(..)`, which lasts one step).
    pub fn body_mut(&mut self) -> &mut WorldBody {
        self.dirty = true;
        &mut self.body
    }

    /// The entity's global transform when the body was built, baked into the simulation
    /// mesh (it maps the mesh file's coordinates to those of the core body's mesh, where its
    /// heat field and cuts live; see [`WorldBody::frame`]).
    pub fn placement(&self) -> GlobalTransform {
        self.placement
    }

    /// The entity's global transform the simulation is at now: [`SoftBodyState::placement`]
    /// moved by the body's teleports (its mechanics are at the core body's mesh moved by
    /// [`WorldBody::frame`]).
    pub fn pose(&self) -> GlobalTransform {
        self.pose
    }

    /// Records that the simulation is at `pose` now (the rendered mesh is written in its
    /// frame).
    pub(crate) fn set_pose(&mut self, pose: GlobalTransform) {
        self.pose = pose;
        self.to_local =
            (pose.affine() != bevy::math::Affine3A::IDENTITY).then(|| pose.affine().inverse());
    }

    /// Kinetic and elastic energy of the body now, computed on this call (nothing is
    /// computed per step for them): at the precise level the solver's (strain energy of its
    /// model plus its anchors), at the cage level the cage's own (its vertices' kinetic
    /// energy and its springs').
    pub fn energies(&self) -> Energies {
        let b = self.body.model();
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

/// A piece that came loose from a cut body: an entity of its own, with the cut body's
/// components (material, heat, tuning, render material...) cloned, its own [`SoftBody`]
/// mesh (the piece's), and [`SoftBodyState`] in the state it was cut in. A
/// [`ResetSimulation`](crate::physics::ResetSimulation) despawns it.
#[derive(Component, Reflect, Clone, Copy, Debug, PartialEq, Eq)]
#[reflect(Component)]
pub struct CutPiece {
    /// The entity it was cut from.
    pub from: Entity,
}

/// The share of its uncut body's volume, and so of its mass, a cut body or a piece of one
/// has: the plugin gives it that share of its [`TissueMaterial`]'s masses (an MSD's damping
/// stays per node), when it changes the material and when it builds the body again.
#[derive(Component, Reflect, Clone, Copy, Debug, PartialEq)]
#[reflect(Component)]
pub struct CutShare(pub f64);

impl CutShare {
    /// `material` with this share of its masses.
    pub fn of(share: Option<&CutShare>, material: &TissueMaterial) -> TissueMaterial {
        let mut m = *material;
        if let Some(s) = share {
            m.fem.mass *= s.0;
            if let MsdMaterial::Own { params, .. } = &mut m.msd {
                params.mass *= s.0;
            }
        }
        m
    }
}

/// A body as it was before its first cut, kept on the entity so a
/// [`ResetSimulation`](crate::physics::ResetSimulation) puts it back.
#[derive(Component)]
pub struct UncutBody {
    pub(crate) body: Option<Box<soft_tissue_core::world::WorldBody>>,
    pub(crate) mesh: Handle<crate::assets::TetMeshAsset>,
    pub(crate) built_from: crate::physics::BuiltFrom,
    /// Where the body was when it was first cut (see [`SoftBodyState::pose`]).
    pub(crate) pose: GlobalTransform,
}

/// A kinematic tool driven by its entity's `Transform` (position: translation; the tool
/// frame: its rotation, the shaft along local +Y, a grasper's jaws closing along local +X).
#[derive(Component, Reflect, Clone, Copy, Debug)]
#[reflect(Component, from_reflect = false)]
#[require(Transform, ToolReaction)]
pub struct SoftTool {
    /// Tip shape.
    #[reflect(ignore)]
    pub shape: ToolShape,
    /// Hold: grabs the surface points under the tip on the step it turns on, releases them
    /// when it turns off (an exact attach, whatever the friction).
    pub grab: bool,
    /// Electrocautery power delivered at the contact, W (0: off).
    pub cautery_watts: f64,
    /// The cautery electrode's radius, m: its heat is modelled at that scale (a millimetre
    /// spot that chars and vaporizes; `soft_tissue_core::heat`). `None` spreads the power
    /// over the pressed mesh nodes. Default 1 mm.
    pub electrode_radius: Option<f64>,
    /// A grasper's jaw opening the jaws move toward, scene units (0 closes them; ignored by
    /// other tools).
    pub jaws: f64,
    /// A blade cuts the bodies its edge sweeps through while this is on (ignored by other
    /// tools).
    pub cut: bool,
    /// The tool's surface friction (combined with the tissue's).
    pub friction: Friction,
}

impl SoftTool {
    /// A sphere of `radius` (scene units).
    pub fn sphere(radius: f64) -> Self {
        SoftTool {
            shape: ToolShape::Sphere { radius },
            grab: false,
            cautery_watts: 0.0,
            electrode_radius: Some(DEFAULT_ELECTRODE_RADIUS),
            jaws: 0.0,
            cut: false,
            friction: Friction::default(),
        }
    }

    /// A scalpel: a blade edge of `length` (scene units) along the shaft from the tip,
    /// not cutting.
    pub fn blade(length: f64) -> Self {
        SoftTool {
            shape: ToolShape::Blade { length },
            grab: false,
            cautery_watts: 0.0,
            electrode_radius: Some(DEFAULT_ELECTRODE_RADIUS),
            jaws: 0.0,
            cut: false,
            friction: Friction::default(),
        }
    }

    /// A grasper with two `jaw`s opening up to `max_opening` (scene units), open.
    pub fn grasper(jaw: JawShape, max_opening: f64) -> Self {
        SoftTool {
            shape: ToolShape::Grasper { jaw, max_opening },
            grab: false,
            cautery_watts: 0.0,
            electrode_radius: Some(DEFAULT_ELECTRODE_RADIUS),
            jaws: max_opening,
            cut: false,
            friction: Friction::default(),
        }
    }
}

/// What the tissue does back to a tool (written every step).
#[derive(Component, Reflect, Clone, Copy, Debug, Default, PartialEq)]
#[reflect(Component)]
pub struct ToolReaction {
    /// Force of the tissue on the tool, N (scene units): the sum of the forces of its
    /// contacts as the step's contact solve balanced them, and a cutting blade's resistance
    /// ([`ToolReaction::cutting`]).
    pub force: Vec3,
    /// The part of [`ToolReaction::force`] that resists a blade's cut: the fracture energy
    /// of what it cut per distance moved (the bodies' [`TissueMaterial::toughness`]), against
    /// its motion; zero for other tools.
    pub cutting: Vec3,
    /// Contacts with a force.
    pub contacts: u32,
    /// Grabbed surface points.
    pub grips: u32,
    /// A grasper's jaw opening now, scene units.
    pub opening: f64,
    /// The normal force on each jaw (a probe's in the first), scene units.
    pub jaw_forces: [f64; 2],
}

/// The shape of a static obstacle, in its entity's frame (the entity's translation and
/// rotation place it; its scale is not applied: the shape holds the sizes).
#[derive(Clone, Debug)]
pub enum ObstacleCollider {
    /// The half-space below the local plane y = 0 (a table top).
    Plane,
    /// A box centred on the entity.
    Box {
        /// Half extents, scene units.
        half_extents: Vec3,
    },
    /// A ball.
    Sphere {
        /// Radius, scene units.
        radius: f64,
    },
    /// A capsule around the segment from the entity along local +Y (a rib, a rod).
    Capsule {
        /// Radius, scene units.
        radius: f64,
        /// Segment length, scene units.
        length: f64,
    },
    /// A closed triangle surface (a bone), built once and shared.
    Mesh(std::sync::Arc<MeshShape>),
}

impl ObstacleCollider {
    /// The collider of a core shape.
    pub fn from_shape(shape: &RigidShape) -> Self {
        match shape {
            RigidShape::Plane => ObstacleCollider::Plane,
            RigidShape::Box { half_extents } => ObstacleCollider::Box {
                half_extents: crate::convert::to_bevy(half_extents),
            },
            RigidShape::Sphere { radius } => ObstacleCollider::Sphere { radius: *radius },
            RigidShape::Capsule { radius, length } => ObstacleCollider::Capsule {
                radius: *radius,
                length: *length,
            },
            RigidShape::Mesh(m) => ObstacleCollider::Mesh(m.clone()),
        }
    }

    /// The core shape.
    pub fn shape(&self) -> RigidShape {
        match self {
            ObstacleCollider::Plane => RigidShape::Plane,
            ObstacleCollider::Box { half_extents } => RigidShape::Box {
                half_extents: crate::convert::to_core(*half_extents),
            },
            ObstacleCollider::Sphere { radius } => RigidShape::Sphere { radius: *radius },
            ObstacleCollider::Capsule { radius, length } => RigidShape::Capsule {
                radius: *radius,
                length: *length,
            },
            ObstacleCollider::Mesh(m) => RigidShape::Mesh(m.clone()),
        }
    }

    /// A mesh obstacle from a Bevy triangle-list mesh's positions and indices (its own
    /// frame). A mesh of another topology, without positions, with indices that are not
    /// whole triangles, or whose surface the contact refuses (no triangles, a bad index, a
    /// non-finite vertex) is refused by name.
    pub fn from_mesh(mesh: &Mesh) -> Result<Self, ObstacleMeshError> {
        let topology = mesh.primitive_topology();
        if topology != bevy::mesh::PrimitiveTopology::TriangleList {
            return Err(ObstacleMeshError::NotTriangles(topology));
        }
        let positions = mesh
            .attribute(Mesh::ATTRIBUTE_POSITION)
            .and_then(|a| a.as_float3())
            .ok_or(ObstacleMeshError::NoPositions)?;
        let vertices: Vec<_> = positions
            .iter()
            .map(|p| crate::convert::to_core(Vec3::from_array(*p)))
            .collect();
        let indices: Vec<u32> = match mesh.indices() {
            Some(i) => i.iter().map(|k| k as u32).collect(),
            None => (0..vertices.len() as u32).collect(),
        };
        if !indices.len().is_multiple_of(3) {
            return Err(ObstacleMeshError::PartialTriangle {
                count: indices.len(),
            });
        }
        let triangles = indices
            .chunks_exact(3)
            .map(|t| [t[0], t[1], t[2]])
            .collect();
        Ok(ObstacleCollider::Mesh(std::sync::Arc::new(MeshShape::new(
            vertices, triangles,
        )?)))
    }
}

/// Why a Bevy mesh makes no obstacle ([`ObstacleCollider::from_mesh`]).
#[derive(Debug, thiserror::Error)]
pub enum ObstacleMeshError {
    /// Not a triangle list.
    #[error("obstacle mesh: a {0:?} mesh, not a triangle list")]
    NotTriangles(bevy::mesh::PrimitiveTopology),
    /// No `ATTRIBUTE_POSITION` of three floats.
    #[error("obstacle mesh: it has no float3 positions")]
    NoPositions,
    /// Indices (or vertices, unindexed) not a multiple of three.
    #[error("obstacle mesh: {count} indices are not whole triangles")]
    PartialTriangle {
        /// Indices (vertices where unindexed).
        count: usize,
    },
    /// The contact refused the surface.
    #[error("obstacle mesh: {0}")]
    Shape(#[from] soft_tissue_core::contact::ContactError),
}

/// A static rigid obstacle the bodies rest on or are pushed against (a table, a rib, an
/// instrument port), placed by its entity's `Transform`. Moving the entity moves it (bodies
/// touching it are pushed by the contact solve, as by a tool).
#[derive(Component, Clone, Debug)]
#[require(Transform)]
pub struct SoftObstacle {
    /// Shape.
    pub collider: ObstacleCollider,
    /// Surface friction (combined with the tissue's).
    pub friction: Friction,
}

impl SoftObstacle {
    /// An obstacle of `collider` with the default friction.
    pub fn new(collider: ObstacleCollider) -> Self {
        SoftObstacle {
            collider,
            friction: Friction::default(),
        }
    }
}

/// The core tool of a [`SoftTool`].
#[derive(Component)]
pub struct ToolState {
    pub(crate) tool: Tool,
    pub(crate) order: u64,
    pub(crate) grabbing: bool,
    /// A blade's incision while it cuts.
    pub(crate) incision: Option<soft_tissue_core::world::Incision>,
}

impl ToolState {
    /// The core tool.
    pub fn tool(&self) -> &Tool {
        &self.tool
    }
}
