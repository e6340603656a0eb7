//! `SoftTissueWorld`: many bodies, each at its own level of precision, tools, contact and heat.
//!
//! One fixed step runs the stages of the design in order, each a public function over a slice
//! of bodies so the Bevy plugin calls the same code on its components:
//!
//! ```text
//! cut -> prepare -> detect_contacts -> switch_precision -> step_solvers -> solve_contacts -> writeback
//! ```
//!
//! - cut: every blade with cutting on cuts the bodies its incision crosses
//!   ([`WorldBody::cut_within`], in the step or on a thread of its own: [`WorldBody::begin_cut`]); pieces that come loose are added as bodies (see
//!   `docs/cutting.md`).
//! - [`prepare`]: tool velocities from their poses, body surfaces and bounds gathered.
//! - [`detect_contacts`]: broad phase, tool and body narrow phases on the positions at the
//!   start of the step (with the margins, so a body is raised before anything reaches it),
//!   grabs resolved. Marks every touched body.
//! - [`switch_precision`]: touched bodies rise to their precise method (same step, before
//!   the contact is resolved).
//! - [`step_solvers`]: cautery power into the heat fields, heat steps, every body's level
//!   steps: its free motion (a resting precise body may drop back to its cage there).
//! - [`solve_contacts`]: the contact problem of all touching bodies, tools and obstacles
//!   on the moved positions, and each body's correction (see [`crate::contact`]); grips
//!   hold, forces on the tools.
//! - [`writeback`]: surface positions in `f32` for rendering, diagnostics.
//!
//! Everything runs on one thread in index order, so a run is bit-for-bit repeatable.

mod body;
pub mod burn;
mod cut;
mod cut_force;
mod cut_job;
mod scene;
mod script;
mod soft_world;
mod teleport;

pub use body::{SETTLE_STEPS, WorldBody};
pub use burn::CARVE_GROWTH;
pub use cut::{BladeCut, BladeOutcome, CutRecord, Incision, remap_grips, swept_triangles};
pub use cut_force::{CutLoad, cutting_resistance, load_cutting};
pub use cut_job::{CutJob, CutPlace};
pub use soft_world::SoftTissueWorld;

pub use crate::contact::{ContactState, ContactStats, detect_contacts, solve_contacts};
pub use crate::timing::StageTimes;
pub use scene::{
    SceneBody, SceneOptions, body_settings, check_mesh_path, load_mesh, load_mesh_with,
    obstacle_shape, placed_mesh, placement_pose, scene_bodies, scene_bodies_with, scene_obstacles,
};
pub use script::{Script, ScriptAction, ScriptError, ScriptEvent, Waypoint};

use std::borrow::{Borrow, BorrowMut};
use std::sync::Arc;
use std::time::Instant;

use rayon::prelude::*;

use crate::Vec3;
use crate::contact::{ContactConfig, ContactError, Friction, Obstacle, SurfaceCollider, Tool};
use crate::heat::{HeatBoundary, HeatError, HeatField, HeatParams};
use crate::linalg::CgStats;
use crate::mesh::TetMesh;
use crate::precision::{
    BodySettings, Level, LevelSnapshot, LeveledModel, PrecisionError, ShadowError, SwitchRecord,
};
use crate::scenario::SceneError;

