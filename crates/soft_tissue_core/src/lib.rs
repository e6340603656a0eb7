//! Engine-free core of `bevy_soft_tissue`.
//!
//! Everything physical or geometric lives here, with no Bevy dependency, so it can be
//! tested headless, benchmarked from the `soft-tissue` command-line tool and reused outside
//! Bevy. The Bevy plugin (the root package) is a thin adapter over these modules.
//!
//! Modules, one concern each:
//! - [`mesh`]: tetrahedral meshes, derived topology, validation, quality, mesh files
//!   ([`mesh::io`]) and generated organ shapes ([`mesh::generate`]).
//! - [`material`]: the physical parameters of the paper's methods, with units.
//! - [`fem`]: linear and corotational tetrahedral FEM with implicit Euler.
//! - [`msd`]: mass-spring-damper bodies with RK4, symplectic and implicit Euler.
//! - [`cage`]: Green-coordinate cages (the cheap level), cage builders and cage bodies.
//! - [`precision`]: levels of precision, the switching policy and the state transfer.
//! - [`contact`]: surface colliders, broad and narrow phase, tools.
//! - [`heat`]: heat conduction and thermal damage.
//! - [`haptics`]: devices, the 1 kHz haptic thread, virtual coupling, recordings.
//! - [`world`]: `SoftTissueWorld`, the stage functions, scenes and tool scripts.
//! - [`boundary`]: fixed nodes and soft anchors shared by the solvers.
//! - [`state`]: the per-node state of every precise body and the [`NodalModel`] accessors.
//! - [`bench`](mod@bench): the benchmark load shared by the command-line tool and criterion.
//! - [`linalg`]: block-sparse matrices, sparse Cholesky (`faer`), preconditioned CG.
//! - [`scenario`]: the paper's two scenes (cylinders, organs) as serialisable data.
//!
//! Conventions: SI-like units chosen by the scene (the paper's scenes are unit-free, see
//! [`scenario`]), `f64` throughout the core, `f32` only at the render boundary in the plugin.

pub mod bench;
pub mod boundary;
pub mod cage;
pub mod calibration;
pub mod contact;
pub mod fem;
mod geometry;
pub mod haptics;
pub mod heat;
pub mod linalg;
pub mod material;
pub mod mesh;
pub mod msd;
pub mod parallel;
pub mod precision;
pub mod scenario;
pub mod stability;
pub mod state;
pub mod timing;
pub mod world;

pub use state::NodalModel;

/// Three-component vector used for positions, displacements and forces (`f64`).
pub type Vec3 = nalgebra::Vector3<f64>;
