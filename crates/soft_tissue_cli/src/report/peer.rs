//! Side by side with rapier3d 0.36's FEM soft bodies on the same tetrahedral mesh, material,
//! masses, fixed nodes, load and time step.
//!
//! The error of both codes is measured against a reference neither defines: the closed-form
//! static solution of linear elasticity for a prismatic bar clamped at one end under a uniform
//! body force along its axis (Poisson ratio 0),
//!
//! `u(s) = (rho g / E) (L s - s^2 / 2)` along the axis, nothing across it,
//!
//! with `s` the distance from the clamped section, `L` the free length, `rho` the density
//! (the body's mass over its volume) and `g` the body force per unit mass. With Poisson ratio
//! 0 the stress is uniaxial, the lateral faces carry nothing and the clamp restrains no
//! lateral contraction, so the solution is exact for the continuum; a corotational material
//! gives the same one (the deformation is a stretch without rotation, where corotational and
//! linear stresses coincide). The bottom 10 % of the bar is held and the clamped section is
//! the top of that slab. A linear-tetrahedron mesh cannot hold the quadratic field exactly,
//! nor a held slab a clamped plane, and a real mesh is not exactly a prism (the cylinder's rim
//! nodes sit a little off its end faces): the static linear-FEM solution on the same mesh
//! shows that floor. The liver has no closed form: it runs the sideways load for the step
//! times and the deflections only.

use std::path::Path;
use std::time::Instant;

use soft_tissue_core::Vec3;
use soft_tissue_core::boundary::Boundary;
use soft_tissue_core::fem::{FemBody, FemConfig, FemModel};
use soft_tissue_core::material::FemParams;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::io::read_tet_mesh;
use soft_tissue_core::state::NodalModel;
use soft_tissue_peers::{PeerSetup, rapier_fem};

use super::{Res, median};

/// How a mesh is held and loaded in the side-by-side.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Protocol {
    /// The bottom 10 % along its longest axis held, pulled along that axis by a body force,
    /// Poisson ratio 0: the closed-form bar (for prismatic meshes).
    AxialBar,
    /// Bottom 10 % along y held, a body force along x (a cantilever under its own weight);
    /// no closed form.
    Sideways,
}

/// The closed-form reference of an [`Protocol::AxialBar`] row.
#[derive(Debug, Clone)]
pub(super) struct ClosedForm {
    /// The closed form's displacement of the free end, length.
    pub tip: f64,
    /// Largest node distance from the closed form at the end, % of `tip`.
    pub ours_error_pct: f64,
    pub rapier_error_pct: f64,
    /// The same for the static linear-FEM solution on this mesh: what linear tetrahedra on
    /// this mesh can reach at best (the discretisation error).
    pub mesh_floor_pct: f64,
    /// The free end's mean axial displacement against the closed form's, % of `tip`: ours,
    /// rapier's, and the static linear-FEM solution's.
    pub ours_tip_error_pct: f64,
    pub rapier_tip_error_pct: f64,
    pub floor_tip_error_pct: f64,
}

/// What the side-by-side measured on one mesh.
#[derive(Debug, Clone)]
pub(super) struct PeerRow {
    pub mesh: String,
    pub protocol: Protocol,
    pub nodes: usize,
    pub tets: usize,
    pub dt: f64,
    pub steps: usize,
    /// Body force per unit mass, length / time^2 (along the load's axis).
    pub load: f64,
    pub ours_median_us: f64,
    pub rapier_median_us: f64,
    /// Mean displacement along the load of the far-end nodes at the end, length.
    pub ours_tip: f64,
    pub rapier_tip: f64,
    /// The closed form, for the rows that have one.
    pub closed_form: Option<ClosedForm>,
    /// Largest node speed at the end (shows whether the body has settled).
    pub ours_speed: f64,
    pub rapier_speed: f64,
}

/// Mean displacement along `axis` of the nodes `far`.
fn tip(mesh: &TetMesh, x: &[Vec3], far: &[usize], axis: usize) -> f64 {
    far.iter()
        .map(|&i| x[i][axis] - mesh.positions()[i][axis])
        .sum::<f64>()
        / far.len().max(1) as f64
}

