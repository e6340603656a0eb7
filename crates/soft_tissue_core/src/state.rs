//! The per-node state of the precise bodies (FEM and MSD), its accessors, and the checks and
//! measures they share.

use crate::Vec3;

fn finite(v: &Vec3) -> bool {
    v.iter().all(|c| c.is_finite())
}

/// The first non-finite position or velocity, as `(what, node)`.
pub(crate) fn first_non_finite_state(x: &[Vec3], v: &[Vec3]) -> Option<(&'static str, usize)> {
    x.iter().zip(v).enumerate().find_map(|(i, (x, v))| {
        if !finite(x) {
            Some(("position", i))
        } else if !finite(v) {
            Some(("velocity", i))
        } else {
            None
        }
    })
}

/// The first non-finite external force, position or velocity, as `(what, node)`.
fn first_non_finite_input(f_ext: &[Vec3], x: &[Vec3], v: &[Vec3]) -> Option<(&'static str, usize)> {
    f_ext
        .iter()
        .position(|f| !finite(f))
        .map(|i| ("external force", i))
        .or_else(|| first_non_finite_state(x, v))
}

/// `1/2 sum m v^2`.
pub(crate) fn kinetic_energy(v: &[Vec3], mass: &[f64]) -> f64 {
    0.5 * v
        .iter()
        .zip(mass)
        .map(|(v, m)| m * v.norm_squared())
        .sum::<f64>()
}

/// The larger of `a` and `b`, NaN when either is (`f64::max` drops a NaN, so a reduction
/// over broken values would read as a good one).
pub(crate) fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

/// Largest speed; NaN when any velocity is (never "at rest").
pub(crate) fn max_speed(v: &[Vec3]) -> f64 {
    v.iter().map(|v| v.norm()).fold(0.0, nan_max)
}

/// The per-node state every precise body keeps: rest and current positions, velocities, the
/// external force accumulator, lumped masses, fixed axes and soft anchors.
#[derive(Debug, Clone)]
pub struct Nodes {
    pub(crate) rest: Vec<Vec3>,
    pub(crate) x: Vec<Vec3>,
    pub(crate) v: Vec<Vec3>,
    pub(crate) f_ext: Vec<Vec3>,
    pub(crate) mass: Vec<f64>,
    pub(crate) fixed: Vec<[bool; 3]>,
    pub(crate) anchor_k: Vec<f64>,
    pub(crate) anchor_target: Vec<Vec3>,
}

impl Nodes {
    /// At rest at `rest`, anchors targeting the rest positions.
    pub(crate) fn new(
        rest: Vec<Vec3>,
        mass: Vec<f64>,
        fixed: Vec<[bool; 3]>,
        anchor_k: Vec<f64>,
    ) -> Self {
        let n = rest.len();
        Nodes {
            x: rest.clone(),
            anchor_target: rest.clone(),
            rest,
            v: vec![Vec3::zeros(); n],
            f_ext: vec![Vec3::zeros(); n],
            mass,
            fixed,
            anchor_k,
        }
    }

    /// Back at rest in the rest shape, no pending force.
    pub(crate) fn reset(&mut self) {
        self.x.copy_from_slice(&self.rest);
        self.v.fill(Vec3::zeros());
        self.f_ext.fill(Vec3::zeros());
    }

    /// The first non-finite external force, position or velocity.
    pub(crate) fn first_non_finite_input(&self) -> Option<(&'static str, usize)> {
        first_non_finite_input(&self.f_ext, &self.x, &self.v)
    }

    /// Moves the rest shape and the anchors' targets rigidly by `m` (a teleport; see
    /// [`crate::precision::LeveledModel::teleport`]).
    pub(crate) fn move_rest(&mut self, m: &nalgebra::Isometry3<f64>) {
        for p in self.rest.iter_mut().chain(self.anchor_target.iter_mut()) {
            *p = m * nalgebra::Point3::from(*p) - nalgebra::Point3::origin();
        }
    }

