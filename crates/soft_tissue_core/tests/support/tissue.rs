//! Scenes several tests burn: a block of liver-like tissue, fixed below, heated.

use std::sync::Arc;

use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::contact::ContactConfig;
use soft_tissue_core::heat::{HeatBoundary, HeatParams};
use soft_tissue_core::material::{FemParams, MsdParams};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::precision::BodySettings;
use soft_tissue_core::world::{SoftTissueWorld, WorldBody, WorldConfig};

/// Liver's density, kg/m^3.
pub const LIVER_DENSITY: f64 = 1079.0;

/// A world stepping `dt`, its contact scaled to `scale`, holding one body `name` of `mesh`
/// (metres): soft tissue (Young's modulus 20 kPa, Poisson's ratio 0.45, liver's density),
/// its bottom layer of nodes fixed, its heat by `heat` with an insulated surface.
pub fn heated_block(
    name: &str,
    mesh: TetMesh,
    heat: HeatParams,
    dt: f64,
    scale: f64,
) -> SoftTissueWorld {
    let fem = FemParams {
        young_modulus: 2.0e4,
        poisson_ratio: 0.45,
        mass: LIVER_DENSITY * mesh.volume(),
        damping: 1.0,
    };
    let msd = MsdParams {
        stiffness: 100.0,
        mass: fem.mass,
        damping: 0.1,
    };
    let mut s = BodySettings::new(fem, msd, dt);
    s.boundary = Boundary::fixed_below(mesh.positions(), 1, 0.01);
    let body = WorldBody::new(
        name,
        Arc::new(mesh),
        s,
        Some((heat, HeatBoundary::insulated())),
    )
    .unwrap();
    let mut w = SoftTissueWorld::new(WorldConfig {
        dt,
        contact: ContactConfig::for_scale(scale),
    })
    .unwrap();
    w.add_body(body).unwrap();
    w
}
