//! A cage body's side of the contact problem: the compliance of its embedded points through
//! the cage, and the correction of its step by contact forces.
//!
//! A force `f` on a point with coordinates `phi`, `psi` acts on the cage as `J^T f`, `J` the
//! linearised Green-coordinate map (the face terms' part included with calibrated dynamics,
//! [`crate::cage::ReducedModel::add_point_force`]; the vertex weights alone with the paper's
//! cage MSD, as [`CageModel::apply_point_force`] maps them). The cage answers forces held over
//! a step with `h^2 S^-1` (calibrated: `S = M + h C + h^2 K` in the step's frame, factorized
//! once) or `h^2 / m` per vertex (the paper's explicit cage MSD), so a point's compliance is
//! `J C_cage J^T`: exact for the linearised map, the points then evaluated by the exact
//! coordinates.

use nalgebra::{DVector, Matrix3};

use super::{CageError, CageModel};
use crate::Vec3;
use crate::state::NodalModel;

/// Contact workspaces of a cage body.
#[derive(Debug, Default, Clone)]
pub(super) struct CageContact {
    /// Per point, `3 d` numbers: `J^T` (turned into the step's frame) for the three axes.
    q: Vec<f64>,
    /// Per point, the same after the cage's compliance.
    y: Vec<f64>,
    column: Option<DVector<f64>>,
    forces: Vec<Vec3>,
}

impl CageModel {
    /// The generalised force of `f` on point `k` added to `out` (cage vertex forces).
    fn add_generalised(&self, k: usize, f: Vec3, out: &mut [Vec3]) {
        match self.reduced.as_ref() {
            Some(r) => {
                r.model()
                    .add_point_force(self.coords.phi(k), self.coords.psi(k), f, out);
            }
            None => {
                for (o, w) in out.iter_mut().zip(self.coords.phi(k)) {
                    *o += f * *w;
                }
            }
        }
    }

    /// Cage vertex masses and fixed components, for the paper's explicit cage.
    fn explicit_compliance(&self, i: usize, a: usize) -> f64 {
        let msd = &self.msd;
        if msd.fixed()[i][a] {
            0.0
        } else {
            let h = msd.config().dt;
            h * h / msd.masses()[i]
        }
    }

    /// Writes the compliance blocks between the embedded points `points` (row-major,
    /// `points.len()^2` blocks, world frame) for the current cage state.
    pub fn contact_compliance(
        &mut self,
        points: &[u32],
        out: &mut [Matrix3<f64>],
    ) -> Result<(), CageError> {
        let nv = self.cage.vertices().len();
        let d = 3 * nv;
        let m = points.len();
        let mut work = std::mem::take(&mut self.contact);
        work.forces.clear();
        work.forces.resize(nv, Vec3::zeros());
        work.q.clear();
        work.q.resize(3 * d * m, 0.0);
        work.y.clear();
        work.y.resize(3 * d * m, 0.0);
        let rot = match self.reduced.as_ref() {
            Some(r) => r.frame(self.msd.positions()),
            None => Matrix3::identity(),
        };
        let rt = rot.transpose();
        for (p, &k) in points.iter().enumerate() {
            for a in 0..3 {
                work.forces.fill(Vec3::zeros());
                let mut e = Vec3::zeros();
                e[a] = 1.0;
                self.add_generalised(k as usize, e, &mut work.forces);
                let q = &mut work.q[(3 * p + a) * d..(3 * p + a + 1) * d];
                for (i, f) in work.forces.iter().enumerate() {
                    let g = rt * f;
                    q[3 * i..3 * i + 3].copy_from_slice(g.as_slice());
                }
            }
        }
        match self.reduced.as_ref() {
            Some(r) => {
                let column = work.column.get_or_insert_with(|| DVector::zeros(d));
                if column.len() != d {
                    *column = DVector::zeros(d);
                }
                for c in 0..3 * m {
                    column
                        .as_mut_slice()
                        .copy_from_slice(&work.q[c * d..(c + 1) * d]);
                    r.compliance_solve(column);
                    work.y[c * d..(c + 1) * d].copy_from_slice(column.as_slice());
                }
            }
            None => {
                for c in 0..3 * m {
                    for i in 0..d {
                        work.y[c * d + i] =
                            work.q[c * d + i] * self.explicit_compliance(i / 3, i % 3);
                    }
                }
            }
        }
        // Block (i, j) = q_i^T y_j: the row's point and axis against the column's.
        for i in 0..m {
            for j in 0..m {
                let mut b = Matrix3::zeros();
                for a in 0..3 {
                    let qa = &work.q[(3 * i + a) * d..(3 * i + a + 1) * d];
                    for c in 0..3 {
                        let yc = &work.y[(3 * j + c) * d..(3 * j + c + 1) * d];
                        b[(a, c)] = qa.iter().zip(yc).map(|(x, y)| x * y).sum();
                    }
                }
                out[i * m + j] = b;
            }
        }
        self.contact = work;
        Ok(())
    }

    /// Corrects the last step by contact forces `(point, force)` held over it (a point may
    /// repeat): the cage moves by its compliance times their generalised forces, its
    /// velocities by that over the step, and the points are evaluated again.
    pub fn apply_contact_forces(&mut self, forces: &[(u32, Vec3)]) -> Result<(), CageError> {
        let nv = self.cage.vertices().len();
        let d = 3 * nv;
        let mut work = std::mem::take(&mut self.contact);
        work.forces.clear();
        work.forces.resize(nv, Vec3::zeros());
        for &(k, f) in forces {
            if !f.iter().all(|c| c.is_finite()) {
                self.contact = work;
                return Err(CageError::NonFinite {
                    what: "contact force on point",
                    index: k as usize,
                });
            }
            self.add_generalised(k as usize, f, &mut work.forces);
        }
        let (rot, h) = match self.reduced.as_ref() {
            Some(r) => (r.frame(self.msd.positions()), r.dt()),
            None => (Matrix3::identity(), self.msd.config().dt),
        };
        match self.reduced.as_ref() {
            Some(r) => {
                let column = work.column.get_or_insert_with(|| DVector::zeros(d));
                if column.len() != d {
                    *column = DVector::zeros(d);
                }
                let rt = rot.transpose();
                for (i, f) in work.forces.iter().enumerate() {
                    let g = rt * f;
                    column.as_mut_slice()[3 * i..3 * i + 3].copy_from_slice(g.as_slice());
                }
                r.compliance_solve(column);
                for (i, f) in work.forces.iter_mut().enumerate() {
                    *f = rot * Vec3::new(column[3 * i], column[3 * i + 1], column[3 * i + 2]);
                }
            }
            None => {
                for i in 0..nv {
                    for a in 0..3 {
                        work.forces[i][a] *= self.explicit_compliance(i, a);
                    }
                }
            }
        }
        if let Some(i) = work
            .forces
            .iter()
            .position(|f| !f.iter().all(|c| c.is_finite()))
        {
            self.contact = work;
            return Err(CageError::NonFinite {
                what: "cage vertex",
                index: i,
            });
        }
        {
            let nodes = self.msd.nodes_mut();
            for (i, dx) in work.forces.iter().enumerate() {
                nodes.x[i] += dx;
                nodes.v[i] += dx / h;
            }
        }
        self.contact = work;
        self.update_points()
    }
}
