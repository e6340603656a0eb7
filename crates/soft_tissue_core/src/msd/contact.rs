//! An MSD body's side of the contact problem: its compliance on the contact nodes and the
//! correction of its step by the contact forces found.
//!
//! The implicit integrators solve `A dv = h r` with `A = M + h gamma + h^2 (K + Ka)`
//! linearized at the step's start, so forces held over the step move the nodes by
//! `h^2 A^-1 f`: the compliance is taken from the kept columns of the rest system's factor
//! (the preconditioner), and the correction applies the same columns (for a node beyond the
//! pool, the step's own matrix is solved by conjugate gradients). As for FEM, the correction
//! is only the change of the contact forces over the step: the last step's forces load the
//! free step. The explicit integrators (RK4, symplectic Euler) answer a force on a node with
//! that node alone within one step: the compliance is `h^2 / m`, exact for symplectic Euler,
//! and the correction a position impulse `dx = h^2 f / m`, `dv = dx / h` (for RK4 this is a
//! projection, not its own force response).

use nalgebra::Matrix3;

use super::*;
use crate::linalg::ColumnCache;

/// Contact workspaces of an MSD body (sized when it first takes a contact).
#[derive(Debug, Default)]
pub(super) struct MsdContact {
    cache: ColumnCache,
    slots: Vec<u32>,
    rhs: Vec<Vec3>,
    dv: Vec<Vec3>,
    /// The request's nodes left without columns, and the response to unit forces on all of
    /// them per axis (see [`crate::linalg::compliance`]).
    deferred: Vec<u32>,
    lumped: [Vec<Vec3>; 3],
}

impl MsdBody {
    /// Compliance columns computed since the body was built, counted per node (none for
    /// RK4, whose compliance is the nodes' own).
    pub fn contact_columns_computed(&self) -> u64 {
        self.contact.cache.computed()
    }

    /// Writes the compliance blocks between `nodes` (row-major, `nodes.len()^2` blocks) for
    /// the step just taken (see the module docs).
    pub fn contact_compliance(
        &mut self,
        nodes: &[u32],
        out: &mut [Matrix3<f64>],
    ) -> Result<(), MsdError> {
        let m = nodes.len();
        let n = self.nodes.x.len();
        let h = self.config.system_dt();
        let Some(imp) = self.implicit.as_mut() else {
            let h = self.config.dt;
            for (i, &ki) in nodes.iter().enumerate() {
                for j in 0..m {
                    out[i * m + j] = if i == j {
                        let free = Matrix3::from_diagonal(&Vec3::from_fn(|a, _| {
                            if self.nodes.fixed[ki as usize][a] {
                                0.0
                            } else {
                                1.0
                            }
                        }));
                        free * (h * h / self.nodes.mass[ki as usize])
                    } else {
                        Matrix3::zeros()
                    };
                }
            }
            return Ok(());
        };
        let c = &mut self.contact;
        if c.rhs.len() != n {
            c.rhs = vec![Vec3::zeros(); n];
            c.dv = vec![Vec3::zeros(); n];
            c.lumped = std::array::from_fn(|_| vec![Vec3::zeros(); n]);
        }
        c.cache.prepare(
            n,
            h.to_bits() ^ self.config.damping.to_bits().rotate_left(7),
        );
        c.slots.clear();
        let mut failure = None;
        let capacity = c.cache.capacity();
        for &k in nodes {
            if c.slots.len() >= capacity {
                c.slots.push(u32::MAX);
                continue;
            }
            let MsdContact { cache, slots, .. } = c;
            let s = cache.slot(k as usize, slots, &mut |columns| {
                if let Err(e) = imp.system.solve_unit_nodes(&[k], columns)
                    && failure.is_none()
                {
                    failure = Some(e);
                }
            });
            slots.push(s);
        }
        crate::linalg::compliance::without_columns(nodes, &c.slots, &mut c.deferred);
        if failure.is_none() && !c.deferred.is_empty() {
            let [x, y, z] = &mut c.lumped;
            failure = imp.system.solve_unit_nodes(&c.deferred, [x, y, z]).err();
        }
        if let Some(e) = failure {
            c.cache.forget();
            return Err(e.into());
        }
        let mass = &self.nodes.mass;
        let alone = |k: u32| Matrix3::identity() * (h * h / mass[k as usize]);
        crate::linalg::compliance::assemble_blocks(
            &c.cache,
            &c.slots,
            nodes,
            &c.lumped,
            h * h,
            None,
            &alone,
            out,
        );
        Ok(())
    }

