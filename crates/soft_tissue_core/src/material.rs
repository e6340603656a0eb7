//! Physical parameters of the precise and cheap levels, as the paper gives them.
//!
//! The paper's scenes are unit-free: lengths in scene units (its cylinder is 1.24 wide and
//! 1.72 tall), masses in mass units, time in seconds. Any consistent unit system works; the
//! documentation of each field names the dimension.

use serde::{Deserialize, Serialize};

/// Linear-elastic tetrahedral FEM parameters (paper section III-B).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "bevy_reflect", derive(bevy_reflect::Reflect))]
pub struct FemParams {
    /// Young's modulus, force / length^2.
    pub young_modulus: f64,
    /// Poisson ratio, dimensionless, in (-1, 0.5).
    pub poisson_ratio: f64,
    /// Total mass of the body, mass units (lumped onto the nodes by volume).
    pub mass: f64,
    /// Damping coefficient, 1 / time (mass-proportional Rayleigh damping).
    pub damping: f64,
}

/// Mass-spring-damper parameters (paper section III-C, eq. 6-7).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "bevy_reflect", derive(bevy_reflect::Reflect))]
pub struct MsdParams {
    /// Spring stiffness, force / length.
    pub stiffness: f64,
    /// Total mass of the body, mass units.
    pub mass: f64,
    /// Per-node damping coefficient gamma, force * time / length.
    pub damping: f64,
}

/// Default parameters of the MSD that drives a Green-coordinate cage (paper section IV:
/// stiffness 50, mass 20, damping 0.3 in both scenes).
pub const PAPER_CAGE_MSD: MsdParams = MsdParams {
    stiffness: 50.0,
    mass: 20.0,
    damping: 0.3,
};

impl FemParams {
    /// Checks the ranges; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        positive("young_modulus", self.young_modulus)?;
        positive("mass", self.mass)?;
        non_negative("damping", self.damping)?;
        if !(self.poisson_ratio > -1.0 && self.poisson_ratio < 0.5) {
            return Err(format!(
                "poisson_ratio must be in (-1, 0.5), found {}",
                self.poisson_ratio
            ));
        }
        Ok(())
    }
}

impl MsdParams {
    /// Checks the ranges; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        positive("stiffness", self.stiffness)?;
        positive("mass", self.mass)?;
        non_negative("damping", self.damping)
    }
}

fn positive(name: &str, v: f64) -> Result<(), String> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(format!("{name} must be positive and finite, found {v}"))
    }
}

fn non_negative(name: &str, v: f64) -> Result<(), String> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(format!("{name} must be non-negative and finite, found {v}"))
    }
}
