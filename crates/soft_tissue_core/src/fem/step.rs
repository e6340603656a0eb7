//! A FEM body's time step: backward Euler or BDF2 on the linear system of its model (the
//! rest system factorised once; the corotational one warped by the element rotations,
//! refreshed where they moved, and solved by CG), and the static solve.

use super::*;

impl FemBody {
    /// Advances by one time step `config().dt`. On error the state is unchanged (the external
    /// force accumulator is kept for inspection).
    ///
    /// BDF2 ([`FemIntegrator::Bdf2`]) keeps the last step's differences `x_n - x_{n-1}` and
    /// `v_n - v_{n-1}` and takes a backward Euler step of `2 dt / 3` from `x_n + (x_n -
    /// x_{n-1}) / 3`, `v_n + (v_n - v_{n-1}) / 3` (fixed components stay where they are).
    /// Changes made to the state between steps (a contact's correction, a kinematic move)
    /// shift the whole history with them: `x_{n-1}` moves by the same amount as `x_n`, so the
    /// step continues from the corrected state and a correction is not extrapolated (no 4/3
    /// overshoot). The first step, and the first after a reset, a change of model, step or
    /// integrator, a rotation sync or [`FemBody::restart_history`], has no `x_{n-1}`: it takes
    /// `x_n - x_{n-1} = dt v_n`, `v_n - v_{n-1} = dt a_n` with `a_n` the acceleration of the
    /// current state under the step's forces (exact at rest; errors of order `dt^2`, so the
    /// method stays second order).
    pub fn step(&mut self) -> Result<FemStepStats, FemError> {
        self.check_inputs()?;
        self.backup_x.copy_from_slice(&self.nodes.x);
        self.backup_v.copy_from_slice(&self.nodes.v);
        let bdf2 = self.config.integrator == FemIntegrator::Bdf2;
        if bdf2 {
            self.extrapolate();
        }
        match self.step_from_current() {
            Ok(stats) => {
                if bdf2 {
                    self.bdf2
                        .record(&self.nodes, &self.backup_x, &self.backup_v);
                }
                self.nodes.f_ext.fill(Vec3::zeros());
                self.stats = stats;
                Ok(stats)
            }
            Err(e) => {
                self.nodes.x.copy_from_slice(&self.backup_x);
                self.nodes.v.copy_from_slice(&self.backup_v);
                self.dv.fill(Vec3::zeros());
                Err(e)
            }
        }
    }

    /// BDF2: moves the state to the extrapolated start of the step (see [`FemBody::step`]),
    /// starting the history first when there is none.
    pub(super) fn extrapolate(&mut self) {
        if self.bdf2.needs_start(self.nodes.x.len()) {
            self.start_history();
        }
        self.bdf2.extrapolate(&mut self.nodes);
    }

    /// A history for a state without one: `dt v_n` and `dt a_n`, `a_n` the acceleration of
    /// the current state under the step's external forces, gravity, damping, elastic and
    /// anchor forces (rotations extracted afresh; stiffness damping with the rest stiffness
    /// for the linear model, the assembled warped one for the corotational model).
    pub(super) fn start_history(&mut self) {
        let h = self.config.dt;
        let model = self.config.model;
        let mut f = self.bdf2.take_buffer();
        self.forces_and_energy(&self.nodes.x, model, &mut f);
        let (alpha, beta) = (self.config.mass_damping, self.config.stiffness_damping);
        if beta > 0.0 {
            match model {
                FemModel::Linear => self.k_rest.mul_add(-beta, &self.nodes.v, &mut f),
                FemModel::Corotational | FemModel::CorotationalPrefactored => {
                    // K v = (A v - G v) / c with the system matrix A = G + c K.
                    let hs = self.config.system_dt();
                    let c = beta * hs + hs * hs;
                    self.system.matrix.mul(&self.nodes.v, &mut self.tmp);
                    for i in 0..f.len() {
                        let diag = (1.0 + hs * alpha) * self.nodes.mass[i]
                            + hs * hs * self.nodes.anchor_k[i];
                        f[i] -= beta * (self.tmp[i] - diag * self.nodes.v[i]) / c;
                    }
                }
            }
        }
        let g = self.config.gravity;
        for i in 0..f.len() {
            let m = self.nodes.mass[i];
            f[i] = (f[i] + self.nodes.f_ext[i]) / m + g - alpha * self.nodes.v[i];
        }
        self.bdf2.start(&self.nodes, f, h);
    }

