//! An MSD body moved rigidly in place (a teleport; see
//! [`crate::precision::LeveledModel::teleport`]).

use nalgebra::Isometry3;

use super::*;

impl MsdBody {
    /// Moves the body rigidly by `m` in place: its rest shape and anchors' targets, with
    /// `state` its positions (velocities and pending forces turned), BDF2 history and warm
    /// start too. Springs and volumes keep their rest lengths; the implicit integrator's
    /// preconditioner (a factor of the system at rest) is factored again for a turn. On
    /// error (it does not factor) the body is left as it was.
    pub(crate) fn move_by(&mut self, m: &Isometry3<f64>, state: bool) -> Result<(), MsdError> {
        let q = m.rotation;
        let turned = q.angle() != 0.0;
        self.nodes.move_rest(m);
        if turned && let Err(e) = self.refactor_implicit() {
            self.nodes.move_rest(&m.inverse());
            let _ = self.refactor_implicit();
            return Err(e);
        }
        if state {
            self.nodes.move_state(m);
            if turned {
                self.bdf2.turn(&q);
                if let Some(imp) = self.implicit.as_mut() {
                    for d in &mut imp.dv {
                        *d = q * *d;
                    }
                }
            }
        }
        if turned {
            // Compliance columns are of the system before the turn.
            self.contact = Default::default();
        }
        Ok(())
    }
}
