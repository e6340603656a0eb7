//! The settings of a FEM body and how its mass is given.

use super::*;

/// How the body's mass is given.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum MassSpec {
    /// Total mass (mass units), lumped onto nodes in proportion to their share of volume.
    Total(f64),
    /// Density (mass / length^3); node mass is density times a quarter of each adjacent
    /// tetrahedron's volume.
    Density(f64),
}

/// Settings of a FEM body. Units follow the scene (see [`crate::material`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FemConfig {
    /// Elastic model. Default: corotational.
    pub model: FemModel,
    /// Young's modulus, force / length^2.
    pub young_modulus: f64,
    /// Poisson ratio, in (-1, 0.5).
    pub poisson_ratio: f64,
    /// Mass of the body.
    pub mass: MassSpec,
    /// Rayleigh mass-proportional damping `alpha`, 1 / time (the paper's FEM "damping").
    pub mass_damping: f64,
    /// Rayleigh stiffness-proportional damping `beta`, time. Default 0.
    pub stiffness_damping: f64,
    /// Time step, time.
    pub dt: f64,
    /// Gravity, length / time^2. Default zero.
    pub gravity: Vec3,
    /// Relative residual at which the corotational CG stops. Default 1e-4.
    pub cg_tolerance: f64,
    /// Iteration cap of the corotational CG. Default 20.
    pub cg_max_iterations: u32,
    /// What a corotational CG that reaches its cap without meeting its tolerance does.
    /// `false` (the default, for real time): the step goes on with the last iterate (an
    /// inexact implicit step, still stable) and says so ([`FemStepStats::cg`]'s `converged`
    /// is false; the world counts it in `BodyDiagnostics::unconverged_solves`). `true`: the
    /// step fails with [`FemError::NotConverged`] and leaves the state unchanged.
    #[serde(default)]
    pub cg_must_converge: bool,
    /// Iteration cap of the per-element rotation extraction (warm-started). Default 1.
    pub rotation_iterations: u32,
    /// Corotational: an element's warped stiffness in the implicit system is updated when it
    /// has turned by more than this angle (radians) since its last update; forces always use
    /// the current rotations. 0 updates every element every step (the textbook method).
    /// Default 0.01: the implicit Jacobian lags the rotations by at most 0.6 degrees, well
    /// inside the error of dropping the derivative of `R` that every corotational method
    /// makes. At most a quarter of the elements are updated in one step (the ones turned
    /// longest ago first), so a step never pays a whole re-assembly; under fast rotation of
    /// the whole body the rest follow within a few steps.
    pub stiffness_update_angle: f64,
    /// Prefactored corotational model: iterations per step (each one element loop and three
    /// scalar solves). Default 1.
    #[serde(default = "default_prefactored_iterations")]
    pub prefactored_iterations: u32,
    /// Time integrator. Default backward Euler.
    #[serde(default)]
    pub integrator: FemIntegrator,
    /// Corotational (CG): a warm-started element rotation is refined (up to
    /// `rotation_iterations` updates a step) until its correction angle is below this many
    /// radians. The elastic forces, and so the state stepping settles in, are off the true
    /// corotational forces by about this angle times the stress: with 1e-4 a body at rest
    /// sat 1e-5 to 4e-5 (relative) away from [`FemBody::solve_static`]. Default 1e-10 (see
    /// [`DEFAULT_ROTATION_TOLERANCE`]): stepping converges to the static solution within
    /// 1e-8 (relative); a converged element takes no update, so the cost in motion is a
    /// few more element updates (docs/solvers.md quotes the measured change).
    #[serde(default = "default_rotation_tolerance")]
    pub rotation_tolerance: f64,
}

pub(super) fn default_prefactored_iterations() -> u32 {
    1
}

pub(super) fn default_rotation_tolerance() -> f64 {
    DEFAULT_ROTATION_TOLERANCE
}