    /// One backward Euler step of `config().system_dt()` from the current state; on error
    /// the caller restores the state.
    pub(super) fn step_from_current(&mut self) -> Result<FemStepStats, FemError> {
        let h = self.config.system_dt();
        let alpha = self.config.mass_damping;
        let mut stats = FemStepStats::default();
        match self.config.model {
            FemModel::Linear => {
                self.fill_common_rhs();
                let start = Instant::now();
                let with_product = !self.fixed_at_rest();
                self.linear_dv(with_product)?;
                stats.solve_us = start.elapsed().as_secs_f64() * 1e6;
            }
            FemModel::Corotational => {
                self.fill_common_rhs();
                (
                    stats.rotation_iterations,
                    stats.assembled,
                    stats.forces_us,
                    stats.assembly_us,
                ) = self.corotational_forces_and_matrix();
                let start = Instant::now();
                // -(beta + h) K_R v  =  -(A v - (1 + h alpha) M v - h^2 Ka v) / h
                self.system.matrix.mul(&self.nodes.v, &mut self.tmp);
                for i in 0..self.nodes.x.len() {
                    let diag =
                        (1.0 + h * alpha) * self.nodes.mass[i] + h * h * self.nodes.anchor_k[i];
                    let krv = (self.tmp[i] - diag * self.nodes.v[i]) / h;
                    self.rhs[i] = h * (self.rhs[i] - krv);
                }
                // A body free to turn as a whole preconditions with its rest factor turned
                // the way it turned (its best rigid fit).
                let frame = self.body_frame();
                self.system.set_preconditioner_frame(frame);
                stats.cg = self.system.solve_cg(
                    &self.rhs,
                    &mut self.dv,
                    self.config.cg_tolerance,
                    self.config.cg_max_iterations,
                )?;
                if self.config.cg_must_converge
                    && let Err(e) = stats.cg.require_converged(self.config.cg_tolerance)
                {
                    self.dv.fill(Vec3::zeros());
                    return Err(e.into());
                }
                stats.solve_us = start.elapsed().as_secs_f64() * 1e6;
            }
            FemModel::CorotationalPrefactored => {
                let (worst, loops_us, solve_us) = self.prefactored_step()?;
                stats.rotation_iterations = worst;
                stats.forces_us = loops_us;
                stats.solve_us = solve_us;
            }
        }
        for i in 0..self.nodes.x.len() {
            for a in 0..3 {
                if self.nodes.fixed[i][a] {
                    self.nodes.v[i][a] = 0.0;
                } else {
                    self.nodes.v[i][a] += self.dv[i][a];
                    self.nodes.x[i][a] += h * self.nodes.v[i][a];
                }
            }
        }
        if let Some((what, node)) = state::first_non_finite_state(&self.nodes.x, &self.nodes.v) {
            return Err(FemError::NonFinite { what, node });
        }
        Ok(stats)
    }

    /// The rotation of the body's best rigid fit to its rest shape (mass-weighted, warm
    /// started from the last), for a body with no fixed components; `None` otherwise.
    pub(super) fn body_frame(&mut self) -> Option<Matrix3<f64>> {
        if self.nodes.fixed.iter().any(|f| f.iter().any(|&a| a)) {
            return None;
        }
        let n = &self.nodes;
        let total: f64 = n.mass.iter().sum();
        let c: Vec3 = n.x.iter().zip(&n.mass).map(|(x, m)| x * *m).sum::<Vec3>() / total;
        let c0: Vec3 = n
            .rest
            .iter()
            .zip(&n.mass)
            .map(|(x, m)| x * *m)
            .sum::<Vec3>()
            / total;
        let mut h = Matrix3::zeros();
        for ((x, x0), m) in n.x.iter().zip(&n.rest).zip(&n.mass) {
            h += (x - c) * (x0 - c0).transpose() * *m;
        }
        let mut r = Matrix3::identity();
        rotation::extract_rotation(&h, &mut self.frame, &mut r, 50, 1e-12);
        Some(r)
    }

