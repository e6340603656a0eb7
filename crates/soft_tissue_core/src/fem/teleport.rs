//! A FEM body moved rigidly in place (a teleport; see
//! [`crate::precision::LeveledModel::teleport`]).

use nalgebra::Isometry3;

use super::*;

impl FemBody {
    /// Moves the body rigidly by `m` in place: its rest shape and anchors' targets, with
    /// `state` its positions (velocities and pending forces turned) too, and every operator
    /// that depends on the orientation with them, so it steps on as it would have, turned:
    /// the shape-function gradients, the rest stiffness and, where the state turns too, the
    /// warped stiffness block by block (`R B R^T`), the element rotations and the body
    /// frame relative to the turned rest, the BDF2 history and the warm start; the rest
    /// system is factored again (numerically; its pattern is kept). The prefactored model's
    /// matrix does not depend on the orientation and is kept. Without `state` (a body whose
    /// state already is where `m` puts its rest) the system starts from the turned rest
    /// system, as a body built there does. On error (the turned rest system does not
    /// factor) the body is left as it was.
    pub(crate) fn move_by(&mut self, m: &Isometry3<f64>, state: bool) -> Result<(), FemError> {
        let q = m.rotation;
        if q.angle() != 0.0 {
            let r = *q.to_rotation_matrix().matrix();
            let mut k_rest = self.k_rest.clone();
            for b in k_rest.blocks_mut() {
                *b = r * *b * r.transpose();
            }
            let before = self.system.matrix.clone();
            // The factor is of the rest system.
            let (c, n) = (&self.config, &self.nodes);
            fill_rest_system(&mut self.system.matrix, &k_rest, &n.mass, &n.anchor_k, c);
            if let Err(e) = self.system.refactor() {
                fill_rest_system(
                    &mut self.system.matrix,
                    &self.k_rest,
                    &n.mass,
                    &n.anchor_k,
                    c,
                );
                let _ = self.system.refactor();
                self.system.matrix = before;
                return Err(e.into());
            }
            self.k_rest = k_rest;
            for g in self.grads.iter_mut().flatten() {
                *g = r * *g;
            }
            self.packed =
                packed::PackedElements::new(&self.tets, &self.grads, &self.volumes, n.x.len());
            // Element rotations and the body frame are of the state relative to the rest:
            // turned on both sides with the state, on the rest's side only without it.
            let pq = if state { q } else { UnitQuaternion::identity() };
            for (qe, re) in self.quats.iter_mut().zip(&mut self.rots) {
                *qe = pq * *qe * q.inverse();
                *re = *qe.to_rotation_matrix().matrix();
            }
            self.frame = pq * self.frame * q.inverse();
            if state {
                // The warped stiffness turns with the state it was assembled for.
                self.system.matrix = before;
                for b in self.system.matrix.blocks_mut() {
                    *b = r * *b * r.transpose();
                }
                for qa in &mut self.quats_assembled {
                    *qa = q * *qa * q.inverse();
                }
                for d in &mut self.dv {
                    *d = q * *d;
                }
                self.bdf2.turn(&q);
            } else {
                // The rest system, as a body built at the moved rest has.
                self.quats_assembled.fill(UnitQuaternion::identity());
                self.matrix_current = true;
            }
            self.static_system = None;
            // Compliance columns are of the system before the turn.
            self.contact = Default::default();
        }
        self.nodes.move_rest(m);
        if state {
            self.nodes.move_state(m);
        }
        Ok(())
    }
}
