//! The shadow: a precise simulation run beside the cage level under the same loads, to
//! measure the cage level's error.

use super::*;

/// Distance between the cage level and its shadow precise simulation (see
/// [`LeveledModel::set_shadow`]), over the surface vertices, after the last step.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ShadowError {
    /// Steps the shadow has run beside the cage level since it was (re)started.
    pub steps: u64,
    /// Mean surface-vertex distance this step, scene units.
    pub mean: f64,
    /// Largest surface-vertex distance this step, scene units.
    pub max: f64,
    /// `max` as a fraction of the body's smallest bounding-box dimension.
    pub max_ratio: f64,
    /// Largest `max_ratio` seen since the shadow was enabled.
    pub worst_ratio: f64,
}

impl LeveledModel {
    /// Turns the shadow precise simulation on or off (`mesh` is the body's mesh). The shadow
    /// is a second solver of the body's precise method that, while the body is at the cage
    /// level, starts from the cage's state, takes the same external forces and steps beside
    /// it, so [`LeveledModel::shadow_error`] measures how far the cage level is from what the
    /// precise method would do under the same loads. At the precise level it waits, and it
    /// restarts from the precise state at each down-switch. Costs one precise step per step.
    pub fn set_shadow(&mut self, mesh: &TetMesh, on: bool) -> Result<(), PrecisionError> {
        if !on {
            self.shadow = None;
            self.shadow_error = None;
            return Ok(());
        }
        if self.shadow.is_none() {
            self.shadow = Some(Box::new(build_precise(mesh, &self.settings)?));
            self.restart_shadow()?;
        }
        Ok(())
    }

    /// Whether a shadow precise simulation runs (see [`LeveledModel::set_shadow`]).
    pub fn has_shadow(&self) -> bool {
        self.shadow.is_some()
    }

    /// Distance between the cage level and its shadow after the last step; `None` without a
    /// shadow or while the body is at the precise level.
    pub fn shadow_error(&self) -> Option<ShadowError> {
        self.shadow_error
    }

    /// The shadow's node positions (`None` without a shadow).
    pub fn shadow_positions(&self) -> Option<&[Vec3]> {
        self.shadow.as_ref().map(|s| s.model().positions())
    }

    /// Puts the shadow in the body's current state (from the cage or the precise solver).
    pub(super) fn restart_shadow(&mut self) -> Result<(), PrecisionError> {
        let Some(mut shadow) = self.shadow.take() else {
            return Ok(());
        };
        let worst = self.shadow_error.map_or(0.0, |e| e.worst_ratio);
        match self.level {
            Level::Cage => {
                self.cage_state()?;
                load_state(
                    &mut shadow,
                    &self.nodes_work,
                    &self.nodes_work2,
                    UnitQuaternion::identity(),
                );
            }
            Level::Precise => {
                let from = self.precise.model();
                let to = shadow.model_mut();
                to.positions_mut().copy_from_slice(from.positions());
                to.velocities_mut().copy_from_slice(from.velocities());
                match shadow.as_mut() {
                    Precise::Fem(b) => {
                        b.restart_history();
                        b.sync_rotations();
                    }
                    Precise::Msd(b) => b.restart_history(),
                }
            }
        }
        self.shadow = Some(shadow);
        self.shadow_error = Some(ShadowError {
            worst_ratio: worst,
            ..ShadowError::default()
        });
        Ok(())
    }

    /// Steps the shadow beside a cage step and measures the distance of the two surfaces.
    pub(super) fn step_shadow(&mut self) -> Result<(), PrecisionError> {
        let Some(shadow) = self.shadow.as_mut() else {
            return Ok(());
        };
        shadow.step()?;
        let a = self.cage.points();
        let b = shadow.model().positions();
        let (mut sum, mut max) = (0.0, 0.0_f64);
        for &i in &self.surface {
            let d = (a[i as usize] - b[i as usize]).norm();
            sum += d;
            max = max.max(d);
        }
        let e = self.shadow_error.get_or_insert_with(ShadowError::default);
        e.steps += 1;
        e.mean = sum / self.surface.len().max(1) as f64;
        e.max = max;
        e.max_ratio = max / self.smallest;
        e.worst_ratio = e.worst_ratio.max(e.max_ratio);
        Ok(())
    }

    /// Adds a force on node `node` of the shadow simulation only, for loads applied to the
    /// cage some other way (a contact displacing the cage directly). No effect without a
    /// shadow, at the precise level or for a node out of range.
    pub fn add_shadow_force(&mut self, node: usize, force: Vec3) {
        if self.level != Level::Cage || node >= self.rest.len() {
            return;
        }
        if let Some(s) = self.shadow.as_mut() {
            s.model_mut().add_force(node, force);
        }
    }
}
