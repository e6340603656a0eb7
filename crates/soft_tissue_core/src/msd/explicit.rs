//! The explicit integrators (RK4, symplectic Euler) and their stability limits: the
//! largest stable step estimated from the springs and the substeps a step needs.

use super::*;

impl MsdBody {
    /// Bounds the largest frequency at the rest state, or at the current one when `current`
    /// (the volume term stiffens as elements stretch, springs do not under tension).
    pub(super) fn estimate_limits_at(&mut self, current: bool) {
        // Gershgorin bound on the eigenvalues of M^-1/2 K M^-1/2 (spring blocks have norm <= k
        // at rest and under tension), plus anchors.
        let n = self.nodes.x.len();
        let mut row = std::mem::take(&mut self.limit_row);
        row.clear();
        row.resize(n, 0.0);
        let x = if current {
            &self.nodes.x
        } else {
            &self.nodes.rest
        };
        for s in &self.springs {
            let (a, b) = (s.a as usize, s.b as usize);
            // Tangent stiffness norm: k along the spring, k |1 - L/l| across it (above k
            // only when compressed below half its length).
            let l = (x[b] - x[a]).norm();
            let factor = if current && l > 0.0 {
                (1.0 - s.rest_length / l).abs().max(1.0)
            } else {
                1.0
            };
            let k = s.stiffness * factor;
            let cross = k / (self.nodes.mass[a] * self.nodes.mass[b]).sqrt();
            row[a] += k / self.nodes.mass[a] + cross;
            row[b] += k / self.nodes.mass[b] + cross;
        }
        let kv = self.config.volume_stiffness;
        for (t, v0) in self.tets.iter().zip(&self.rest_volumes) {
            let g = volume_gradient(x, t);
            let norms = g.map(|v| v.norm());
            let sum: f64 = norms.iter().sum();
            // Second-derivative part: |k_v (V - V0) / V0| times the norm of the blocks of the
            // Hessian of V (skew matrices of edge vectors / 6), bounded by the longest edge.
            let p = t.map(|i| x[i as usize]);
            let mut longest: f64 = 0.0;
            for a in 0..4 {
                for b in a + 1..4 {
                    longest = longest.max((p[a] - p[b]).norm());
                }
            }
            let pressure = (kv * (signed_volume(x, t) - v0) / v0).abs();
            for a in 0..4 {
                let i = t[a] as usize;
                row[i] += (kv / v0 * norms[a] * sum + pressure * 3.0 * longest / 6.0)
                    / self.nodes.mass[i];
            }
        }
        let mut w2: f64 = 0.0;
        let mut rate: f64 = 0.0;
        for i in 0..n {
            w2 = w2.max(row[i] + self.nodes.anchor_k[i] / self.nodes.mass[i]);
            rate = rate.max(self.config.damping / self.nodes.mass[i]);
        }
        self.omega_max = w2.sqrt();
        self.damping_rate = rate;
        self.limit_row = row;
    }

    /// At build time: the Gershgorin bound, tightened by the largest eigenvalue of the
    /// mass-scaled spring graph Laplacian `M^-1/2 (sum_s k_s (e_a - e_b)(e_a - e_b)^T) M^-1/2`.
    /// Every spring's tangent block is at most `k I` under tension, so this bounds the
    /// frequencies of every stretched state, not only the rest one. The power method gives it
    /// from below; 80 iterations and a 5 % margin.
    pub(super) fn estimate_limits(&mut self) {
        self.estimate_limits_at(false);
        if !self.tets.is_empty() {
            return;
        }
        let n = self.nodes.x.len();
        let free: Vec<bool> = self
            .nodes
            .fixed
            .iter()
            .map(|f| !f.iter().all(|&a| a))
            .collect();
        let inv_sqrt_m: Vec<f64> = self.nodes.mass.iter().map(|m| 1.0 / m.sqrt()).collect();
        // Deterministic start with components along every node.
        let mut u: Vec<f64> = (0..n)
            .map(|i| {
                if free[i] {
                    1.0 + ((i * 7919) % 13) as f64 / 13.0
                } else {
                    0.0
                }
            })
            .collect();
        let mut w = vec![0.0; n];
        let mut lambda = 0.0;
        for _ in 0..80 {
            let norm = u.iter().map(|v| v * v).sum::<f64>().sqrt();
            if norm == 0.0 {
                return;
            }
            u.iter_mut().for_each(|v| *v /= norm);
            w.fill(0.0);
            for s in &self.springs {
                let (a, b) = (s.a as usize, s.b as usize);
                let d = s.stiffness * (u[a] * inv_sqrt_m[a] - u[b] * inv_sqrt_m[b]);
                w[a] += d * inv_sqrt_m[a];
                w[b] -= d * inv_sqrt_m[b];
            }
            for i in 0..n {
                w[i] = if free[i] {
                    w[i] + self.nodes.anchor_k[i] / self.nodes.mass[i] * u[i]
                } else {
                    0.0
                };
            }
            lambda = u.iter().zip(&w).map(|(a, b)| a * b).sum::<f64>();
            std::mem::swap(&mut u, &mut w);
        }
        let power = (1.05 * lambda).max(0.0).sqrt();
        self.omega_max = self.omega_max.min(power);
    }

