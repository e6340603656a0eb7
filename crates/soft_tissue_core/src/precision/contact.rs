//! A leveled model's side of the contact problem: the compliance and the correction of
//! whichever level it is at (see [`crate::contact`] and [`crate::contact::problem`]).

use nalgebra::Matrix3;

use super::{Level, LeveledModel, Precise, PrecisionError};
use crate::Vec3;

impl LeveledModel {
    /// Writes the compliance blocks between mesh nodes `nodes` (row-major, `nodes.len()^2`
    /// blocks, world frame: block `(i, j)` is how far node `i` moves over the step per unit
    /// force held on node `j`) for the step just taken: the precise solver's (see
    /// [`crate::fem::FemBody::contact_compliance`], [`crate::msd::MsdBody::contact_compliance`])
    /// or, at the cage level, the cage's mapped by the coordinates
    /// ([`crate::cage::CageModel::contact_compliance`]).
    pub fn contact_compliance(
        &mut self,
        nodes: &[u32],
        out: &mut [Matrix3<f64>],
    ) -> Result<(), PrecisionError> {
        match self.level {
            Level::Precise => match &mut self.precise {
                Precise::Fem(b) => b.contact_compliance(nodes, out)?,
                Precise::Msd(b) => b.contact_compliance(nodes, out)?,
            },
            Level::Cage => self.cage.contact_compliance(nodes, out)?,
        }
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
                self.cage.apply_contact_forces(forces)?;
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
        match &mut self.precise {
            Precise::Fem(b) => b.contact_compliance(nodes, &mut out)?,
            Precise::Msd(b) => b.contact_compliance(nodes, &mut out)?,
        }
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