    /// Forces that do not depend on the model: external, gravity, mass damping, anchors
    /// (with their implicit term), into `rhs`.
    pub(super) fn fill_common_rhs(&mut self) {
        let h = self.config.system_dt();
        let alpha = self.config.mass_damping;
        let g = self.config.gravity;
        for i in 0..self.nodes.x.len() {
            let m = self.nodes.mass[i];
            let k = self.nodes.anchor_k[i];
            self.rhs[i] = self.nodes.f_ext[i] + m * g
                - alpha * m * self.nodes.v[i]
                - k * (self.nodes.x[i] - self.nodes.anchor_target[i] + h * self.nodes.v[i]);
        }
    }

    /// Linear model: `dv` from the forces in `rhs`, either with a product with `K` or
    /// without one (exact only when the fixed components sit at rest).
    pub(super) fn linear_dv(&mut self, with_product: bool) -> Result<(), FemError> {
        let h = self.config.system_dt();
        let alpha = self.config.mass_damping;
        let beta = self.config.stiffness_damping;
        if !with_product {
            // The system matrix is A = G + c K with G = (1 + h alpha) M + h^2 Ka diagonal
            // and c = h beta + h^2, so h K y = (h / c) (A y - G y) for y = u + (beta + h) v:
            // dv = A^-1 (h r + (h / c) G y) - (h / c) y, one solve and no product with K.
            // Exact on the free unknowns when the fixed components sit at rest (y = 0
            // there); otherwise the branch below multiplies by K.
            let c = beta * h + h * h;
            let hc = h / c;
            for i in 0..self.nodes.x.len() {
                let y = self.nodes.x[i] - self.nodes.rest[i] + (beta + h) * self.nodes.v[i];
                let diag = (1.0 + h * alpha) * self.nodes.mass[i] + h * h * self.nodes.anchor_k[i];
                self.tmp[i] = y;
                self.rhs[i] = h * self.rhs[i] + (hc * diag) * y;
            }
            self.system.solve_direct(&self.rhs, &mut self.dv)?;
            for (d, y) in self.dv.iter_mut().zip(&self.tmp) {
                *d -= hc * y;
            }
        } else {
            // -K (u + (beta + h) v)
            for i in 0..self.nodes.x.len() {
                self.tmp[i] = self.nodes.x[i] - self.nodes.rest[i] + (beta + h) * self.nodes.v[i];
            }
            self.k_rest.mul_add(-1.0, &self.tmp, &mut self.rhs);
            for r in &mut self.rhs {
                *r *= h;
            }
            self.system.solve_direct(&self.rhs, &mut self.dv)?;
        }
        Ok(())
    }

    /// Whether every fixed component sits at its rest coordinate (not moved kinematically).
    pub(super) fn fixed_at_rest(&self) -> bool {
        self.nodes
            .fixed
            .iter()
            .zip(self.nodes.x.iter().zip(&self.nodes.rest))
            .all(|(f, (x, r))| (0..3).all(|a| !f[a] || x[a] == r[a]))
    }

