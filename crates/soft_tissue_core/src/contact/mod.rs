//! Contact between bodies, tools and obstacles: detection, the contact problem of a step and
//! its solve, in one place.
//!
//! - **Surfaces** ([`surface`]). Each body has a [`SurfaceCollider`]: its boundary triangles,
//!   positions gathered from the body, the inside/outside test by pseudo-normals (Baerentzen
//!   and Aanaes 2005) made right at non-manifold edges and vertices too, normals computed only
//!   where a query lands, and a bounding-volume hierarchy of the triangles (parry3d's `Bvh`)
//!   whose leaf boxes are grown by a slack so that a move updates only the leaves of vertices
//!   that left them. parry works in `f32` on glam 0.33; the conversion is [`to_parry_aabb`],
//!   which rounds outward so no candidate is lost.
//! - **Rigid things** ([`rigid`], [`tool`]). Tools (a probe, a grasper's two jaws) and static
//!   [`Obstacle`]s (a table, a bone, a port) are rigid shapes at a pose: spheres, capsules,
//!   boxes, planes and closed triangle meshes, each with its [`Friction`].
//! - **Detection** ([`detect`]). Sweep and prune over body bounds, then vertex against
//!   triangle both ways for a body pair, on the [`PairCandidates`] kept while the two move
//!   less than a slack; every surface vertex near a rigid shape, and for round shapes every
//!   triangle near its core (a thin probe between vertices).
//! - **The contact problem** ([`problem`]). After each body's free motion (its own implicit
//!   step), the contacts of all touching bodies, tools and obstacles form one problem:
//!   Signorini (no penetration, no pull) and Coulomb (static and kinetic) conditions on the
//!   contact rows, coupled through each body's compliance on its contact vertices (the
//!   Delassus operator), solved by projected Gauss-Seidel, then each body corrects its step
//!   by the forces found (its own exact solve, [`crate::precision::LeveledModel::apply_contact_forces`]).
//!   The contact set is detected again on the corrected positions, and a new round solves
//!   what changed, until no contact penetrates beyond the tolerance. The force on a tool is
//!   the sum of its rows' forces.
//! - **Stages** (`contact/stages/`): [`detect_contacts`] at the start of a step (who is touched, to
//!   raise it before the contact is resolved; cautery) and [`solve_contacts`] after the free
//!   motion.

pub mod cases;
pub mod detect;
pub mod problem;
pub mod rigid;
mod stages;
pub mod surface;
pub mod tool;

pub use detect::{
    BodyContact, PairCandidates, ToolContact, broad_phase, detect_candidates, detect_pair,
    detect_tool, grab_vertices, pair_reach, tool_distance,
};
pub use problem::{BodyPoint, ContactRow, ContactSolver, Counterpart, RowKind, SolveStats};
pub use rigid::{Friction, FrictionCombine, MeshShape, Obstacle, Pose, RigidShape, pose_along};
pub use stages::{ContactState, ContactStats, detect_contacts, solve_contacts};
pub use surface::{SurfaceCollider, SurfaceHit};
pub use tool::{DEFAULT_ELECTRODE_RADIUS, Grip, JawShape, Tool, ToolShape};

use parry3d::bounding_volume::Aabb as ParryAabb;
use parry3d::math::Vector as ParryVector;
use serde::{Deserialize, Serialize};

use crate::Vec3;

/// Contact settings, in scene units.
///
/// Read from scene files with the solver fields optional (older files have only the first
/// four).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ContactConfig {
    /// Bodies are kept this far apart (a skin that absorbs round-off and the f32 rendering).
    pub thickness: f64,
    /// Deepest penetration the narrow phase looks for.
    pub search_radius: f64,
    /// A tool this close to a body counts as touching it (raises it early); 0 for contact only.
    pub tool_margin: f64,
    /// Bodies this close count as touching for the switch (before they overlap).
    pub body_margin: f64,
    /// Largest penetration (below the thickness, or into a rigid shape) a step may leave;
    /// deeper contacts start another round of the contact solve (see `max_rounds`).
    #[serde(default = "default_tolerance")]
    pub tolerance: f64,
    /// Most rounds of the contact solve in a step (detection on the corrected positions,
    /// solve, correction); at least 1.
    #[serde(default = "default_rounds")]
    pub max_rounds: u32,
    /// Most projected Gauss-Seidel sweeps of one solve.
    #[serde(default = "default_sweeps")]
    pub max_sweeps: u32,
}

