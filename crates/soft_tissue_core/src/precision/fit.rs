//! Fitting the cage to the precise level's surface (positions and velocities, by least
//! squares through `cage::fit`), as a down-switch and the rest test use it.

use super::*;

/// Newton steps of a fit made within a step (the rest check, a down-switch): bounded, and
/// a fit stopped there goes on from where it stopped at the next check.
pub(super) const STEP_NEWTON_STEPS: u32 = 12;

/// Newton steps of a fit asked for outside the step ([`LeveledModel::fit_cage_now`]): on the
/// cylinder's 128-vertex fitted cage under `poke-a` every one of the 500 fits converges
/// (the slowest within 69 iterations, warm-started; 494 and 492 of 500 within 40 Newton
/// steps, against FEM and the MSD).
pub(super) const NOW_NEWTON_STEPS: u32 = 100;

impl LeveledModel {
    /// The rotation of the rigid motion that best maps the rest cage onto `cage` (Kabsch).
    pub(super) fn cage_rotation(&self, cage: &[Vec3]) -> UnitQuaternion<f64> {
        crate::fem::rotation::best_rotation(self.cage.cage().vertices(), cage)
    }

    /// Iterates the cage fit on the precise body's current surface, at most `max_iterations`
    /// times from the last fit, and returns the largest surface distance of the fit (the cage
    /// level's error if the body dropped now).
    pub(super) fn fit_cage(
        &mut self,
        max_iterations: u32,
        newton_steps: u32,
    ) -> Result<f64, PrecisionError> {
        let coords = self.cage.coordinates().clone();
        self.fit.set_newton_steps(newton_steps);
        let points = self.precise.model().positions();
        self.last_fit = self.fit.positions(
            &coords,
            points,
            &mut self.fit_cage,
            FIT_TOLERANCE * self.smallest,
            max_iterations,
        );
        let residual = self.fit.residual(&coords, &self.fit_cage, points);
        if !residual.is_finite() {
            // Start the next fit from the cage, not from a broken estimate.
            self.fit_cage.copy_from_slice(self.cage.cage_positions());
            return Err(PrecisionError::SingularFit);
        }
        Ok(residual)
    }

    /// Iterates the cage velocity fit (linearised at the fitted positions) from the last one.
    pub(super) fn fit_velocities(&mut self, max_iterations: u32) -> FitReport {
        let coords = self.cage.coordinates().clone();
        let dt = self.settings.dt;
        self.fit.velocities(
            &coords,
            &self.fit_cage,
            self.precise.model().velocities(),
            &mut self.fit_velocity,
            1e-3 * dt,
            FIT_TOLERANCE * self.smallest / dt,
            max_iterations,
        )
    }

    /// The last cage fit: iterations, last change, whether it converged.
    pub fn last_fit(&self) -> FitReport {
        self.last_fit
    }

    /// The cage level's current error estimate: the largest distance of a surface vertex
    /// from the cage's best fit, as of the last fit (every step at rest at the precise level,
    /// and at each down-switch).
    pub fn cage_residual(&self) -> f64 {
        self.residual
    }

    /// Fits the cage to the precise level's current surface now, as a down-switch would
    /// (warm-started from the last fit), and returns the largest distance between a surface
    /// vertex and the fitted cage's image of it: how close a cage of this shape can follow
    /// the precise state, whatever its dynamics. Reads the precise level's state at either
    /// level (at the cage level that is the state it left, or was handed at the last switch).
    pub fn fit_cage_now(&mut self) -> Result<f64, PrecisionError> {
        self.fit_cage(MAX_FIT_ITERATIONS, NOW_NEWTON_STEPS)
    }
}