    /// Moves the state rigidly by `m`: positions (fixed components too: a support moves with
    /// the body) moved, velocities and pending forces turned.
    pub(crate) fn move_state(&mut self, m: &nalgebra::Isometry3<f64>) {
        for p in &mut self.x {
            *p = m * nalgebra::Point3::from(*p) - nalgebra::Point3::origin();
        }
        for v in self.v.iter_mut().chain(self.f_ext.iter_mut()) {
            *v = m.rotation * *v;
        }
    }

    /// Energy of the anchor springs.
    pub(crate) fn anchor_energy(&self) -> f64 {
        self.x
            .iter()
            .zip(&self.anchor_target)
            .zip(&self.anchor_k)
            .map(|((x, t), k)| 0.5 * k * (x - t).norm_squared())
            .sum()
    }
}

/// What every precise body (FEM, MSD) exposes about its nodes. Import it to call these on a
/// [`crate::fem::FemBody`] or [`crate::msd::MsdBody`].
pub trait NodalModel {
    /// The per-node state.
    fn nodes(&self) -> &Nodes;

    /// The per-node state, to change.
    fn nodes_mut(&mut self) -> &mut Nodes;

    /// Number of nodes.
    fn node_count(&self) -> usize {
        self.nodes().x.len()
    }

    /// Rest positions.
    fn rest_positions(&self) -> &[Vec3] {
        &self.nodes().rest
    }

    /// Current positions.
    fn positions(&self) -> &[Vec3] {
        &self.nodes().x
    }

    /// Current positions, to set (state transfer, or moving fixed nodes kinematically: a
    /// fixed component keeps whatever position it is given).
    fn positions_mut(&mut self) -> &mut [Vec3] {
        &mut self.nodes_mut().x
    }

    /// Current velocities.
    fn velocities(&self) -> &[Vec3] {
        &self.nodes().v
    }

    /// Current velocities, to set.
    fn velocities_mut(&mut self) -> &mut [Vec3] {
        &mut self.nodes_mut().v
    }

    /// Lumped node masses.
    fn masses(&self) -> &[f64] {
        &self.nodes().mass
    }

    /// Per-node fixed axes.
    fn fixed(&self) -> &[[bool; 3]] {
        &self.nodes().fixed
    }

    /// External forces waiting for the next step.
    fn external_forces(&self) -> &[Vec3] {
        &self.nodes().f_ext
    }

    /// External force accumulator (force units per node): forces added here act during the
    /// next step and are then cleared.
    fn external_forces_mut(&mut self) -> &mut [Vec3] {
        &mut self.nodes_mut().f_ext
    }

    /// Adds an external force on a node for the next step. Ignores a node out of range.
    fn add_force(&mut self, node: usize, force: Vec3) {
        if let Some(f) = self.nodes_mut().f_ext.get_mut(node) {
            *f += force;
        }
    }

    /// Stiffness of each node's soft anchor, force per length (0: none).
    fn anchor_stiffnesses(&self) -> &[f64] {
        &self.nodes().anchor_k
    }

    /// The total force the soft anchors put on the body now, `-sum k (x - target)` (the
    /// reaction of what holds the body).
    fn anchor_force(&self) -> Vec3 {
        let n = self.nodes();
        n.x.iter()
            .zip(&n.anchor_target)
            .zip(&n.anchor_k)
            .map(|((x, t), k)| -(x - t) * *k)
            .sum()
    }

    /// Targets of the soft anchors (rest positions unless set).
    fn anchor_targets_mut(&mut self) -> &mut [Vec3] {
        &mut self.nodes_mut().anchor_target
    }

    /// Kinetic energy `1/2 sum m v^2`.
    fn kinetic_energy(&self) -> f64 {
        kinetic_energy(&self.nodes().v, &self.nodes().mass)
    }

    /// Largest node speed.
    fn max_speed(&self) -> f64 {
        max_speed(&self.nodes().v)
    }
}