/// A failure of the world, naming the body or tool.
#[derive(Debug, thiserror::Error)]
pub enum WorldError {
    /// A body's levels failed.
    #[error("body `{body}`: {source}")]
    Precision {
        /// The body.
        body: BodyName,
        /// Underlying error.
        source: PrecisionError,
    },
    /// A body's heat field failed.
    #[error("body `{body}`: {source}")]
    Heat {
        /// The body.
        body: BodyName,
        /// Underlying error.
        source: HeatError,
    },
    /// A body's surface or a tool is unusable for contact.
    #[error("`{name}`: {source}")]
    Contact {
        /// The body, or a tool or obstacle (by name, without an id).
        name: BodyName,
        /// Underlying error.
        source: ContactError,
    },
    /// A scene could not be loaded.
    #[error(transparent)]
    Scene(#[from] SceneError),
    /// A mesh could not be read or placed.
    #[error("body `{body}`: mesh: {message}")]
    Mesh {
        /// The body.
        body: BodyName,
        /// What failed.
        message: String,
    },
    /// A cut of a body was refused (the body is left as it was).
    #[error("body `{body}`: cut: {reason}")]
    Cut {
        /// The body.
        body: BodyName,
        /// Why.
        reason: String,
    },
    /// A time step is not usable.
    #[error("time step: {0}")]
    TimeStep(String),
    /// The world's thread pool could not be started.
    #[error(transparent)]
    Threads(#[from] crate::parallel::ThreadsError),
    /// Two bodies share a name.
    #[error("a body named `{0}` already exists")]
    DuplicateName(String),
    /// No body or tool by that name or index.
    #[error("no {kind} `{name}`")]
    Unknown {
        /// "body" or "tool".
        kind: &'static str,
        /// Name or index asked for.
        name: String,
    },
    /// An earlier step failed (its error is the text); the world steps again after
    /// [`SoftTissueWorld::resume`] or [`SoftTissueWorld::reset`].
    #[error("stopped after a failed step ({0}); resume() or reset() the world to step again")]
    Halted(String),
    /// A stage met or would have left a non-finite value (the stage left the state as it was).
    #[error("body `{body}`: non-finite position at node {node} after {stage}")]
    NonFinite {
        /// The body.
        body: BodyName,
        /// Node.
        node: usize,
        /// Stage.
        stage: &'static str,
    },
}

/// The body an error is about: its name (what the message shows), and the process-unique
/// id of the built body that raised it ([`WorldBody::id`]; none for a body still being built,
/// or a tool or obstacle).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BodyName {
    /// Name.
    pub name: String,
    /// [`WorldBody::id`] of the body, if built.
    pub id: Option<u64>,
}

impl std::fmt::Display for BodyName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.name)
    }
}

impl From<String> for BodyName {
    fn from(name: String) -> Self {
        BodyName { name, id: None }
    }
}

impl From<&str> for BodyName {
    fn from(name: &str) -> Self {
        BodyName {
            name: name.to_string(),
            id: None,
        }
    }
}

impl PartialEq<str> for BodyName {
    fn eq(&self, other: &str) -> bool {
        self.name == other
    }
}

impl PartialEq<&str> for BodyName {
    fn eq(&self, other: &&str) -> bool {
        self.name == *other
    }
}

/// World settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldConfig {
    /// Fixed step, s. Every body's solver step must equal it.
    pub dt: f64,
    /// Contact settings.
    pub contact: ContactConfig,
}

/// What a body reports after a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyDiagnostics {
    /// Level after the step.
    pub level: Level,
    /// The body's precise method (running when `level` is [`Level::Precise`]).
    pub method: crate::precision::PreciseMethod,
    /// Wall time of this body's solver step (level and heat, a down-switch included),
    /// microseconds.
    pub step_us: f64,
    /// Wall time of this body's up-switch in the switch stage, microseconds (0 without one).
    pub switch_us: f64,
    /// The iterative solve of this step's precise step (corotational FEM, implicit MSD):
    /// iterations, final relative residual and whether it met its tolerance within its
    /// iteration cap. `None` at the cage level and for direct or explicit methods.
    pub cg: Option<CgStats>,
    /// Precise steps since the body was built (or reset) whose iterative solve stopped at its
    /// iteration cap above its tolerance (each went on with its last iterate; see
    /// [`LeveledModel::set_precise_cg_must_converge`] to make that an error).
    pub unconverged_solves: u64,
    /// Contacts of this step's contact solve with a force on this body (points against
    /// tools, obstacles and other bodies, grips).
    pub contacts: u32,
    /// Deepest penetration of this body's contacts after the step's contact solve (below
    /// the thickness against bodies and obstacles, into a tool), scene units.
    pub max_penetration: f64,
    /// Whether the body counted as touched this step.
    pub touched: bool,
    /// Switches so far.
    pub switch_count: u64,
    /// The switch made during this step, if any.
    pub switched: Option<SwitchRecord>,
    /// The last switch ever made.
    pub last_switch: Option<SwitchRecord>,
    /// Largest surface displacement from the initial (settled) shape, scene units.
    pub max_displacement: f64,
    /// Largest temperature, C, at a node or an electrode's spot (`None` without a heat
    /// field).
    pub max_temperature: Option<f64>,
    /// Wall time of this body's heat in the step (coarse field and electrode spots), us
    /// (part of `step_us`; beside the mechanics on another thread in a pool).
    pub heat_us: f64,
    /// Distance of the cage level from its shadow precise simulation after this step
    /// (`None` unless [`WorldBody::set_shadow`] turned it on and the body is at its cage).
    pub shadow: Option<ShadowError>,
}

