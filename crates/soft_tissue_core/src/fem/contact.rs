//! A FEM body's side of the contact problem: its compliance on the contact nodes and the
//! correction of its step by the contact forces found.
//!
//! A step solves `A dv = h r` (backward Euler, or BDF2 with `h = 2 dt / 3`), so contact forces
//! `f` held over the step add `dv = h A^-1 f` and move the nodes by `h^2 A^-1 f`: the
//! compliance is `h^2 A^-1`. For the linear model `A` is the rest system, factorized once,
//! and the columns of its inverse are exact and kept ([`ColumnCache`]). The corotational
//! model's `A` is the rest system warped by the element rotations: its compliance is taken
//! as the kept rest columns turned by the nodes' rotations, `R_i C_ij R_j^T` (SOFA's warped
//! compliance, Saupin, Duriez and Cotin, ISBMS 2008), an approximation the contact rounds
//! correct. The prefactored model's step is `x += A^-1 (-grad Phi)` with its constant matrix
//! per axis, so its compliance is exactly that matrix's inverse, without `h^2` (its `A`
//! holds `M / h^2`).
//!
//! The correction applies the same compliance to the forces found (exact for the linear and
//! prefactored models, the warped columns for the corotational one), added to the positions
//! and velocities (and to BDF2's history, as part of the step). It corrects only the change
//! of the contact forces over the step: the contact stage hands the last step's forces to
//! the next free step as loads, which the step's own solve answers exactly, so the warped
//! compliance's error scales with how fast the contact changes and vanishes at rest (the
//! forces on a body at rest balance as its own solve balances them). Where a contact node has
//! no kept column (more contact nodes than the pool holds) the step's system is solved.

use nalgebra::{Matrix3, Quaternion, UnitQuaternion};

use super::*;
use crate::linalg::ColumnCache;

/// Contact workspaces of a FEM body (sized when it first takes a contact).
#[derive(Debug, Default, Clone)]
pub(super) struct FemContact {
    cache: ColumnCache,
    slots: Vec<u32>,
    /// The request's nodes left without columns, and the body's response to unit forces on
    /// all of them per axis (see [`crate::linalg::compliance`]).
    deferred: Vec<u32>,
    lumped: [Vec<Vec3>; 3],
    rotations: Vec<Matrix3<f64>>,
    rhs: Vec<Vec3>,
    dv: Vec<Vec3>,
    dx: Vec<Vec3>,
    axis: Vec<f64>,
    /// Elements around each node (compressed rows), for node rotations.
    adjacency_start: Vec<u32>,
    adjacency: Vec<u32>,
}

impl FemBody {
    /// Compliance columns computed since the body was built, counted per node.
    pub fn contact_columns_computed(&self) -> u64 {
        self.contact.cache.computed()
    }

    /// The key the kept columns belong to: the model and the step's system.
    fn compliance_key(&self) -> u64 {
        let c = &self.config;
        let mut k = c.system_dt().to_bits();
        k = k.rotate_left(13) ^ c.mass_damping.to_bits();
        k = k.rotate_left(13) ^ c.stiffness_damping.to_bits();
        k.rotate_left(13)
            ^ match c.model {
                FemModel::Linear | FemModel::Corotational => 1,
                FemModel::CorotationalPrefactored => 2,
            }
    }

    fn prepare_contact(&mut self) {
        let n = self.nodes.x.len();
        let key = self.compliance_key();
        let c = &mut self.contact;
        if c.rhs.len() != n {
            c.rhs = vec![Vec3::zeros(); n];
            c.dv = vec![Vec3::zeros(); n];
            c.dx = vec![Vec3::zeros(); n];
            c.axis = vec![0.0; n];
            c.lumped = std::array::from_fn(|_| vec![Vec3::zeros(); n]);
            let mut count = vec![0u32; n + 1];
            for t in &self.tets {
                for &i in t {
                    count[i as usize + 1] += 1;
                }
            }
            for i in 0..n {
                count[i + 1] += count[i];
            }
            let mut fill = count.clone();
            let mut adj = vec![0u32; count[n] as usize];
            for (e, t) in self.tets.iter().enumerate() {
                for &i in t {
                    adj[fill[i as usize] as usize] = e as u32;
                    fill[i as usize] += 1;
                }
            }
            c.adjacency_start = count;
            c.adjacency = adj;
        }
        c.cache.prepare(n, key);
    }

    /// Rotation of node `i`: the normalized mean of its elements' rotations (identity for the
    /// linear model and for a node in no element).
    fn node_rotation(&self, i: usize) -> Matrix3<f64> {
        if self.config.model != FemModel::Corotational {
            return Matrix3::identity();
        }
        Self::rotation_of_node(&self.contact, &self.quats, i)
    }

