//! What the FEM validation files (`fem.rs`, `fem_time.rs`) share: the material and the
//! meshes they load.

#![allow(dead_code)] // Each test file uses part of it.

use nalgebra::{Matrix3, Rotation3};
use soft_tissue_core::Vec3;
use soft_tissue_core::fem::{FemConfig, FemIntegrator, FemModel, MassSpec};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::generate::block;

pub fn config(model: FemModel, young: f64, poisson: f64) -> FemConfig {
    FemConfig {
        model,
        young_modulus: young,
        poisson_ratio: poisson,
        mass: MassSpec::Density(1.0),
        mass_damping: 0.0,
        stiffness_damping: 0.0,
        dt: 0.01,
        gravity: Vec3::zeros(),
        cg_tolerance: 1e-10,
        cg_max_iterations: 200,
        rotation_iterations: 20,
        stiffness_update_angle: 0.0,
        prefactored_iterations: 1,
        cg_must_converge: false,
        integrator: FemIntegrator::BackwardEuler,
        rotation_tolerance: soft_tissue_core::fem::DEFAULT_ROTATION_TOLERANCE,
    }
}

pub fn cube(cells: usize) -> TetMesh {
    block(Vec3::zeros(), Vec3::repeat(1.0), [cells; 3]).unwrap()
}

pub fn on_boundary(p: &Vec3) -> bool {
    p.iter()
        .any(|&c| c.abs() < 1e-12 || (c - 1.0).abs() < 1e-12)
}

pub const MODELS: [FemModel; 2] = [FemModel::Linear, FemModel::Corotational];

/// A small symmetric strain and a 90-degree rotation about a skew axis.
pub fn strain() -> Matrix3<f64> {
    Matrix3::new(
        0.010, 0.003, -0.002, 0.003, -0.004, 0.001, -0.002, 0.001, 0.006,
    )
}

pub fn quarter_turn() -> Matrix3<f64> {
    *Rotation3::from_axis_angle(
        &nalgebra::Unit::new_normalize(Vec3::new(1.0, 2.0, -0.5)),
        std::f64::consts::FRAC_PI_2,
    )
    .matrix()
}
