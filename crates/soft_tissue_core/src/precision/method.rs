//! The level a body runs at and its precise method: one type each for the core, scene
//! files, the plugin and the command line.

use serde::{Deserialize, Serialize};

use crate::fem::FemModel;
use crate::msd::MsdIntegrator;

/// The level a body runs at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "bevy_reflect", derive(bevy_reflect::Reflect))]
pub enum Level {
    /// Green coordinates of an MSD-driven cage (where every body starts).
    #[default]
    Cage,
    /// The body's precise method.
    Precise,
}

/// The precise method of a body: one type for the core, scene files, the plugin and the
/// command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "bevy_reflect", derive(bevy_reflect::Reflect))]
pub enum PreciseMethod {
    /// Linear tetrahedral FEM, implicit (the paper).
    LinearFem,
    /// Corotational tetrahedral FEM, implicit: right under large rotations (the default).
    #[default]
    CorotationalFem,
    /// Corotational FEM with a constant prefactored system: a fixed, low cost per step on
    /// large meshes, numerically damped in stiff, slow motion (see
    /// [`FemModel::CorotationalPrefactored`]).
    PrefactoredFem,
    /// Mass-spring-damper, classical Runge-Kutta (the paper).
    MsdRk4,
    /// Mass-spring-damper, symplectic Euler.
    MsdSymplectic,
    /// Mass-spring-damper, linearised implicit Euler (stable at any step). Scene files
    /// written before the methods were one type name it `Msd`.
    #[serde(alias = "Msd")]
    MsdImplicit,
    /// Mass-spring-damper, linearised BDF2 (second order).
    MsdBdf2,
}

impl PreciseMethod {
    /// Every method, in display order.
    pub const ALL: [PreciseMethod; 7] = [
        PreciseMethod::LinearFem,
        PreciseMethod::CorotationalFem,
        PreciseMethod::PrefactoredFem,
        PreciseMethod::MsdRk4,
        PreciseMethod::MsdSymplectic,
        PreciseMethod::MsdImplicit,
        PreciseMethod::MsdBdf2,
    ];

    /// The FEM method of `model`.
    pub fn fem(model: FemModel) -> Self {
        match model {
            FemModel::Linear => PreciseMethod::LinearFem,
            FemModel::Corotational => PreciseMethod::CorotationalFem,
            FemModel::CorotationalPrefactored => PreciseMethod::PrefactoredFem,
        }
    }

    /// The MSD method of `integrator`.
    pub fn msd(integrator: MsdIntegrator) -> Self {
        match integrator {
            MsdIntegrator::Rk4 => PreciseMethod::MsdRk4,
            MsdIntegrator::SymplecticEuler => PreciseMethod::MsdSymplectic,
            MsdIntegrator::ImplicitEuler => PreciseMethod::MsdImplicit,
            MsdIntegrator::ImplicitBdf2 => PreciseMethod::MsdBdf2,
        }
    }

    /// The solver of the method: a FEM model or an MSD integrator.
    pub fn solver(self) -> Result<FemModel, MsdIntegrator> {
        match self {
            PreciseMethod::LinearFem => Ok(FemModel::Linear),
            PreciseMethod::CorotationalFem => Ok(FemModel::Corotational),
            PreciseMethod::PrefactoredFem => Ok(FemModel::CorotationalPrefactored),
            PreciseMethod::MsdRk4 => Err(MsdIntegrator::Rk4),
            PreciseMethod::MsdSymplectic => Err(MsdIntegrator::SymplecticEuler),
            PreciseMethod::MsdImplicit => Err(MsdIntegrator::ImplicitEuler),
            PreciseMethod::MsdBdf2 => Err(MsdIntegrator::ImplicitBdf2),
        }
    }

    /// The FEM model, for a FEM method.
    pub fn fem_model(self) -> Option<FemModel> {
        self.solver().ok()
    }

    /// The MSD integrator, for an MSD method.
    pub fn msd_integrator(self) -> Option<MsdIntegrator> {
        self.solver().err()
    }

    /// Whether the method is a FEM one.
    pub fn is_fem(self) -> bool {
        self.fem_model().is_some()
    }

    /// Short name: `fem-linear`, `fem-corotational`, `fem-corotational-prefactored`, `msd-rk4`,
    /// `msd-symplectic`, `msd-implicit`, `msd-bdf2`.
    pub fn name(self) -> &'static str {
        match self {
            PreciseMethod::LinearFem => "fem-linear",
            PreciseMethod::CorotationalFem => "fem-corotational",
            PreciseMethod::PrefactoredFem => "fem-corotational-prefactored",
            PreciseMethod::MsdRk4 => "msd-rk4",
            PreciseMethod::MsdSymplectic => "msd-symplectic",
            PreciseMethod::MsdImplicit => "msd-implicit",
            PreciseMethod::MsdBdf2 => "msd-bdf2",
        }
    }

    /// The method of a short name ([`PreciseMethod::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        PreciseMethod::ALL.into_iter().find(|m| m.name() == name)
    }
}

impl std::fmt::Display for PreciseMethod {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}
