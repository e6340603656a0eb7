//! A leveled model's side of the contact problem: the compliance and the correction of
//! whichever level it is at (see [`crate::contact`] and [`crate::contact::problem`]).
//!
//! At the cage level a body answers contact as its precise model would, and its cage carries
//! what the cage can show of that answer. A coarse cage cannot dent: under a tool its
//! surface only moves as its cage's shapes move it, so the cage alone is far stiffer at a
//! point than the tissue (a box cage is pushed away as a whole to keep a ball out, where the
//! tissue dents and moves a little). So the contact rows see the precise model's compliance
//! `W` (turned by the rotation from the precise model's state to the cage level's points),
//! the forces they find load the cage as any force does, and what the cage's motion misses
//! of the precise model's response to them (that response at every node less the cage's
//! motion there) is kept as a *dent* on the cage's points (see
//! [`crate::cage::CageModel::add_dent`]): the surface under and around the tool stands where
//! the precise model's step puts it, and the cage moves by the force the precise model
//! feels. The dent is the one-step response to the contact's whole force (under a held load
//! it does not relax further toward the static response, as the precise model does): each
//! correction adds to it, and it is kept while the contact's forces load the body's steps
//! (held over the next step, they hold the cage where it is and the dent with it); a step
//! with no contact load drops it. A body whose cage holds a resting shape is the exception
//! (see `dents`).

use nalgebra::Matrix3;

use super::{Level, LeveledModel, Precise, PrecisionError};
use crate::Vec3;

/// The cage level's contact dent bookkeeping (see the module docs).
#[derive(Debug)]
pub(super) struct ContactDent {
    /// The rotation the last compliance gathered at the cage level was turned by.
    turn: Matrix3<f64>,
    /// Whether contact loads the coming step (see [`LeveledModel::add_contact_load`]).
    loaded: bool,
    // Workspaces.
    before: Vec<Vec3>,
    change: Vec<Vec3>,
    turned: Vec<(u32, Vec3)>,
}

impl Default for ContactDent {
    fn default() -> Self {
        ContactDent {
            turn: Matrix3::identity(),
            loaded: false,
            before: Vec::new(),
            change: Vec::new(),
            turned: Vec::new(),
        }
    }
}

impl ContactDent {
    /// Forgets the kept rotation (the body moved: the next compliance finds it again).
    pub(super) fn forget(&mut self) {
        self.turn = Matrix3::identity();
    }
}

impl LeveledModel {
    /// Writes the compliance blocks between mesh nodes `nodes` (row-major, `nodes.len()^2`
    /// blocks, world frame: block `(i, j)` is how far node `i` moves over the step per unit
    /// force held on node `j`) for the step just taken: the precise solver's (see
    /// [`crate::fem::FemBody::contact_compliance`], [`crate::msd::MsdBody::contact_compliance`]),
    /// at the cage level too, turned by the rotation from the precise model's state to the
    /// cage level's points (see the module docs); at the cage level of a body whose cage
    /// holds a resting shape, the cage's own ([`crate::cage::CageModel::contact_compliance`]).
    pub fn contact_compliance(
        &mut self,
        nodes: &[u32],
        out: &mut [Matrix3<f64>],
    ) -> Result<(), PrecisionError> {
        match self.level {
            Level::Precise => precise_compliance(&mut self.precise, nodes, out)?,
            Level::Cage if !self.dents() => self.cage.contact_compliance(nodes, out)?,
            Level::Cage => {
                precise_compliance(&mut self.precise, nodes, out)?;
                let turn = crate::fem::rotation::best_rotation(
                    self.precise.model().positions(),
                    self.cage.points(),
                )
                .to_rotation_matrix()
                .into_inner();
                for o in out.iter_mut() {
                    *o = turn * *o * turn.transpose();
                }
                self.dent.turn = turn;
            }
        }
        Ok(())
    }

    /// Whether contact dents the body (see the module docs): at the cage level, when the
    /// cage's equilibrium is the body's rest shape. A body whose cage holds a resting shape
    /// (a free body on its supports, one pressed by its neighbours; see
    /// [`LeveledModel::set_held`]) has no gravity at its cage level and its resting dents
    /// are in that shape (its detail): the contact forces at its cage level are not the
    /// loads the precise model would dent under, and it meets contact with its cage's own
    /// compliance.
    fn dents(&self) -> bool {
        self.level == Level::Cage && !self.rebased && !self.falls()
    }

    /// A contact load on node `node` for the next step (the last step's contact force, see
    /// [`crate::contact`]): an external force (see [`LeveledModel::add_force`]); at the cage
    /// level it also keeps the dent (see the module docs).
    pub fn add_contact_load(&mut self, node: usize, force: Vec3) -> Result<(), PrecisionError> {
        self.add_force(node, force)?;
        self.dent.loaded = true;
        Ok(())
    }

    /// After a step: at the cage level, keeps the dent while contact loaded the step and
    /// drops it otherwise; at the precise level nothing is kept. Returns whether the cage's
    /// points must be evaluated again (the dent was dropped).
    pub(super) fn renew_dent(&mut self) -> bool {
        let loaded = std::mem::take(&mut self.dent.loaded);
        if self.cage.dent().is_some() && !(loaded && self.dents()) {
            self.cage.clear_dent();
            return self.level == Level::Cage;
        }
        false
    }