    /// Corrects the step just taken by contact forces `(node, force)` held over it (a node
    /// may repeat; see the module docs). Fixed components stay. A failed solve changes
    /// nothing; a non-finite result is applied (the caller checks the state, as the contact
    /// stage does).
    pub fn apply_contact_forces(&mut self, forces: &[(u32, Vec3)]) -> Result<(), MsdError> {
        self.contact_response(forces)?;
        let c = &mut self.contact;
        for i in 0..self.nodes.x.len() {
            self.nodes.v[i] += c.dv[i];
            // For BDF2's history the change is part of the step.
            self.nodes.x[i] += c.rhs[i];
        }
        if self.config.integrator == MsdIntegrator::ImplicitBdf2 {
            self.bdf2.absorb(&self.contact.rhs, &self.contact.dv);
        }
        Ok(())
    }

    /// The displacement of every node that contact forces `(node, force)` held over the
    /// step just taken make (see [`MsdBody::apply_contact_forces`], which applies the same),
    /// without changing the state: a cage-level body's dent (see
    /// [`crate::precision::LeveledModel::contact_compliance`]).
    pub fn contact_displacement(&mut self, forces: &[(u32, Vec3)]) -> Result<&[Vec3], MsdError> {
        self.contact_response(forces)?;
        Ok(&self.contact.rhs)
    }

    /// The response to contact forces: velocity changes into `contact.dv`, displacements
    /// into `contact.rhs`.
    fn contact_response(&mut self, forces: &[(u32, Vec3)]) -> Result<(), MsdError> {
        let n = self.nodes.x.len();
        let c = &mut self.contact;
        if c.rhs.len() != n {
            c.rhs = vec![Vec3::zeros(); n];
            c.dv = vec![Vec3::zeros(); n];
        }
        c.rhs.fill(Vec3::zeros());
        for &(k, f) in forces {
            c.rhs[k as usize] += f;
        }
        let h = match self.implicit.as_mut() {
            Some(imp) => {
                let h = self.config.system_dt();
                // The kept rest columns give the response (the compliance the contact problem
                // was solved with); without them the step's matrix is solved.
                c.dv.fill(Vec3::zeros());
                let from_columns = forces
                    .iter()
                    .all(|&(k, _)| c.cache.column(k as usize, 0).is_some());
                if from_columns {
                    for &(k, f) in forces {
                        // The three axes' columns in one pass over the nodes.
                        let f = f * h;
                        let column = |a| c.cache.column(k as usize, a).expect("checked");
                        let (c0, c1, c2) = (column(0), column(1), column(2));
                        for (((d, x), y), z) in c.dv.iter_mut().zip(c0).zip(c1).zip(c2) {
                            *d += x * f.x + y * f.y + z * f.z;
                        }
                    }
                }
                if !from_columns {
                    for r in c.rhs.iter_mut() {
                        *r *= h;
                    }
                    let stats = imp.system.solve_cg(
                        &c.rhs,
                        &mut c.dv,
                        self.config.cg_tolerance,
                        self.config.cg_max_iterations,
                    )?;
                    if self.config.cg_must_converge {
                        stats.require_converged(self.config.cg_tolerance)?;
                    }
                }
                h
            }
            None => {
                let h = self.config.dt;
                for i in 0..n {
                    c.dv[i] = c.rhs[i] * (h / self.nodes.mass[i]);
                }
                h
            }
        };
        for i in 0..n {
            for a in 0..3 {
                if self.nodes.fixed[i][a] {
                    c.dv[i][a] = 0.0;
                }
            }
        }
        for i in 0..n {
            c.rhs[i] = c.dv[i] * h;
        }
        Ok(())
    }
}
