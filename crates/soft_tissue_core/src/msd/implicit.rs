//! The linearised implicit integrators (implicit Euler, BDF2): the system's assembly and
//! factorisation, and the step.

use super::*;

impl MsdBody {
    pub(super) fn build_implicit(&mut self) -> Result<(), MsdError> {
        let n = self.nodes.x.len();
        let matrix =
            BlockSparse::from_pairs(n, self.springs.iter().map(|s| [s.a as usize, s.b as usize]));
        let blocks = self
            .springs
            .iter()
            .map(|s| {
                let (a, b) = (s.a as usize, s.b as usize);
                [
                    matrix.diag_index(a),
                    matrix.diag_index(b),
                    matrix.block_index(a, b).expect("pattern"),
                    matrix.block_index(b, a).expect("pattern"),
                ]
                .map(|k| k as u32)
            })
            .collect();
        let tet_blocks = self
            .tets
            .iter()
            .map(|t| {
                let mut s = [0u32; 16];
                for a in 0..4 {
                    for b in 0..4 {
                        s[4 * a + b] = matrix
                            .block_index(t[a] as usize, t[b] as usize)
                            .expect("tetrahedron edges are springs")
                            as u32;
                    }
                }
                s
            })
            .collect();
        let system = ImplicitSystem::new(identity_like(matrix), self.nodes.fixed.clone())?;
        let mut imp = Implicit {
            system,
            blocks,
            tet_blocks,
            rhs: vec![Vec3::zeros(); n],
            dv: vec![Vec3::zeros(); n],
        };
        // Rest-state matrix as the preconditioner.
        self.assemble_implicit(&mut imp, true);
        imp.system.refactor()?;
        self.implicit = Some(imp);
        Ok(())
    }

    /// `M + h gamma I + h^2 (K + Ka)` into the implicit system (at rest positions if `rest`).
    pub(super) fn assemble_implicit(&self, imp: &mut Implicit, rest: bool) {
        let h = self.config.system_dt();
        let x = if rest {
            &self.nodes.rest
        } else {
            &self.nodes.x
        };
        let m = &mut imp.system.matrix;
        m.set_zero();
        let blocks = m.blocks_mut();
        for (s, idx) in self.springs.iter().zip(&imp.blocks) {
            let k = spring_jacobian(s, &x[s.a as usize], &x[s.b as usize]) * (h * h);
            blocks[idx[0] as usize] += k;
            blocks[idx[1] as usize] += k;
            blocks[idx[2] as usize] -= k;
            blocks[idx[3] as usize] -= k;
        }
        // Volume term, Gauss-Newton part k_v / V0 g g^T (positive semi-definite).
        let kv = self.config.volume_stiffness;
        for ((t, v0), idx) in self
            .tets
            .iter()
            .zip(&self.rest_volumes)
            .zip(&imp.tet_blocks)
        {
            let g = volume_gradient(x, t);
            let c = h * h * kv / v0;
            for a in 0..4 {
                for b in 0..4 {
                    blocks[idx[4 * a + b] as usize] += (g[a] * g[b].transpose()) * c;
                }
            }
        }
        for i in 0..self.nodes.x.len() {
            let d = m.diag_index(i);
            let diag =
                self.nodes.mass[i] + h * self.config.damping + h * h * self.nodes.anchor_k[i];
            m.blocks_mut()[d] += Matrix3::identity() * diag;
        }
    }

    /// The rest-state preconditioner for the current system step, refactorized.
    pub(super) fn refactor_implicit(&mut self) -> Result<(), MsdError> {
        if let Some(mut imp) = self.implicit.take() {
            self.assemble_implicit(&mut imp, true);
            let r = imp.system.refactor();
            self.implicit = Some(imp);
            r?;
        }
        Ok(())
    }

    /// BDF2: moves the state to the extrapolated start of the step, starting the history
    /// first when there is none (see [`MsdBody::step`]).
    pub(super) fn extrapolate(&mut self) {
        if self.bdf2.needs_start(self.nodes.x.len()) {
            let mut acc = self.bdf2.take_buffer();
            self.accelerations(&self.nodes.x, &self.nodes.v, &mut acc);
            self.bdf2.start(&self.nodes, acc, self.config.dt);
        }
        self.bdf2.extrapolate(&mut self.nodes);
    }

    pub(super) fn implicit_step(&mut self) -> Result<CgStats, MsdError> {
        let mut imp = self.implicit.take().expect("built with the integrator");
        let h = self.config.system_dt();
        self.assemble_implicit(&mut imp, false);
        // rhs = h (f(x, v) - h (K + Ka) v), with f including damping; (K + Ka) v from the
        // assembled matrix: A v = (m + h gamma) v + h^2 (K + Ka) v.
        let mut av = std::mem::take(&mut self.xt);
        imp.system.matrix.mul(&self.nodes.v, &mut av);
        let g = self.config.gravity;
        let gamma = self.config.damping;
        for i in 0..self.nodes.x.len() {
            imp.rhs[i] = self.nodes.f_ext[i] + self.nodes.mass[i] * g
                - gamma * self.nodes.v[i]
                - self.nodes.anchor_k[i] * (self.nodes.x[i] - self.nodes.anchor_target[i]);
        }
        self.add_internal_forces(&self.nodes.x, &mut imp.rhs);
        for i in 0..self.nodes.x.len() {
            let kv = (av[i] - (self.nodes.mass[i] + h * gamma) * self.nodes.v[i]) / (h * h);
            imp.rhs[i] = h * (imp.rhs[i] - h * kv);
        }
        self.xt = av;
        let stats = imp.system.solve_cg(
            &imp.rhs,
            &mut imp.dv,
            self.config.cg_tolerance,
            self.config.cg_max_iterations,
        );
        let stats = match stats {
            Ok(c) if self.config.cg_must_converge => c
                .require_converged(self.config.cg_tolerance)
                .map_err(MsdError::from),
            other => other.map_err(MsdError::from),
        };
        if stats.is_ok() {
            for i in 0..self.nodes.x.len() {
                for a in 0..3 {
                    if self.nodes.fixed[i][a] {
                        self.nodes.v[i][a] = 0.0;
                    } else {
                        self.nodes.v[i][a] += imp.dv[i][a];
                        self.nodes.x[i][a] += h * self.nodes.v[i][a];
                    }
                }
            }
        }
        self.implicit = Some(imp);
        stats
    }
}

pub(super) fn identity_like(mut m: BlockSparse) -> BlockSparse {
    for i in 0..m.nodes() {
        let d = m.diag_index(i);
        m.blocks_mut()[d] = Matrix3::identity();
    }
    m
}

/// Spring Jacobian block `k (u u^T + max(0, 1 - L/l) (I - u u^T))` (positive semi-definite).
pub(super) fn spring_jacobian(s: &Spring, xa: &Vec3, xb: &Vec3) -> Matrix3<f64> {
    let d = xb - xa;
    let l = d.norm();
    if l == 0.0 || l.is_nan() {
        return Matrix3::identity() * s.stiffness;
    }
    let u = d / l;
    let uu = u * u.transpose();
    let t = (1.0 - s.rest_length / l).max(0.0);
    (uu + (Matrix3::identity() - uu) * t) * s.stiffness
}
