//! What a cut needs of a leveled model: the state of every node whatever the level, and a
//! body made from a cut starting at its precise level in the state it was cut in.

use super::*;

impl LeveledModel {
    /// Every node's position and velocity now, whatever the level (at the cage level, the
    /// cage's exact map and its rate, as an up-switch would hand them over).
    pub fn node_state(&mut self) -> Result<(Vec<Vec3>, Vec<Vec3>), PrecisionError> {
        match self.level {
            Level::Precise => {
                let b = self.precise.model();
                Ok((b.positions().to_vec(), b.velocities().to_vec()))
            }
            Level::Cage => {
                self.cage_state()?;
                Ok((self.nodes_work.clone(), self.nodes_work2.clone()))
            }
        }
    }

    /// Starts the body at its precise level with nodes at `x` moving at `v` (a body made
    /// from a cut, in the state the body it came from was in). Components held fixed keep
    /// their position. The cage was built around the rest shape; under gravity the body
    /// rests in a shape of its own, which its cage then keeps as its equilibrium, as a free
    /// body's does (so the down-switch at rest does not let the cage spring back to the
    /// unloaded shape). A pin to the cage level is kept and applied at once.
    pub fn start_precise(&mut self, x: &[Vec3], v: &[Vec3]) -> Result<(), PrecisionError> {
        let n = self.rest.len();
        if x.len() != n || v.len() != n {
            return Err(PrecisionError::BadNode {
                node: x.len().min(v.len()),
                nodes: n,
            });
        }
        if let Some((what, node)) = crate::state::first_non_finite_state(x, v) {
            return Err(PrecisionError::NonFiniteSwitch {
                from: self.level,
                what,
                node,
            });
        }
        load_state(&mut self.precise, x, v, UnitQuaternion::identity());
        self.lowered_rotation = UnitQuaternion::identity();
        self.level = Level::Precise;
        self.rests_loaded = self.settings.gravity.norm() > 0.0;
        self.steps_at_level = 0;
        self.rest_count = 0;
        self.slow_steps = 0;
        self.asleep = false;
        if self.pin == Some(Level::Cage) {
            self.pin = None;
            self.lower()?;
            self.pin = Some(Level::Cage);
        }
        Ok(())
    }
}