    /// Corotational: updates rotations, adds elastic forces to `rhs`, and assembles the
    /// system matrix `(1 + h alpha) M + (h beta + h^2) R K R^T + h^2 Ka`. Returns the worst
    /// rotation iterations, whether it assembled, and the times of the two, microseconds.
    pub(super) fn corotational_forces_and_matrix(&mut self) -> (u32, bool, f64, f64) {
        let start = Instant::now();
        let cos_half = (0.5 * self.config.stiffness_update_angle).cos();
        let loop_stats = self.packed.forces(
            &self.nodes.x,
            packed::RotationState {
                quats: &mut self.quats,
                rots: &mut self.rots,
                assembled: &self.quats_assembled,
                stale: &mut self.stale,
            },
            self.lambda,
            self.mu,
            self.config.rotation_iterations,
            self.config.rotation_tolerance,
            cos_half,
            &mut self.rhs,
        );
        let worst = loop_stats.worst_iterations;
        let forces_us = start.elapsed().as_secs_f64() * 1e6;
        let start = Instant::now();
        let assembled = if !self.matrix_current || self.config.stiffness_update_angle == 0.0 {
            self.assemble_warped_system();
            true
        } else if loop_stats.stale {
            self.update_stale_elements();
            true
        } else {
            false
        };
        (
            worst,
            assembled,
            forces_us,
            start.elapsed().as_secs_f64() * 1e6,
        )
    }

    /// Updates the warped stiffness of the stale elements of this step's element loop (at
    /// most [`ASSEMBLY_SHARE`] of all elements, continuing round robin from where the last
    /// update stopped): each element's contribution with its assembled rotation is taken out
    /// and the one with its current rotation put in.
    pub(super) fn update_stale_elements(&mut self) {
        let n = self.stale.len();
        if n == 0 {
            return;
        }
        let budget = (self.tets.len() / ASSEMBLY_SHARE).max(64).min(n);
        let start = self
            .stale
            .partition_point(|&t| (t as usize) < self.assembly_cursor);
        let h = self.config.system_dt();
        let c = self.config.stiffness_damping * h + h * h;
        let (lambda, mu) = (self.lambda, self.mu);
        let element = |k: usize| self.stale[(start + k) % n] as usize;
        // An element's change `c (K(R) - K(R_assembled))` of its ten upper blocks; in a pool
        // the changes are computed side by side (the costly part), then added in element
        // order either way, so the matrix does not depend on the thread count.
        let delta = |t: usize| {
            let old = *self.quats_assembled[t].to_rotation_matrix().matrix();
            let (g, v) = (&self.grads[t], self.volumes[t]);
            element_upper_change(g, v, &old, &self.rots[t], lambda, mu, c)
        };
        let parallel = crate::parallel::in_pool() && budget >= 2 * PARALLEL_ELEMENTS;
        if parallel {
            if self.assembly_deltas.len() < budget {
                self.assembly_deltas.resize(budget, [[0.0; 9]; 10]);
            }
            self.assembly_deltas[..budget]
                .par_iter_mut()
                .with_min_len(PARALLEL_ELEMENTS / 4)
                .enumerate()
                .for_each(|(k, d)| *d = delta(element(k)));
        }
        let mut last = 0;
        for k in 0..budget {
            let t = element(k);
            let d = if parallel {
                self.assembly_deltas[k]
            } else {
                delta(t)
            };
            scatter_upper(self.system.matrix.blocks_mut(), &self.upper[t], &d);
            for &target in &self.upper[t] {
                self.system
                    .matrix
                    .mirror_block((target & !TRANSPOSED) as usize);
            }
            last = t;
        }
        for k in 0..budget {
            let t = element(k);
            self.quats_assembled[t] = self.quats[t];
        }
        self.assembly_cursor = last + 1;
    }

    /// `(1 + h alpha) M + (h beta + h^2) R K R^T + h^2 Ka` with the current rotations, in the
    /// upper triangle through the scatter map, then mirrored.
    pub(super) fn assemble_warped_system(&mut self) {
        let h = self.config.system_dt();
        let c = self.config.stiffness_damping * h + h * h;
        self.system.matrix.set_upper_zero();
        let rots = &self.rots;
        add_warped_upper(
            &mut self.system.matrix,
            &self.upper,
            &self.grads,
            &self.volumes,
            |t| rots[t],
            self.lambda,
            self.mu,
            c,
        );
        self.system.matrix.mirror_upper();
        let alpha = self.config.mass_damping;
        for i in 0..self.nodes.x.len() {
            let d = self.system.matrix.diag_index(i);
            let diag = (1.0 + h * alpha) * self.nodes.mass[i] + h * h * self.nodes.anchor_k[i];
            self.system.matrix.blocks_mut()[d] += Matrix3::from_diagonal_element(diag);
        }
        self.quats_assembled.copy_from_slice(&self.quats);
        self.matrix_current = true;
    }

