//! Messages games can react to (read them with `MessageReader`). Each names the body's
//! entity; its `Name` says which organ it is (a body spawned without one is given its mesh's
//! file name, `liver.vtk`: see [`crate::assets::body_label`]).

use bevy::prelude::*;

use crate::components::Level;

/// A body changed level (written in the Writeback set of the step it switched).
#[derive(Message, Clone, Copy, Debug, PartialEq)]
pub struct LevelChanged {
    /// The body.
    pub entity: Entity,
    /// Level before.
    pub from: Level,
    /// Level after.
    pub to: Level,
    /// Largest surface-vertex jump of the switch, as a fraction of the body's smallest
    /// bounding-box dimension.
    pub jump_ratio: f64,
}

/// A body was touched (by a tool or another body) this step.
#[derive(Message, Clone, Copy, Debug, PartialEq)]
pub struct BodyTouched {
    /// The body.
    pub entity: Entity,
    /// Contacts found (tool triangles and vertex-triangle pairs).
    pub contacts: u32,
}
