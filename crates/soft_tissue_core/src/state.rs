//! Checks and measures shared by the per-node state of the solvers (FEM and MSD bodies).

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
pub(crate) fn first_non_finite_input(
    f_ext: &[Vec3],
    x: &[Vec3],
    v: &[Vec3],
) -> Option<(&'static str, usize)> {
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

/// Largest speed.
pub(crate) fn max_speed(v: &[Vec3]) -> f64 {
    v.iter().map(|v| v.norm()).fold(0.0, f64::max)
}