fn max_distance(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, f64::max)
}

/// The closed-form positions of the axial bar: every node moved along `axis` by
/// `(rho g / E) (L s - s^2 / 2)`, `s` its distance from the clamped face at `base`.
pub(super) fn bar_positions(
    rest: &[Vec3],
    axis: usize,
    base: f64,
    length: f64,
    rho_g_over_e: f64,
) -> Vec<Vec3> {
    rest.iter()
        .map(|p| {
            let s = (p[axis] - base).clamp(0.0, length);
            let mut q = *p;
            q[axis] += rho_g_over_e * (length * s - 0.5 * s * s);
            q
        })
        .collect()
}

/// Our FEM on `mesh`: returns the body after `steps` steps and the step times, us.
fn ours(
    mesh: &TetMesh,
    params: &FemParams,
    model: FemModel,
    dt: f64,
    gravity: Vec3,
    boundary: &Boundary,
    steps: usize,
) -> Res<(FemBody, Vec<f64>)> {
    let mut c = FemConfig::paper(params, dt);
    c.model = model;
    c.gravity = gravity;
    let mut body = FemBody::new(mesh, c, boundary)?;
    let mut times = Vec::with_capacity(steps);
    for _ in 0..steps {
        let t = Instant::now();
        body.step()?;
        times.push(t.elapsed().as_secs_f64() * 1e6);
    }
    Ok((body, times))
}

/// The index of the longest axis of the mesh's bounding box.
fn longest_axis(mesh: &TetMesh) -> usize {
    let b = mesh.bbox();
    let d = b.max - b.min;
    (0..3).max_by(|&i, &j| d[i].total_cmp(&d[j])).unwrap_or(1)
}