impl WorldError {
    /// The body (or tool) the error names, if it names one.
    pub fn subject(&self) -> Option<&str> {
        self.named().map(|b| b.name.as_str())
    }

    /// The process-unique id of the body the error is about ([`WorldBody::id`]), when a built
    /// body raised it: unlike the name, it tells apart bodies of the same name (two copies
    /// of one scene in a plugin app).
    pub fn body_id(&self) -> Option<u64> {
        self.named().and_then(|b| b.id)
    }

    fn named(&self) -> Option<&BodyName> {
        match self {
            WorldError::Precision { body, .. }
            | WorldError::Heat { body, .. }
            | WorldError::Mesh { body, .. }
            | WorldError::Cut { body, .. }
            | WorldError::NonFinite { body, .. } => Some(body),
            WorldError::Contact { name, .. } => Some(name),
            _ => None,
        }
    }
}

impl BodyDiagnostics {
    /// What runs now: `cage`, `fem` or `msd`.
    pub fn running(&self) -> &'static str {
        match (self.level, self.method.is_fem()) {
            (Level::Cage, _) => "cage",
            (Level::Precise, true) => "fem",
            (Level::Precise, false) => "msd",
        }
    }
}

/// Prepare: tool velocities over `dt`, surfaces gathered from the bodies.
pub fn prepare<B: BorrowMut<WorldBody>, T: BorrowMut<Tool>>(
    bodies: &mut [B],
    tools: &mut [T],
    dt: f64,
) {
    for t in tools.iter_mut() {
        t.borrow_mut().begin_step(dt);
    }
    for b in bodies.iter_mut() {
        let b = b.borrow_mut();
        // A sleeping body has not moved since it was last gathered.
        if !(b.model.is_asleep() && b.written_asleep) {
            b.collider.gather(b.model.node_positions());
            b.start.copy_from_slice(b.collider.positions());
        }
        b.touched = false;
        b.contacts = 0;
        b.active = false;
        b.moved = 0.0;
    }
}

/// Raise every touched body to its precise method (before the contact is resolved).
pub fn switch_precision<B: BorrowMut<WorldBody>>(bodies: &mut [B]) -> Result<(), WorldError> {
    for b in bodies.iter_mut() {
        let b = b.borrow_mut();
        b.diagnostics.switched = None;
        b.diagnostics.switch_us = 0.0;
        if b.touched && b.model.level() == Level::Cage {
            let start = Instant::now();
            match b.model.raise() {
                Ok(Some(r)) => b.diagnostics.switched = Some(r),
                Ok(None) => {}
                Err(e) => return Err(b.precision_err(e)),
            }
            b.diagnostics.switch_us = start.elapsed().as_secs_f64() * 1e6;
        }
    }
    Ok(())
}