    /// Solves for static equilibrium under gravity, external forces (kept, not cleared) and
    /// anchors, in place of the current positions; velocities are zeroed. Linear: one solve.
    /// Corotational: Newton-like iterations with the warped stiffness until the largest
    /// update is below `tolerance` times the rest bounding-box diagonal. Builds (once) a
    /// factorization of the stiffness; not meant for every frame.
    pub fn solve_static(&mut self, tolerance: f64, max_iterations: u32) -> Result<u32, FemError> {
        let boundary_ok = self.nodes.fixed.iter().any(|f| f.iter().any(|&a| a))
            || self.nodes.anchor_k.iter().any(|&k| k > 0.0);
        if !boundary_ok {
            return Err(FemError::Unconstrained);
        }
        self.check_inputs()?;
        if self.static_system.is_none() {
            let mut k = self.k_rest.clone();
            for i in 0..self.nodes.x.len() {
                let d = k.diag_index(i);
                k.blocks_mut()[d] += Matrix3::identity() * self.nodes.anchor_k[i];
            }
            self.static_system = Some(ImplicitSystem::new(k, self.nodes.fixed.clone())?);
        }
        let size = {
            let (lo, hi) = self.nodes.rest.iter().fold(
                (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY)),
                |(lo, hi), p| (lo.inf(p), hi.sup(p)),
            );
            (hi - lo).norm()
        };
        let model = self.config.model;
        let g = self.config.gravity;
        let mut f = vec![Vec3::zeros(); self.nodes.x.len()];
        let mut dx = vec![Vec3::zeros(); self.nodes.x.len()];
        let mut update = f64::INFINITY;
        let mut rots = vec![Matrix3::identity(); self.tets.len()];
        for it in 0..max_iterations.max(1) {
            self.forces_and_energy(&self.nodes.x.clone(), model, &mut f);
            for i in 0..f.len() {
                f[i] += self.nodes.f_ext[i] + self.nodes.mass[i] * g;
            }
            let sys = self.static_system.as_mut().expect("built above");
            dx.fill(Vec3::zeros());
            match model {
                FemModel::Linear => sys.solve_direct(&f, &mut dx)?,
                FemModel::Corotational | FemModel::CorotationalPrefactored => {
                    for (t, r) in rots.iter_mut().enumerate() {
                        let p = self.tets[t].map(|i| self.nodes.x[i as usize]);
                        *r = rotation::rotation_of(&element::deformation_gradient(
                            &p,
                            &self.grads[t],
                        ));
                    }
                    sys.matrix.set_upper_zero();
                    add_warped_upper(
                        &mut sys.matrix,
                        &self.upper,
                        &self.grads,
                        &self.volumes,
                        |t| rots[t],
                        self.lambda,
                        self.mu,
                        1.0,
                    );
                    sys.matrix.mirror_upper();
                    for i in 0..self.nodes.x.len() {
                        let d = sys.matrix.diag_index(i);
                        sys.matrix.blocks_mut()[d] += Matrix3::identity() * self.nodes.anchor_k[i];
                    }
                    sys.solve_cg(&f, &mut dx, 1e-12, 500)?;
                }
            }
            for i in 0..self.nodes.x.len() {
                self.nodes.x[i] += dx[i];
            }
            update = dx.iter().map(|d| d.norm()).fold(0.0, state::nan_max) / size;
            if !update.is_finite() {
                self.nodes.x.copy_from_slice(&self.nodes.rest);
                return Err(FemError::NonFinite {
                    what: "position",
                    node: 0,
                });
            }
            if model == FemModel::Linear || update <= tolerance {
                self.nodes.v.fill(Vec3::zeros());
                return Ok(it + 1);
            }
        }
        Err(FemError::StaticNotConverged {
            iterations: max_iterations,
            update,
        })
    }
}
