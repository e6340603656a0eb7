//! A rigid move of a whole leveled model (a teleport): every level's state and every rest it
//! springs back to move together, so the body keeps its shape, its motion, its level and
//! its switch history, and nothing springs back to where it was.
//!
//! What moves: positions (of the precise nodes, the cage vertices, the embedded points) by
//! the move; velocities, pending forces, BDF2 histories, warm starts and the cage's detail
//! turned by its rotation; the rests (the precise solvers' rest shape and their anchors'
//! targets, the cage's rest shape and equilibrium, the cage MSD's rest and anchors) moved
//! with them.
//!
//! Whether an operator must change depends on the method, so every operator that depends
//! on the orientation is turned with the body, in place:
//!
//! - A translation changes none: every elastic operator (linear and corotated stiffness,
//!   springs, the prefactored matrix, the cage's reduced matrices) acts on differences of
//!   positions. The state and the rests move; nothing is factored.
//! - Linear FEM's stiffness `K` is assembled in world axes: with the positions and the rest
//!   turned by `R` and `K` kept, the force `-K (x' - X')` is not `R f` but a ghost force that
//!   strains the body by its own turn. `K`, the rest system and the corotational model's
//!   warped stiffness turn block by block (`R B R^T`, exactly the operators of the turned
//!   rest shape) and the rest system is factored again (numerically, its pattern kept):
//!   the linear model solves with that factor, the corotational model preconditions with
//!   it. Its element rotations and body frame, relative to the rest, turn on both sides.
//! - The prefactored corotational model's matrix `c M + Ka + (2 mu + 3 lambda) L` is the
//!   same on the three axes: a turn leaves it as it is (nodes held along some axes only
//!   would break that, and a turn of them is refused: held axes are world axes); its
//!   element loop reads the turned shape-function gradients.
//! - An MSD's springs and volumes keep their rest lengths; the implicit integrator's
//!   preconditioner, a factor of the system at rest, is factored again.
//! - The cage: Green coordinates do not change under a rigid motion of cage and points
//!   (only the rest cage and points move); the calibrated reduced matrices turn block by
//!   block, their small dense system factored again; the cage MSD's springs keep their
//!   lengths.
//!
//! So the moved body steps on exactly as the body left in place would, seen through the
//! move (`tests/teleport.rs`: to rounding for direct solves, to the solver's tolerance for
//! iterative ones). Gravity stays in world axes: a body turned on its supports sags the new
//! way at its precise level (at the cage level it keeps the shape it had, turned).

use nalgebra::Isometry3;

use super::*;

/// `p` moved by `m`.
fn at(m: &Isometry3<f64>, p: &Vec3) -> Vec3 {
    m * nalgebra::Point3::from(*p) - nalgebra::Point3::origin()
}

impl LeveledModel {
    /// Moves the body rigidly by `m` (rotation about the origin, then translation): a
    /// teleport. Every level's state moves with it (positions moved; velocities and pending
    /// forces turned) and so does every rest shape it returns to (the precise rest and
    /// anchors' targets, the cage's rest, equilibrium and calibrated dynamics), so the body
    /// keeps its shape (deformation included), motion and level, and steps on as it would
    /// have, turned (see the module docs). A turn factors the precise rest system again; a
    /// translation factors nothing.
    ///
    /// Refused, leaving the model as it was, when `m` is not finite, when a turn would move
    /// nodes held along some of their axes only (held axes are world axes), or when a
    /// turned system does not factor.
    pub fn teleport(&mut self, m: &Isometry3<f64>) -> Result<(), PrecisionError> {
        self.move_by(m, true)
    }

    /// Moves the rests (and the cage, at rest with them) of a model whose precise state
    /// already is where `m` puts its rests: a piece of a cut of a moved body, built in the
    /// coordinates the body was built in.
    pub(crate) fn move_rests(&mut self, m: &Isometry3<f64>) -> Result<(), PrecisionError> {
        self.move_by(m, false)
    }

    fn move_by(&mut self, m: &Isometry3<f64>, state: bool) -> Result<(), PrecisionError> {
        let finite = m
            .translation
            .vector
            .iter()
            .chain(m.rotation.coords.iter())
            .all(|c| c.is_finite());
        if !finite {
            return Err(PrecisionError::Move("the move is not finite".into()));
        }
        let turned = m.rotation.angle() != 0.0;
        if turned
            && let Some(node) = self
                .precise
                .model()
                .fixed()
                .iter()
                .position(|f| f.iter().any(|&a| a) && !f.iter().all(|&a| a))
        {
            return Err(PrecisionError::Move(format!(
                "node {node} is held along some of its axes only, which a turn would change"
            )));
        }
        // Each part is left as it was when it fails; the parts moved before it are moved
        // back.
        move_precise(&mut self.precise, m, state)?;
        let back = m.inverse();
        if let Some(s) = self.shadow.as_deref_mut()
            && let Err(e) = move_precise(s, m, state)
        {
            let _ = move_precise(&mut self.precise, &back, state);
            return Err(e);
        }
        if let Err(e) = self.cage.move_by(m) {
            let _ = move_precise(&mut self.precise, &back, state);
            if let Some(s) = self.shadow.as_deref_mut() {
                let _ = move_precise(s, &back, state);
            }
            return Err(e.into());
        }
        for p in self
            .rest
            .iter_mut()
            .chain(&mut self.equilibrium)
            .chain(&mut self.fit_cage)
        {
            *p = at(m, p);
        }
        for v in &mut self.fit_velocity {
            *v = m.rotation * *v;
        }
        self.dent.forget();
        // The cage's rotation at the last down-switch, relative to its (now turned) rest.
        self.lowered_rotation = m.rotation * self.lowered_rotation * m.rotation.inverse();
        Ok(())
    }
}

/// Moves a precise solver rigidly by `m` in place (see [`FemBody`]'s and [`MsdBody`]'s
/// `move_by`): its rest, with `state` its state too.
fn move_precise(p: &mut Precise, m: &Isometry3<f64>, state: bool) -> Result<(), PrecisionError> {
    match p {
        Precise::Fem(b) => b.move_by(m, state)?,
        Precise::Msd(b) => b.move_by(m, state)?,
    }
    Ok(())
}