/// Cautery power into the heat fields, then every body's heat and level step.
pub fn step_solvers<B: BorrowMut<WorldBody> + Send, T: Borrow<Tool>>(
    bodies: &mut [B],
    tools: &[T],
    state: &ContactState,
) -> Result<(), WorldError> {
    // Cautery: each tool's power is shared over the points it pressed in the last step's
    // contact solve (those with a normal force), each point's share by its weights.
    for (it, tool) in tools.iter().enumerate() {
        let tool = tool.borrow();
        let watts = tool.cautery_watts();
        if watts <= 0.0 {
            continue;
        }
        let pressing = |r: &&crate::contact::ContactRow| {
            matches!(r.other, crate::contact::Counterpart::Tool { tool, .. } if tool == it as u32)
                && r.is_contact()
                && r.force.x > 0.0
        };
        let total = state.solved_rows().iter().filter(pressing).count();
        if total == 0 {
            continue;
        }
        if let Some(radius) = tool.electrode_radius() {
            electrode_power(bodies, state, it as u32, &pressing, watts, radius)?;
            continue;
        }
        // Rows on a body a cut or a carve replaced this step name the old body's nodes:
        // nodal heating skips that body for the step.
        let share = watts / total as f64;
        for (i, b) in bodies.iter_mut().enumerate() {
            let b = b.borrow_mut();
            let Some(h) = b.heat.as_mut() else { continue };
            for r in state
                .fitting_rows(i as u32, b.collider.id())
                .filter(pressing)
            {
                for (v, w) in r.a.terms() {
                    let node = b.collider.nodes()[v as usize] as usize;
                    h.add_power(node, share * w)
                        .map_err(|source| WorldError::Heat {
                            body: BodyName {
                                name: b.name.clone(),
                                id: Some(b.collider.id()),
                            },
                            source,
                        })?;
                }
            }
        }
    }
    if crate::parallel::in_pool() && bodies.len() > 1 {
        // Each body's step is the same sequential computation on whichever thread runs it,
        // so the result does not depend on the thread count. One task per body: a thread
        // busy with a large body leaves the small ones to the others.
        bodies.par_iter_mut().with_max_len(1).for_each(|b| {
            let b = b.borrow_mut();
            b.step_error = b.step_solver().err();
        });
        for b in bodies.iter_mut() {
            if let Some(e) = b.borrow_mut().step_error.take() {
                return Err(e);
            }
        }
    } else {
        for b in bodies.iter_mut() {
            b.borrow_mut().step_solver()?;
        }
    }
    Ok(())
}

/// An electrode's power into the bodies it presses, each body's share by its part of the
/// normal force, at the force-weighted centre of its pressed points on the rest mesh (see
/// [`HeatField::add_electrode`]; a new spot's tissue fraction is the share of the rest mesh
/// around that centre, [`burn::tissue_fraction_in`]). On a body replaced this step (its rows
/// name the old mesh's nodes) the power goes to the spot this electrode, tool `tool`,
/// powered last (carried through a carve), if any.
fn electrode_power<B: BorrowMut<WorldBody>>(
    bodies: &mut [B],
    state: &ContactState,
    tool: u32,
    pressing: &dyn Fn(&&crate::contact::ContactRow) -> bool,
    watts: f64,
    radius: f64,
) -> Result<(), WorldError> {
    let force: f64 = state
        .solved_rows()
        .iter()
        .filter(pressing)
        .map(|r| r.force.x)
        .sum();
    for (i, b) in bodies.iter_mut().enumerate() {
        let body = i as u32;
        let part: f64 = state
            .solved_rows()
            .iter()
            .filter(|r| r.a.body == body && pressing(r))
            .map(|r| r.force.x)
            .sum();
        if part <= 0.0 {
            continue;
        }
        let b = b.borrow_mut();
        // Where the craters grow: the balls tried that no crater matches any more go.
        b.prune_vaporize_tried();
        let Some(h) = b.heat.as_mut() else { continue };
        let rest = b.mesh.positions();
        let mut center = Vec3::zeros();
        let nodes = &mut b.electrode_nodes;
        nodes.clear();
        let mut fitted = 0.0;
        for q in state.fitting_rows(body, b.collider.id()).filter(pressing) {
            let f = q.force.x;
            fitted += f;
            for (v, w) in q.a.terms() {
                let node = b.collider.nodes()[v as usize] as usize;
                center += rest[node] * (f * w);
                nodes.push((node, f * w));
            }
        }
        let (center, tissue_fraction) = if fitted > 0.0 {
            center /= fitted;
            for n in nodes.iter_mut() {
                n.1 /= fitted;
            }
            let fraction = match h.spot_fraction_at(&center, radius) {
                Some(f) => f,
                None => burn::tissue_fraction_in(
                    &mut b.occupancy,
                    &b.mesh,
                    &center,
                    radius / h.params().meters_per_unit,
                ),
            };
            (center, fraction)
        } else {
            let Some(spot) = h.powered_spot(tool, radius) else {
                log::debug!(
                    "body `{}`: its mesh changed this step and the electrode had powered no spot on it: it skips the body for the step",
                    b.name
                );
                continue;
            };
            nodes.clear();
            nodes.extend_from_slice(&spot.nodes);
            (spot.center, spot.tissue_fraction)
        };
        let source = crate::heat::ElectrodeSource {
            center,
            watts: watts * part / force,
            radius,
            tissue_fraction,
        };
        h.add_electrode_of(tool, &source, nodes)
            .map_err(|source| WorldError::Heat {
                body: BodyName {
                    name: b.name.clone(),
                    id: Some(b.collider.id()),
                },
                source,
            })?;
    }
    Ok(())
}