    /// The cage level's correction by contact forces with the dent: the cage moves by them,
    /// and the dent takes the precise model's response (turned as the compliance was) less
    /// the points' motion. A non-finite response is an error before anything moves.
    fn dent_by(&mut self, forces: &[(u32, Vec3)]) -> Result<(), PrecisionError> {
        let mut d = std::mem::take(&mut self.dent);
        let r = self.dent_with(forces, &mut d);
        self.dent = d;
        r
    }

    fn dent_with(
        &mut self,
        forces: &[(u32, Vec3)],
        d: &mut ContactDent,
    ) -> Result<(), PrecisionError> {
        let back = d.turn.transpose();
        d.turned.clear();
        d.turned.extend(forces.iter().map(|&(k, f)| (k, back * f)));
        let response = match &mut self.precise {
            Precise::Fem(b) => b.contact_displacement(&d.turned)?,
            Precise::Msd(b) => b.contact_displacement(&d.turned)?,
        };
        if let Some(node) = response
            .iter()
            .position(|u| !u.iter().all(|c| c.is_finite()))
        {
            return Err(crate::cage::CageError::NonFinite {
                what: "contact dent of point",
                index: node,
            }
            .into());
        }
        d.change.clear();
        d.change.extend(response.iter().map(|u| d.turn * u));
        d.before.clear();
        d.before.extend_from_slice(self.cage.points());
        self.cage.apply_contact_forces(forces)?;
        for ((c, b), p) in d.change.iter_mut().zip(&d.before).zip(self.cage.points()) {
            *c -= p - b;
        }
        self.cage.add_dent(&d.change)?;
        self.cage.update_points()?;
        Ok(())
    }

    /// Corrects the step just taken by contact forces `(node, force)` held over it (a node
    /// may repeat): the current level's exact response. At the cage level the forces also
    /// reach the shadow simulation (as loads of its next step) and wake the body. On error
    /// the level's state is unchanged.
    pub fn apply_contact_forces(&mut self, forces: &[(u32, Vec3)]) -> Result<(), PrecisionError> {
        let n = self.rest.len();
        if let Some(&(node, _)) = forces.iter().find(|(k, _)| *k as usize >= n) {
            return Err(PrecisionError::BadNode {
                node: node as usize,
                nodes: n,
            });
        }
        match self.level {
            Level::Precise => match &mut self.precise {
                Precise::Fem(b) => b.apply_contact_forces(forces)?,
                Precise::Msd(b) => b.apply_contact_forces(forces)?,
            },
            Level::Cage => {
                self.asleep = false;
                if self.dents() {
                    self.dent_by(forces)?;
                } else {
                    self.cage.apply_contact_forces(forces)?;
                }
                for &(k, f) in forces {
                    self.add_shadow_force(k as usize, f);
                }
            }
        }
        Ok(())
    }

    /// Computes and keeps the precise model's compliance columns of mesh nodes `nodes`
    /// (see [`crate::linalg::ColumnCache`]) whatever the level, so the contact of a later
    /// step finds them kept: a body built in the background for a cut or a carve warms the
    /// nodes a tool will press on when it lands, off the steps' threads. Also builds a
    /// prefactored model's factors. Only the first nodes the cache has room for are taken;
    /// returns how many nodes' columns were computed (none for RK4, whose compliance is the
    /// nodes' own, and none for an empty list).
    pub fn warm_contact_columns(&mut self, nodes: &[u32]) -> Result<usize, PrecisionError> {
        let n = self.rest.len();
        if let Some(&node) = nodes.iter().find(|&&k| k as usize >= n) {
            return Err(PrecisionError::BadNode {
                node: node as usize,
                nodes: n,
            });
        }
        let nodes = &nodes[..nodes.len().min(crate::linalg::ColumnCache::capacity_for(n))];
        if nodes.is_empty() {
            return Ok(0);
        }
        let before = self.contact_columns_computed();
        let mut out = vec![Matrix3::zeros(); nodes.len() * nodes.len()];
        precise_compliance(&mut self.precise, nodes, &mut out)?;
        Ok((self.contact_columns_computed() - before) as usize)
    }

    /// Compliance columns the precise model has computed since it was built or last turned
    /// (a turn drops them; three a node, counted per node): how often contact had to solve
    /// for them.
    pub fn contact_columns_computed(&self) -> u64 {
        match &self.precise {
            Precise::Fem(b) => b.contact_columns_computed(),
            Precise::Msd(b) => b.contact_columns_computed(),
        }
    }
}

/// The precise solver's compliance between `nodes` (see
/// [`LeveledModel::contact_compliance`]).
fn precise_compliance(
    precise: &mut Precise,
    nodes: &[u32],
    out: &mut [Matrix3<f64>],
) -> Result<(), PrecisionError> {
    match precise {
        Precise::Fem(b) => b.contact_compliance(nodes, out)?,
        Precise::Msd(b) => b.contact_compliance(nodes, out)?,
    }
    Ok(())
}