    /// Estimated largest stable step of the configured explicit integrator (infinite for the
    /// implicit one). RK4 is stable for `|lambda h| < 2.78` on the negative real axis and
    /// `< 2.83` on the imaginary axis; symplectic Euler for `omega h < 2`. The bound uses
    /// `omega_max + gamma / m_min` with a margin (2.5 and 1.9).
    pub fn stable_dt(&self) -> f64 {
        let rho = self.omega_max + self.damping_rate;
        if rho == 0.0 {
            return f64::INFINITY;
        }
        match self.config.integrator {
            MsdIntegrator::Rk4 => 2.5 / rho,
            MsdIntegrator::SymplecticEuler => 1.9 / rho,
            MsdIntegrator::ImplicitEuler | MsdIntegrator::ImplicitBdf2 => f64::INFINITY,
        }
    }

    /// Number of substeps the next step will take, or the error if the policy refuses it.
    pub fn substeps_needed(&self) -> Result<u32, MsdError> {
        let limit = self.stable_dt();
        let dt = self.config.dt;
        if dt <= limit {
            return Ok(1);
        }
        let needed = (dt / limit).ceil() as u64;
        let allowed = match self.config.explicit_limit {
            ExplicitLimit::Substep { max_substeps } => max_substeps,
            ExplicitLimit::Refuse => 0,
        };
        if needed > allowed as u64 {
            return Err(MsdError::TimeStepTooLarge {
                integrator: self.config.integrator,
                dt,
                limit,
                needed,
                allowed,
            });
        }
        Ok(needed as u32)
    }

    pub(super) fn rk4(&mut self, h: f64) {
        let n = self.nodes.x.len();
        let mut kx = std::mem::take(&mut self.kx);
        let mut kv = std::mem::take(&mut self.kv);
        let mut xt = std::mem::take(&mut self.xt);
        let mut vt = std::mem::take(&mut self.vt);
        // Stage 1
        kx[0].copy_from_slice(&self.nodes.v);
        self.accelerations(&self.nodes.x, &self.nodes.v, &mut kv[0]);
        // Stages 2-4
        for (s, c) in [(1usize, 0.5 * h), (2, 0.5 * h), (3, h)] {
            for i in 0..n {
                xt[i] = self.nodes.x[i] + c * kx[s - 1][i];
                vt[i] = self.nodes.v[i] + c * kv[s - 1][i];
            }
            kx[s].copy_from_slice(&vt);
            self.accelerations(&xt, &vt, &mut kv[s]);
        }
        for i in 0..n {
            let dx = (kx[0][i] + 2.0 * kx[1][i] + 2.0 * kx[2][i] + kx[3][i]) * (h / 6.0);
            let dv = (kv[0][i] + 2.0 * kv[1][i] + 2.0 * kv[2][i] + kv[3][i]) * (h / 6.0);
            for a in 0..3 {
                if self.nodes.fixed[i][a] {
                    self.nodes.v[i][a] = 0.0;
                } else {
                    self.nodes.x[i][a] += dx[a];
                    self.nodes.v[i][a] += dv[a];
                }
            }
        }
        self.kx = kx;
        self.kv = kv;
        self.xt = xt;
        self.vt = vt;
    }

    pub(super) fn symplectic(&mut self, h: f64) {
        let mut acc = std::mem::take(&mut self.xt);
        self.accelerations(&self.nodes.x, &self.nodes.v, &mut acc);
        for i in 0..self.nodes.x.len() {
            for a in 0..3 {
                if self.nodes.fixed[i][a] {
                    self.nodes.v[i][a] = 0.0;
                } else {
                    self.nodes.v[i][a] += h * acc[i][a];
                    self.nodes.x[i][a] += h * self.nodes.v[i][a];
                }
            }
        }
        self.xt = acc;
    }
}