    /// The normalized mean of node `i`'s elements' rotations.
    fn rotation_of_node(c: &FemContact, quats: &[UnitQuaternion<f64>], i: usize) -> Matrix3<f64> {
        let range = c.adjacency_start[i] as usize..c.adjacency_start[i + 1] as usize;
        let mut sum = Quaternion::new(0.0, 0.0, 0.0, 0.0);
        let mut first: Option<Quaternion<f64>> = None;
        for &e in &c.adjacency[range] {
            let q = quats[e as usize].into_inner();
            let reference = *first.get_or_insert(q);
            sum += if q.dot(&reference) < 0.0 { -q } else { q };
        }
        if sum.norm() == 0.0 {
            return Matrix3::identity();
        }
        *UnitQuaternion::from_quaternion(sum)
            .to_rotation_matrix()
            .matrix()
    }

    /// Writes the compliance blocks between `nodes` (row-major, `nodes.len()^2` blocks) for
    /// the step just taken (see the module docs). Columns not kept are computed (three
    /// substitutions a node).
    pub fn contact_compliance(
        &mut self,
        nodes: &[u32],
        out: &mut [Matrix3<f64>],
    ) -> Result<(), FemError> {
        self.prepare_contact();
        let h = self.config.system_dt();
        let prefactored = self.config.model == FemModel::CorotationalPrefactored;
        if prefactored && self.prefactored.is_none() {
            self.prefactored = Some(prefactored::Prefactored::new(self)?);
        }
        let scale = if prefactored { 1.0 } else { h * h };
        let mut failure = None;
        {
            let FemBody {
                contact,
                system,
                prefactored: pre,
                nodes: state,
                ..
            } = self;
            contact.slots.clear();
            let capacity = contact.cache.capacity();
            for &k in nodes {
                if contact.slots.len() >= capacity {
                    contact.slots.push(u32::MAX);
                    continue;
                }
                let FemContact {
                    cache, slots, axis, ..
                } = contact;
                let s = cache.slot(k as usize, slots, &mut |columns| {
                    let r = if prefactored {
                        let p = pre.as_mut().expect("built above");
                        let mut r = Ok(());
                        for (a, column) in columns.into_iter().enumerate() {
                            axis.fill(0.0);
                            axis[k as usize] = if state.fixed[k as usize][a] { 0.0 } else { 1.0 };
                            let f = p.axis_factor[a];
                            r = r.and(p.factors[f].solve_in_place(axis));
                            for (c, v) in column.iter_mut().zip(axis.iter()) {
                                *c = Vec3::zeros();
                                c[a] = *v;
                            }
                        }
                        r.map_err(FemError::from)
                    } else {
                        system
                            .solve_unit_nodes(&[k], columns)
                            .map_err(FemError::from)
                    };
                    if let Err(e) = r
                        && failure.is_none()
                    {
                        failure = Some(e);
                    }
                });
                slots.push(s);
            }
        }
        if failure.is_none() {
            failure = self.lump_deferred(nodes).err();
        }
        if let Some(e) = failure {
            self.contact.cache.forget();
            return Err(e);
        }
        let mut rotations = std::mem::take(&mut self.contact.rotations);
        rotations.clear();
        rotations.extend(nodes.iter().map(|&k| self.node_rotation(k as usize)));
        let c = &self.contact;
        let mass = &self.nodes.mass;
        // A lumped block that is no compliance: the node alone, by its mass (more compliant
        // than the body: the contact rounds finish what this leaves).
        let alone = |k: u32| Matrix3::identity() * (h * h / mass[k as usize].max(1e-300));
        crate::linalg::compliance::assemble_blocks(
            &c.cache,
            &c.slots,
            nodes,
            &c.lumped,
            scale,
            Some(&rotations),
            &alone,
            out,
        );
        self.contact.rotations = rotations;
        Ok(())
    }

    /// The response to unit forces on all the request's nodes left without columns, per
    /// axis, into `contact.lumped` (nothing when every node has its columns).
    fn lump_deferred(&mut self, nodes: &[u32]) -> Result<(), FemError> {
        let FemBody {
            contact,
            system,
            prefactored: pre,
            nodes: state,
            config,
            ..
        } = self;
        crate::linalg::compliance::without_columns(nodes, &contact.slots, &mut contact.deferred);
        if contact.deferred.is_empty() {
            return Ok(());
        }
        let [x, y, z] = &mut contact.lumped;
        if config.model != FemModel::CorotationalPrefactored {
            return Ok(system.solve_unit_nodes(&contact.deferred, [x, y, z])?);
        }
        let p = pre.as_mut().expect("built before the columns");
        for (a, column) in contact.lumped.iter_mut().enumerate() {
            contact.axis.fill(0.0);
            for &k in &contact.deferred {
                if !state.fixed[k as usize][a] {
                    contact.axis[k as usize] += 1.0;
                }
            }
            p.factors[p.axis_factor[a]].solve_in_place(&mut contact.axis)?;
            for (c, v) in column.iter_mut().zip(contact.axis.iter()) {
                *c = Vec3::zeros();
                c[a] = *v;
            }
        }
        Ok(())
    }