/// BDF2's memory of the last step: `x_n - x_{n-1}` and `v_n - v_{n-1}` (empty until BDF2 is
/// first used). A BDF2 step is a backward Euler step of `2 dt / 3` from the extrapolated state
/// `x_n + (x_n - x_{n-1}) / 3`, `v_n + (v_n - v_{n-1}) / 3`; FEM and MSD bodies share this
/// bookkeeping.
#[derive(Debug, Clone, Default)]
pub(crate) struct Bdf2History {
    dx: Vec<Vec3>,
    dv: Vec<Vec3>,
    /// Whether the differences belong to the current state (false after building, a reset,
    /// a change of model, step or integrator, a rotation sync, a level switch).
    pub(crate) valid: bool,
}

impl Bdf2History {
    /// Makes it hold `n` nodes (a new size forgets the history; allocates only then) and
    /// says whether a history must be started.
    pub(crate) fn needs_start(&mut self, n: usize) -> bool {
        if self.dx.len() != n {
            self.dx = vec![Vec3::zeros(); n];
            self.dv = vec![Vec3::zeros(); n];
            self.valid = false;
        }
        !self.valid
    }

    /// A buffer of one vector per node for the caller's accelerations (taken from the
    /// history; give it back through [`Bdf2History::start`]).
    pub(crate) fn take_buffer(&mut self) -> Vec<Vec3> {
        std::mem::take(&mut self.dv)
    }

    /// Starts a history for a state without one: `dt v_n` and `dt a_n` (`acc` the current
    /// accelerations, the buffer from [`Bdf2History::take_buffer`]); fixed components zero.
    /// Errors of order `dt^2`, so the method stays second order; exact at rest.
    pub(crate) fn start(&mut self, nodes: &Nodes, mut acc: Vec<Vec3>, h: f64) {
        for (i, a) in acc.iter_mut().enumerate() {
            for k in 0..3 {
                let held = nodes.fixed[i][k];
                a[k] = if held { 0.0 } else { h * a[k] };
                self.dx[i][k] = if held { 0.0 } else { h * nodes.v[i][k] };
            }
        }
        self.dv = acc;
        self.valid = true;
    }

    /// Turns the recorded differences with a body turned by `r` (a teleport).
    pub(crate) fn turn(&mut self, r: &nalgebra::UnitQuaternion<f64>) {
        for d in self.dx.iter_mut().chain(self.dv.iter_mut()) {
            *d = r * *d;
        }
    }

    /// Moves the free components of the state to the extrapolated start of the step.
    pub(crate) fn extrapolate(&self, nodes: &mut Nodes) {
        for i in 0..nodes.x.len() {
            for k in 0..3 {
                if !nodes.fixed[i][k] {
                    nodes.x[i][k] += self.dx[i][k] / 3.0;
                    nodes.v[i][k] += self.dv[i][k] / 3.0;
                }
            }
        }
    }

    /// Adds a change made as part of the step just recorded (a contact correction) to the
    /// step's differences, so the next step extrapolates from the corrected step. Nothing
    /// without a history.
    pub(crate) fn absorb(&mut self, dx: &[Vec3], dv: &[Vec3]) {
        if !self.valid || self.dx.len() != dx.len() {
            return;
        }
        for i in 0..dx.len() {
            self.dx[i] += dx[i];
            self.dv[i] += dv[i];
        }
    }

    /// Records the step just taken, from `before_x`, `before_v` to the nodes' state.
    pub(crate) fn record(&mut self, nodes: &Nodes, before_x: &[Vec3], before_v: &[Vec3]) {
        for i in 0..nodes.x.len() {
            self.dx[i] = nodes.x[i] - before_x[i];
            self.dv[i] = nodes.v[i] - before_v[i];
        }
        self.valid = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A NaN anywhere makes the largest speed NaN (a body with a NaN velocity is never taken
    /// for one at rest); otherwise it is the plain maximum.
    #[test]
    fn reductions_keep_nan() {
        let v = [Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 2.0, 0.0)];
        assert_eq!(max_speed(&v), 2.0);
        for k in 0..2 {
            let mut w = v;
            w[k].y = f64::NAN;
            assert!(max_speed(&w).is_nan(), "NaN in velocity {k}");
        }
        assert!(nan_max(f64::NAN, 1.0).is_nan() && nan_max(1.0, f64::NAN).is_nan());
        assert_eq!(nan_max(-1.0, 3.0), 3.0);
    }
}