impl WorldBody {
    /// This body's heat and level step, timed into its diagnostics.
    fn step_solver(&mut self) -> Result<(), WorldError> {
        let start = Instant::now();
        // The last step's contact forces load this free step (its own solve answers them
        // exactly; the contact stage then corrects only their change).
        for k in 0..self.contact_load.len() {
            let (v, f) = self.contact_load[k];
            let node = self.collider.nodes()[v as usize] as usize;
            self.model
                .add_contact_load(node, f)
                .map_err(|e| self.precision_err(e))?;
        }
        self.contact_load.clear();
        // Contacts with a force in the last step hold the body (it may rest pressed).
        self.model.set_held(self.solve_contacts > 0);
        // The heat field and the mechanics do not read each other within a step: in a pool
        // they run side by side.
        // The heat field's new temperatures are taken only when the mechanics stepped too,
        // so a body whose mechanics fail is left as it was.
        let timed = |h: &mut HeatField| {
            let start = Instant::now();
            let r = h.solve_next();
            (r, start.elapsed())
        };
        let ((heat, heat_time), mechanics) = match self.heat.as_mut() {
            Some(h) if crate::parallel::in_pool() => {
                rayon::join(|| timed(h), || self.model.step(self.touched))
            }
            Some(h) => {
                let heat = timed(h);
                (heat, self.model.step(self.touched))
            }
            None => (
                (Ok(()), std::time::Duration::ZERO),
                self.model.step(self.touched),
            ),
        };
        heat.map_err(|source| WorldError::Heat {
            body: self.label(),
            source,
        })?;
        let stats = mechanics.map_err(|e| self.precision_err(e))?;
        let mut heat_time = heat_time;
        if let Some(h) = self.heat.as_mut() {
            let start = Instant::now();
            h.commit();
            heat_time += start.elapsed();
        }
        self.diagnostics.heat_us = heat_time.as_secs_f64() * 1e6;
        if let Some(r) = stats.switched {
            self.diagnostics.switched = Some(r);
        }
        self.diagnostics.cg = if stats.level == Level::Precise {
            self.model.precise_cg()
        } else {
            None
        };
        if self.diagnostics.cg.is_some_and(|c| !c.converged) {
            self.diagnostics.unconverged_solves += 1;
        }
        self.diagnostics.step_us = start.elapsed().as_secs_f64() * 1e6;
        Ok(())
    }
}

/// Writes the surfaces and diagnostics of every body. A body whose surface is not finite
/// keeps its last written surface; the first such body is the error (every body is
/// written either way).
pub fn writeback<B: BorrowMut<WorldBody>>(bodies: &mut [B]) -> Result<(), WorldError> {
    let mut result = Ok(());
    for b in bodies.iter_mut() {
        let r = b.borrow_mut().writeback();
        if result.is_ok() {
            result = r;
        }
    }
    result
}

impl WorldBody {
    /// The writeback of this body alone (the stage does it for every body; the bodies are
    /// independent, in any order).
    pub fn writeback(&mut self) -> Result<(), WorldError> {
        self.diagnostics.contacts = self.solve_contacts;
        self.diagnostics.max_penetration = self.penetration;
        self.diagnostics.touched = self.touched;
        self.write_surface()
    }
}