impl FemConfig {
    /// Corotational FEM with the paper's material parameters (its damping taken as the
    /// mass-proportional Rayleigh coefficient) and time step.
    pub fn paper(params: &FemParams, dt: f64) -> Self {
        FemConfig {
            model: FemModel::Corotational,
            young_modulus: params.young_modulus,
            poisson_ratio: params.poisson_ratio,
            mass: MassSpec::Total(params.mass),
            mass_damping: params.damping,
            stiffness_damping: 0.0,
            dt,
            gravity: Vec3::zeros(),
            cg_tolerance: 1e-4,
            cg_max_iterations: 20,
            cg_must_converge: false,
            rotation_iterations: 1,
            stiffness_update_angle: 0.01,
            prefactored_iterations: default_prefactored_iterations(),
            integrator: FemIntegrator::BackwardEuler,
            rotation_tolerance: DEFAULT_ROTATION_TOLERANCE,
        }
    }

    /// The step length of the backward-Euler system the integrator solves: `dt` for backward
    /// Euler, `2 dt / 3` for BDF2.
    pub fn system_dt(&self) -> f64 {
        match self.integrator {
            FemIntegrator::BackwardEuler => self.dt,
            FemIntegrator::Bdf2 => 2.0 * self.dt / 3.0,
        }
    }

    /// Checks every field; the error names it.
    pub fn validate(&self) -> Result<(), FemError> {
        let bad =
            |field: &'static str, message: String| Err(FemError::InvalidConfig { field, message });
        let pos = |v: f64| v.is_finite() && v > 0.0;
        let nonneg = |v: f64| v.is_finite() && v >= 0.0;
        if !pos(self.young_modulus) {
            return bad(
                "young_modulus",
                format!("must be positive, found {}", self.young_modulus),
            );
        }
        if !(self.poisson_ratio > -1.0 && self.poisson_ratio < 0.5) {
            return bad(
                "poisson_ratio",
                format!("must be in (-1, 0.5), found {}", self.poisson_ratio),
            );
        }
        match self.mass {
            MassSpec::Total(m) if !pos(m) => {
                return bad("mass", format!("total mass must be positive, found {m}"));
            }
            MassSpec::Density(d) if !pos(d) => {
                return bad("mass", format!("density must be positive, found {d}"));
            }
            _ => {}
        }
        if !nonneg(self.mass_damping) {
            return bad(
                "mass_damping",
                format!("must be >= 0, found {}", self.mass_damping),
            );
        }
        if !nonneg(self.stiffness_damping) {
            return bad(
                "stiffness_damping",
                format!("must be >= 0, found {}", self.stiffness_damping),
            );
        }
        if !pos(self.dt) {
            return bad("dt", format!("must be positive, found {}", self.dt));
        }
        if !self.gravity.iter().all(|g| g.is_finite()) {
            return bad(
                "gravity",
                format!("must be finite, found {:?}", self.gravity),
            );
        }
        if !pos(self.cg_tolerance) {
            return bad(
                "cg_tolerance",
                format!("must be positive, found {}", self.cg_tolerance),
            );
        }
        if self.cg_max_iterations == 0 {
            return bad("cg_max_iterations", "must be at least 1".into());
        }
        if self.prefactored_iterations == 0 {
            return bad("prefactored_iterations", "must be at least 1".into());
        }
        if self.model == FemModel::CorotationalPrefactored && self.integrator == FemIntegrator::Bdf2
        {
            return bad(
                "integrator",
                "must be BackwardEuler for the corotational-prefactored model (its inexact \
                 iterations extrapolated by BDF2 grew energy fivefold in the Young x1000 hard \
                 case)"
                    .into(),
            );
        }
        if self.model == FemModel::CorotationalPrefactored && self.stiffness_damping != 0.0 {
            return bad(
                "stiffness_damping",
                format!(
                    "must be 0 for the corotational-prefactored model (it damps by mass only), found {}",
                    self.stiffness_damping
                ),
            );
        }
        if !pos(self.rotation_tolerance) {
            return bad(
                "rotation_tolerance",
                format!("must be positive, found {}", self.rotation_tolerance),
            );
        }
        if !nonneg(self.stiffness_update_angle) {
            return bad(
                "stiffness_update_angle",
                format!("must be >= 0, found {}", self.stiffness_update_angle),
            );
        }
        Ok(())
    }
}
