//! Side by side with rapier3d 0.36's FEM soft bodies on the same tetrahedral mesh, material,
//! masses, fixed nodes, load and time step.
//!
//! The load: the body's bottom 10 % (along y) held fixed and a sideways body force (gravity
//! along x), so the body bends like a cantilever under its own weight. Its size is chosen per
//! mesh so our linear FEM's static tip deflection is 5 % of the body's height (a visible bend,
//! inside the small-strain range where the two corotational codes should agree). Each code
//! runs the same number of steps from rest; at the end the shape is compared with our
//! corotational FEM at a tenth of the step and a tight CG tolerance (the fine reference).

use std::path::Path;
use std::time::Instant;

use soft_tissue_core::Vec3;
use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::fem::{FemBody, FemConfig, FemModel};
use soft_tissue_core::material::FemParams;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::io::read_tet_mesh;
use soft_tissue_core::state::NodalBody;
use soft_tissue_peers::{PeerSetup, rapier_fem};

use super::{Res, median};

/// What the side-by-side measured on one mesh.
#[derive(Debug, Clone)]
pub(super) struct PeerRow {
    pub mesh: String,
    pub nodes: usize,
    pub tets: usize,
    pub dt: f64,
    pub steps: usize,
    /// Sideways body force, length / time^2.
    pub load: f64,
    pub ours_median_us: f64,
    pub rapier_median_us: f64,
    /// Mean sideways displacement of the top 5 % nodes at the end, length.
    pub ours_deflection: f64,
    pub rapier_deflection: f64,
    pub reference_deflection: f64,
    /// Largest node distance from the reference at the end, % of the smallest dimension.
    pub ours_error_pct: f64,
    pub rapier_error_pct: f64,
    /// Largest node speed at the end (shows whether the body has settled).
    pub ours_speed: f64,
    pub rapier_speed: f64,
}

fn tip_deflection(mesh: &TetMesh, x: &[Vec3], top: &[usize]) -> f64 {
    top.iter()
        .map(|&i| x[i].x - mesh.positions()[i].x)
        .sum::<f64>()
        / top.len().max(1) as f64
}

fn max_distance(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, f64::max)
}

/// Our FEM on `mesh`: returns the body after `steps` steps and the step times, us.
fn ours(
    mesh: &TetMesh,
    params: &FemParams,
    model: FemModel,
    dt: f64,
    load: f64,
    steps: usize,
    cg: Option<(f64, u32)>,
) -> Res<(FemBody, Vec<f64>)> {
    let mut c = FemConfig::paper(params, dt);
    c.model = model;
    c.gravity = Vec3::new(load, 0.0, 0.0);
    let boundary = Boundary::fixed_below(mesh.positions(), 1, 0.1);
    let mut body = FemBody::new(mesh, c, &boundary)?;
    if let Some((tol, cap)) = cg {
        body.set_cg(tol, cap)?;
    }
    let mut times = Vec::with_capacity(steps);
    for _ in 0..steps {
        let t = Instant::now();
        body.step()?;
        times.push(t.elapsed().as_secs_f64() * 1e6);
    }
    Ok((body, times))
}

/// Runs the side-by-side on one mesh file (relative to `assets`) for `duration` seconds.
pub(super) fn compare(
    assets: &Path,
    file: &str,
    params: &FemParams,
    dt: f64,
    duration: f64,
) -> Res<PeerRow> {
    let path = assets.join(file);
    let mesh = read_tet_mesh(&path)
        .map_err(|e| format!("{}: {e}", path.display()))?
        .mesh;
    let b = mesh.bbox();
    let height = b.max.y - b.min.y;
    let top: Vec<usize> = (0..mesh.node_count())
        .filter(|&i| mesh.positions()[i].y >= b.max.y - 0.05 * height)
        .collect();
    let steps = (duration / dt).round() as usize;
    // Size the load: our linear FEM's static deflection is linear in it. Implicit Euler with
    // a long step settles to the static solution in a few steps.
    let probe = 9.81;
    let (settled, _) = ours(&mesh, params, FemModel::Linear, 1.0, probe, 200, None)?;
    let d1 = tip_deflection(&mesh, settled.positions(), &top);
    if !(d1.is_finite() && d1.abs() > 0.0) {
        return Err(format!("{file}: no deflection under the probe load").into());
    }
    let load = probe * 0.05 * height / d1.abs();

    let (fine, _) = ours(
        &mesh,
        params,
        FemModel::Corotational,
        dt / 10.0,
        load,
        steps * 10,
        Some((1e-8, 200)),
    )?;
    let (body, times) = ours(&mesh, params, FemModel::Corotational, dt, load, steps, None)?;
    let setup = PeerSetup {
        young_modulus: params.young_modulus,
        poisson_ratio: params.poisson_ratio,
        damping_ratio: 1.0,
        masses: body.masses().to_vec(),
        fixed: Boundary::fixed_below(mesh.positions(), 1, 0.1)
            .resolve(mesh.node_count())?
            .0
            .iter()
            .enumerate()
            .filter(|(_, m)| m.iter().all(|&a| a))
            .map(|(i, _)| i)
            .collect(),
        gravity: Vec3::new(load, 0.0, 0.0),
        dt,
    };
    let peer = rapier_fem(&mesh, &setup, steps)?;
    let scale = mesh.bbox().smallest_dimension();
    Ok(PeerRow {
        mesh: file.to_string(),
        nodes: mesh.node_count(),
        tets: mesh.tet_count(),
        dt,
        steps,
        load,
        ours_median_us: median(&times).unwrap_or(0.0),
        rapier_median_us: median(&peer.step_us).unwrap_or(0.0),
        ours_deflection: tip_deflection(&mesh, body.positions(), &top),
        rapier_deflection: tip_deflection(&mesh, &peer.positions, &top),
        reference_deflection: tip_deflection(&mesh, fine.positions(), &top),
        ours_error_pct: 100.0 * max_distance(body.positions(), fine.positions()) / scale,
        rapier_error_pct: 100.0 * max_distance(&peer.positions, fine.positions()) / scale,
        ours_speed: body.max_speed(),
        rapier_speed: peer.max_speed,
    })
}