/// Runs the side-by-side on one mesh file (relative to `assets`) for `duration` seconds.
pub(super) fn compare(
    assets: &Path,
    file: &str,
    params: &FemParams,
    dt: f64,
    duration: f64,
    protocol: Protocol,
) -> Res<PeerRow> {
    let path = assets.join(file);
    let mesh = read_tet_mesh(&path)
        .map_err(|e| format!("{}: {e}", path.display()))?
        .mesh;
    let b = mesh.bbox();
    let steps = (duration / dt).round() as usize;
    let mut params = *params;
    // The axis the load acts along, the held nodes, the far end and the load.
    let (axis, boundary, far, load, closed) = match protocol {
        Protocol::AxialBar => {
            params.poisson_ratio = 0.0;
            let axis = longest_axis(&mesh);
            // The bottom 10 % held: the closed form's clamp is the top of that slab. (Held
            // on its end face alone, a mesh whose rim nodes sit a little off that face, as
            // the cylinder's do, is clamped on part of its section only.)
            let held = 0.1;
            let extent = b.max[axis] - b.min[axis];
            let base = b.min[axis] + held * extent;
            let length = b.max[axis] - base;
            let boundary = Boundary::fixed_below(mesh.positions(), axis, held);
            let far: Vec<usize> = (0..mesh.node_count())
                .filter(|&i| mesh.positions()[i][axis] >= b.max[axis] - 1e-9 * extent)
                .collect();
            // The load puts the free end 1 % of the length from rest: rho g L^2 / (2 E).
            let rho = params.mass / mesh.volume();
            let load = 0.02 * params.young_modulus / (rho * length);
            let k = rho * load / params.young_modulus;
            let reference = bar_positions(mesh.positions(), axis, base, length, k);
            (
                axis,
                boundary,
                far,
                load,
                Some((reference, k * length * length / 2.0)),
            )
        }
        Protocol::Sideways => {
            let height = b.max.y - b.min.y;
            let far: Vec<usize> = (0..mesh.node_count())
                .filter(|&i| mesh.positions()[i].y >= b.max.y - 0.05 * height)
                .collect();
            let boundary = Boundary::fixed_below(mesh.positions(), 1, 0.1);
            // Size the load: our linear FEM's static deflection is linear in it.
            let probe = 9.81;
            let mut c = FemConfig::paper(&params, dt);
            c.model = FemModel::Linear;
            c.gravity = Vec3::new(probe, 0.0, 0.0);
            let mut settled = FemBody::new(&mesh, c, &boundary)?;
            settled.solve_static(1e-10, 50)?;
            let d1 = tip(&mesh, settled.positions(), &far, 0);
            if !(d1.is_finite() && d1.abs() > 0.0) {
                return Err(format!("{file}: no deflection under the probe load").into());
            }
            (0, boundary, far, probe * 0.05 * height / d1.abs(), None)
        }
    };
    let mut gravity = Vec3::zeros();
    gravity[axis] = load;
    let (body, times) = ours(
        &mesh,
        &params,
        FemModel::Corotational,
        dt,
        gravity,
        &boundary,
        steps,
    )?;
    let setup = PeerSetup {
        young_modulus: params.young_modulus,
        poisson_ratio: params.poisson_ratio,
        damping_ratio: 1.0,
        masses: body.masses().to_vec(),
        fixed: boundary
            .resolve(mesh.node_count())?
            .0
            .iter()
            .enumerate()
            .filter(|(_, m)| m.iter().all(|&a| a))
            .map(|(i, _)| i)
            .collect(),
        gravity,
        dt,
    };
    let peer = rapier_fem(&mesh, &setup, steps)?;
    let closed_form = match closed {
        Some((reference, tip_exact)) => {
            let mut c = FemConfig::paper(&params, dt);
            c.model = FemModel::Linear;
            c.gravity = gravity;
            let mut floor = FemBody::new(&mesh, c, &boundary)?;
            floor.solve_static(1e-12, 50)?;
            let pct = |x: &[Vec3]| 100.0 * max_distance(x, &reference) / tip_exact;
            let tip_pct =
                |x: &[Vec3]| 100.0 * (tip(&mesh, x, &far, axis) - tip_exact).abs() / tip_exact;
            Some(ClosedForm {
                tip: tip_exact,
                ours_error_pct: pct(body.positions()),
                rapier_error_pct: pct(&peer.positions),
                mesh_floor_pct: pct(floor.positions()),
                ours_tip_error_pct: tip_pct(body.positions()),
                rapier_tip_error_pct: tip_pct(&peer.positions),
                floor_tip_error_pct: tip_pct(floor.positions()),
            })
        }
        None => None,
    };
    Ok(PeerRow {
        mesh: file.to_string(),
        protocol,
        nodes: mesh.node_count(),
        tets: mesh.tet_count(),
        dt,
        steps,
        load,
        ours_median_us: median(&times).unwrap_or(0.0),
        rapier_median_us: median(&peer.step_us).unwrap_or(0.0),
        ours_tip: tip(&mesh, body.positions(), &far, axis),
        rapier_tip: tip(&mesh, &peer.positions, &far, axis),
        closed_form,
        ours_speed: body.max_speed(),
        rapier_speed: peer.max_speed,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The closed form satisfies its own equations: zero at the clamp, zero strain at the
    /// free end (no traction), and `E u'' + rho g = 0` in between (central differences of a
    /// quadratic are exact).
    #[test]
    fn the_bar_closed_form_solves_the_axial_equilibrium() {
        let (length, k) = (2.0, 0.003);
        let at = |s: f64| bar_positions(&[Vec3::new(0.5, s, -0.25)], 1, 0.0, length, k)[0];
        let u = |s: f64| at(s).y - s;
        assert_eq!(u(0.0), 0.0);
        let h = 1e-3;
        assert!(((u(length) - u(length - h)) / h).abs() < k * h);
        for s in [0.3, 1.0, 1.7] {
            let second = (u(s + h) - 2.0 * u(s) + u(s - h)) / (h * h);
            assert!((second + k).abs() < 1e-6 * k.max(1.0), "{second}");
            assert_eq!(at(s).x, 0.5);
            assert_eq!(at(s).z, -0.25);
        }
        assert!((u(length) - k * length * length / 2.0).abs() < 1e-15);
    }
}