    /// Corrects the step just taken by contact forces `(node, force)` held over it (a node
    /// may repeat): the step's own system solved with them, added to the positions and
    /// velocities (fixed components stay). A failed solve changes nothing; a non-finite
    /// result is applied (the caller checks the state, as the contact stage does).
    pub fn apply_contact_forces(&mut self, forces: &[(u32, Vec3)]) -> Result<(), FemError> {
        self.contact_response(forces)?;
        let n = self.nodes.x.len();
        // A non-finite result is left for the contact stage's check, which puts every body
        // back as it was.
        for i in 0..n {
            self.nodes.x[i] += self.contact.dx[i];
            self.nodes.v[i] += self.contact.dv[i];
        }
        if self.config.integrator == FemIntegrator::Bdf2 {
            self.bdf2.absorb(&self.contact.dx, &self.contact.dv);
        }
        Ok(())
    }

    /// The displacement of every node that contact forces `(node, force)` held over the
    /// step just taken make (see [`FemBody::apply_contact_forces`], which applies the same),
    /// without changing the state: a cage-level body's dent (see
    /// [`crate::precision::LeveledModel::contact_compliance`]).
    pub fn contact_displacement(&mut self, forces: &[(u32, Vec3)]) -> Result<&[Vec3], FemError> {
        self.contact_response(forces)?;
        Ok(&self.contact.dx)
    }

    /// The response to contact forces into `contact.dx` and `contact.dv`.
    fn contact_response(&mut self, forces: &[(u32, Vec3)]) -> Result<(), FemError> {
        self.prepare_contact();
        let n = self.nodes.x.len();
        let h = self.config.system_dt();
        let FemBody {
            contact,
            system,
            prefactored: pre,
            nodes,
            config,
            quats,
            ..
        } = self;
        contact.rhs.fill(Vec3::zeros());
        for &(k, f) in forces {
            contact.rhs[k as usize] += f;
        }
        // The kept columns give the response at once: exactly for the linear and prefactored
        // models (their matrices are the factored ones), warped by the nodes' rotations for
        // the corotational model (the compliance the problem was solved with, so the gaps it
        // closed are closed).
        let from_columns = forces
            .iter()
            .all(|&(k, _)| contact.cache.column(k as usize, 0).is_some());
        let scale = if config.model == FemModel::CorotationalPrefactored {
            1.0
        } else {
            h * h
        };
        if from_columns {
            contact.dx.fill(Vec3::zeros());
            let rotate = config.model == FemModel::Corotational;
            for &(k, f) in forces {
                let f = if rotate {
                    Self::rotation_of_node(contact, quats, k as usize).transpose() * f
                } else {
                    f
                };
                // The three axes' columns in one pass over the nodes.
                let f = f * scale;
                let column = |a| contact.cache.column(k as usize, a).expect("checked");
                let (c0, c1, c2) = (column(0), column(1), column(2));
                for (((d, x), y), z) in contact.dx.iter_mut().zip(c0).zip(c1).zip(c2) {
                    *d += x * f.x + y * f.y + z * f.z;
                }
            }
            if rotate {
                for i in 0..n {
                    contact.dx[i] = Self::rotation_of_node(contact, quats, i) * contact.dx[i];
                }
            }
        }
        match (config.model, from_columns) {
            (_, true) => {
                for i in 0..n {
                    contact.dv[i] = contact.dx[i] / h;
                }
            }
            (FemModel::Linear, false) => {
                for r in contact.rhs.iter_mut() {
                    *r *= h;
                }
                system.solve_direct(&contact.rhs, &mut contact.dv)?;
                for i in 0..n {
                    contact.dx[i] = contact.dv[i] * h;
                }
            }
            (FemModel::Corotational, false) => {
                for r in contact.rhs.iter_mut() {
                    *r *= h;
                }
                contact.dv.fill(Vec3::zeros());
                let stats = system.solve_cg(
                    &contact.rhs,
                    &mut contact.dv,
                    config.cg_tolerance,
                    config.cg_max_iterations,
                )?;
                if config.cg_must_converge {
                    stats.require_converged(config.cg_tolerance)?;
                }
                for i in 0..n {
                    contact.dx[i] = contact.dv[i] * h;
                }
            }
            (FemModel::CorotationalPrefactored, false) => {
                let Some(p) = pre.as_mut() else {
                    return Err(FemError::Linalg(crate::linalg::LinalgError::NotFactored));
                };
                for a in 0..3 {
                    for i in 0..n {
                        contact.axis[i] = if nodes.fixed[i][a] {
                            0.0
                        } else {
                            contact.rhs[i][a]
                        };
                    }
                    p.factors[p.axis_factor[a]].solve_in_place(&mut contact.axis)?;
                    for i in 0..n {
                        contact.dx[i][a] = contact.axis[i];
                    }
                }
                for i in 0..n {
                    contact.dv[i] = contact.dx[i] / h;
                }
            }
        }
        for i in 0..n {
            for a in 0..3 {
                if nodes.fixed[i][a] {
                    contact.dx[i][a] = 0.0;
                    contact.dv[i][a] = 0.0;
                }
            }
        }
        Ok(())
    }
}
