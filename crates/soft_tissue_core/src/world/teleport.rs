//! Moving a body rigidly (a teleport) and the frame its mechanics sit in.
//!
//! A body's mesh ([`WorldBody::mesh`]) keeps the coordinates the body was built in: its heat
//! field (temperatures, the electrodes' spots, burn marks, samples), its cuts and the tissue
//! carved out of it are all in them, and none of that changes when the body moves. Its
//! mechanics (every level's state and rests, the contact surface, the surface written out)
//! are in world coordinates: where the mesh is once moved by the body's frame
//! ([`WorldBody::frame`], the identity until the body is moved). A teleport moves the
//! mechanics and composes the frame; what builds mechanics from the mesh (a change of
//! method or material, a shadow) builds them on the mesh moved by the frame
//! ([`WorldBody::rest_mesh`]).

use nalgebra::Isometry3;

use super::cut::BladeCut;
use super::*;
use crate::precision::PreciseMethod;

/// `p` moved by `m`.
fn at(m: &Isometry3<f64>, p: &Vec3) -> Vec3 {
    m * nalgebra::Point3::from(*p) - nalgebra::Point3::origin()
}

/// Whether `m` moves nothing.
fn is_identity(m: &Isometry3<f64>) -> bool {
    m.rotation.angle() == 0.0 && m.translation.vector == Vec3::zeros()
}

impl WorldBody {
    /// The rigid map from the coordinates of [`WorldBody::mesh`] (those the body was built
    /// in, where its heat field and cuts live) to where its mechanics are: the composition of
    /// its teleports, the identity for a body never moved.
    pub fn frame(&self) -> &Isometry3<f64> {
        &self.frame
    }

    /// The rest mesh where the body's mechanics are: [`WorldBody::mesh`] moved by
    /// [`WorldBody::frame`] (the same mesh for a body never moved).
    pub fn rest_mesh(&self) -> Result<Arc<TetMesh>, WorldError> {
        if is_identity(&self.frame) {
            return Ok(self.mesh.clone());
        }
        self.mesh_in(&self.frame)
    }

    fn mesh_in(&self, frame: &Isometry3<f64>) -> Result<Arc<TetMesh>, WorldError> {
        self.mesh
            .mapped(|p| at(frame, p))
            .map(Arc::new)
            .map_err(|e| WorldError::Mesh {
                body: self.label(),
                message: format!("moved: {e}"),
            })
    }

    /// Moves the body rigidly by `m` (rotation about the origin, then translation): a
    /// teleport. Its state moves with it at every level (positions moved, velocities and
    /// pending forces turned), and so does everything it would spring back to (rest shape,
    /// anchors, cage, contact surface), so it keeps its shape (deformation included), its
    /// motion and its level; its temperatures and damage, which live on the mesh, are not
    /// touched (see the module docs; [`LeveledModel::teleport`] says what a turn costs). The
    /// contact surface forgets its travel (a teleport is not a sweep through what lies
    /// between). Refused, leaving the body as it was, for a move that is not finite or a
    /// turn of nodes held along some of their axes only.
    pub fn teleport(&mut self, m: Isometry3<f64>) -> Result<(), WorldError> {
        if is_identity(&m) {
            return Ok(());
        }
        self.model.teleport(&m).map_err(|e| self.precision_err(e))?;
        self.frame = m * self.frame;
        for p in self.rest_surface.iter_mut().chain(&mut self.start) {
            *p = at(&m, p);
        }
        for (_, f) in &mut self.contact_load {
            *f = m.rotation * *f;
        }
        self.collider.reset_motion(self.model.node_positions());
        self.written_asleep = false;
        self.write_surface()?;
        // The next writeback writes the surface again (and says so) though the body sleeps.
        self.written_asleep = false;
        Ok(())
    }

    /// Changes the precise method at run time (see [`LeveledModel::set_precise_method`]: no
    /// jump), the new solver built on the body's rest mesh where its mechanics are.
    pub fn set_precise_method(&mut self, method: PreciseMethod) -> Result<(), WorldError> {
        if method == self.model.settings().precise {
            return Ok(());
        }
        let mesh = self.rest_mesh()?;
        self.model
            .set_precise_method(&mesh, method)
            .map_err(|e| self.precision_err(e))?;
        self.written_asleep = false;
        Ok(())
    }

    /// After a cut of this body landed ([`WorldBody::finish_cut`] gave `cut`): the kept body
    /// (this one) and the pieces were built in the mesh's coordinates with the state where
    /// the body was; they take the frame the body had (`cut.previous`), so their rests are
    /// where their state is. Nothing to do for a body never moved. Call it before anything
    /// steps the pieces.
    pub fn carry_frame(&mut self, cut: &mut BladeCut) -> Result<(), WorldError> {
        let frame = cut.previous.frame;
        self.adopt_frame(frame)?;
        for p in &mut cut.pieces {
            p.adopt_frame(frame)?;
        }
        Ok(())
    }

    /// Moves the rests of a body built in the mesh's coordinates, whose state is already in
    /// `frame`, to `frame`.
    pub(super) fn adopt_frame(&mut self, frame: Isometry3<f64>) -> Result<(), WorldError> {
        let m = frame * self.frame.inverse();
        if is_identity(&m) {
            return Ok(());
        }
        self.model
            .move_rests(&m)
            .map_err(|e| self.precision_err(e))?;
        self.frame = frame;
        for p in &mut self.rest_surface {
            *p = at(&m, p);
        }
        Ok(())
    }
}
