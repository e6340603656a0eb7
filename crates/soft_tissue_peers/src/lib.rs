//! Peers of the soft-tissue solvers, driven on our meshes and loads so the report can put
//! them side by side: rapier3d 0.36's FEM soft bodies (corotational cells, implicit Euler).
//!
//! Kept in its own crate: the plugin and the core never depend on it, only the CLI's `report`.
//! Rapier works in `f32` with glam vectors; the conversion from the core's `f64` nalgebra
//! vectors happens here and nowhere else.

use std::time::Instant;

use rapier3d::prelude::{
    PhysicsWorld, SoftBodyBuilder, SoftBodyCellModel, SoftBodyMaterial, SoftBodySolver, Vector,
};
use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::TetMesh;

/// A bad input to a peer run, naming what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PeerError {
    /// The masses do not match the mesh's nodes.
    #[error("{masses} masses given for a mesh of {nodes} nodes")]
    Masses {
        /// Masses given.
        masses: usize,
        /// Mesh nodes.
        nodes: usize,
    },
    /// A fixed node index past the mesh's nodes.
    #[error("fixed node {node} out of range (mesh has {nodes} nodes)")]
    FixedNode {
        /// The index.
        node: usize,
        /// Mesh nodes.
        nodes: usize,
    },
    /// A non-finite or non-positive setting.
    #[error("bad setting {name} = {value}")]
    Setting {
        /// Setting name.
        name: &'static str,
        /// Its value.
        value: f64,
    },
    /// The peer's state left the finite numbers.
    #[error("rapier3d's state is not finite after step {step}")]
    NotFinite {
        /// Step at which it was seen.
        step: usize,
    },
}

/// Material and load of a peer run, in the core's units.
#[derive(Debug, Clone, PartialEq)]
pub struct PeerSetup {
    /// Young's modulus, force / length^2.
    pub young_modulus: f64,
    /// Poisson ratio.
    pub poisson_ratio: f64,
    /// Rapier's elastic damping ratio of the cells (it has no Rayleigh damping).
    pub damping_ratio: f64,
    /// Per-node masses (our lumped masses, so both see the same inertia and weight).
    pub masses: Vec<f64>,
    /// Nodes held fixed.
    pub fixed: Vec<usize>,
    /// Body force per unit mass, length / time^2.
    pub gravity: Vec3,
    /// Time step, seconds.
    pub dt: f64,
}

/// What a peer run measured.
#[derive(Debug, Clone, PartialEq)]
pub struct PeerRun {
    /// Node positions after the last step.
    pub positions: Vec<Vec3>,
    /// Wall-clock time of each step, us.
    pub step_us: Vec<f64>,
    /// Largest node speed after the last step.
    pub max_speed: f64,
}

fn to_rapier(v: Vec3) -> Vector {
    Vector::new(v.x as f32, v.y as f32, v.z as f32)
}

fn from_rapier(v: Vector) -> Vec3 {
    Vec3::new(f64::from(v.x), f64::from(v.y), f64::from(v.z))
}

/// Runs `steps` steps of rapier3d's FEM soft body (corotational cells, `SoftBodySolver::Fem`)
/// on `mesh` under `setup`: no colliders, no sleeping, one solver iteration per step (the
/// implicit solve is the elasticity; more iterations only refine contacts and joints).
pub fn rapier_fem(mesh: &TetMesh, setup: &PeerSetup, steps: usize) -> Result<PeerRun, PeerError> {
    let nodes = mesh.node_count();
    if setup.masses.len() != nodes {
        return Err(PeerError::Masses {
            masses: setup.masses.len(),
            nodes,
        });
    }
    if let Some(&node) = setup.fixed.iter().find(|&&i| i >= nodes) {
        return Err(PeerError::FixedNode { node, nodes });
    }
    for (name, value, ok) in [
        (
            "young_modulus",
            setup.young_modulus,
            setup.young_modulus > 0.0,
        ),
        (
            "poisson_ratio",
            setup.poisson_ratio,
            (0.0..0.5).contains(&setup.poisson_ratio),
        ),
        (
            "damping_ratio",
            setup.damping_ratio,
            setup.damping_ratio >= 0.0,
        ),
        ("dt", setup.dt, setup.dt > 0.0),
    ] {
        if !(value.is_finite() && ok) {
            return Err(PeerError::Setting { name, value });
        }
    }
    let mut world = PhysicsWorld::new();
    world.gravity = to_rapier(setup.gravity);
    world.integration_parameters.dt = setup.dt as f32;
    world.integration_parameters.num_solver_iterations = 1;
    let positions: Vec<Vector> = mesh.positions().iter().map(|&p| to_rapier(p)).collect();
    let builder = SoftBodyBuilder::new(positions)
        .cells(mesh.tets().to_vec())
        .cell_model(SoftBodyCellModel::Corotational)
        .material(SoftBodyMaterial {
            young_modulus: setup.young_modulus as f32,
            poisson_ratio: setup.poisson_ratio as f32,
            elastic_damping_ratio: setup.damping_ratio as f32,
            ..Default::default()
        })
        .solver(SoftBodySolver::Fem)
        .masses(setup.masses.iter().map(|&m| m as f32).collect())
        .pinned_particles(setup.fixed.iter().map(|&i| i as u32))
        .no_surface_collider()
        .can_sleep(false);
    let handle = world.insert_soft_body(builder);
    let mut step_us = Vec::with_capacity(steps);
    for step in 0..steps {
        let t = Instant::now();
        world.step();
        step_us.push(t.elapsed().as_secs_f64() * 1e6);
        let body = &world.soft_bodies[handle];
        if step % 50 == 0 && !body.particle_position(0).is_finite() {
            return Err(PeerError::NotFinite { step });
        }
    }
    let body = &world.soft_bodies[handle];
    let positions: Vec<Vec3> = (0..nodes)
        .map(|i| from_rapier(body.particle_position(i)))
        .collect();
    if positions.iter().any(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(PeerError::NotFinite { step: steps });
    }
    let max_speed = body
        .particles()
        .iter()
        .map(|p| f64::from(p.velocity().length()))
        .fold(0.0, f64::max);
    Ok(PeerRun {
        positions,
        step_us,
        max_speed,
    })
}