fn default_tolerance() -> f64 {
    1e-4
}

fn default_rounds() -> u32 {
    5
}

fn default_sweeps() -> u32 {
    200
}

impl ContactConfig {
    /// Defaults for a scene whose bodies are about `scale` across: thickness 0.2 %, search
    /// radius 5 %, tool and body margins 0.5 %, tolerance 0.01 %, five rounds, 200 sweeps.
    pub fn for_scale(scale: f64) -> Self {
        ContactConfig {
            thickness: 0.002 * scale,
            search_radius: 0.05 * scale,
            tool_margin: 0.005 * scale,
            body_margin: 0.005 * scale,
            tolerance: 1e-4 * scale,
            max_rounds: default_rounds(),
            max_sweeps: default_sweeps(),
        }
    }

    /// Checks every field is finite and not negative, the search radius positive.
    pub fn validate(&self) -> Result<(), ContactError> {
        let fields = [
            ("thickness", self.thickness),
            ("search_radius", self.search_radius),
            ("tool_margin", self.tool_margin),
            ("body_margin", self.body_margin),
            ("tolerance", self.tolerance),
        ];
        for (field, value) in fields {
            if !(value.is_finite() && value >= 0.0) {
                return Err(ContactError::BadParameter { field, value });
            }
        }
        for (field, value) in [
            ("search_radius", self.search_radius),
            ("tolerance", self.tolerance),
        ] {
            if value <= 0.0 {
                return Err(ContactError::BadParameter { field, value });
            }
        }
        for (field, value) in [
            ("max_rounds", self.max_rounds),
            ("max_sweeps", self.max_sweeps),
        ] {
            if value == 0 {
                return Err(ContactError::BadParameter { field, value: 0.0 });
            }
        }
        Ok(())
    }
}

/// A failure of the contact code.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ContactError {
    /// A parameter is negative, zero where it must not be, or not finite.
    #[error("contact parameter `{field}` = {value} is out of range")]
    BadParameter {
        /// Field name.
        field: &'static str,
        /// Value given.
        value: f64,
    },
    /// A boundary triangle has no partner across one of its edges (a mesh that passed
    /// validation always has one; this names the triangle if it does not).
    #[error("surface triangle {triangle}: {reason}")]
    BadSurface {
        /// Triangle index (surface order).
        triangle: usize,
        /// What is wrong.
        reason: String,
    },
    /// A tool pose or setting is not finite or out of range.
    #[error("tool `{tool}`: {what} is invalid ({value})")]
    BadTool {
        /// Tool name.
        tool: String,
        /// What is wrong.
        what: &'static str,
        /// Offending value (a norm for vectors).
        value: f64,
    },
    /// A friction coefficient is out of range.
    #[error("`{owner}`: friction `{field}` = {value} {reason}")]
    BadFriction {
        /// The body, tool or obstacle.
        owner: String,
        /// Field name.
        field: &'static str,
        /// Value given.
        value: f64,
        /// What is wrong.
        reason: &'static str,
    },
    /// A rigid shape (an obstacle's) cannot be used.
    #[error("shape `{shape}`: {reason}")]
    BadShape {
        /// The shape or obstacle.
        shape: String,
        /// What is wrong.
        reason: String,
    },
}

/// Converts bounds to parry's `f32` boxes, rounding outward. The one place where parry's
/// glam 0.33 types meet the `f64` nalgebra types of the core.
pub fn to_parry_aabb(min: &Vec3, max: &Vec3) -> ParryAabb {
    let down = |x: f64| {
        let f = x as f32;
        if (f as f64) > x { f.next_down() } else { f }
    };
    let up = |x: f64| {
        let f = x as f32;
        if (f as f64) < x { f.next_up() } else { f }
    };
    ParryAabb::new(
        ParryVector::new(down(min.x), down(min.y), down(min.z)),
        ParryVector::new(up(max.x), up(max.y), up(max.z)),
    )
}

pub(crate) fn overlaps(a: &(Vec3, Vec3), b: &(Vec3, Vec3), grow: f64) -> bool {
    (0..3).all(|k| a.0[k] - grow <= b.1[k] && b.0[k] - grow <= a.1[k])
}
