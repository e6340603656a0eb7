//! Our corotational FEM against a peer engine's (rapier3d) on the same meshes.

use super::*;

/// Side by side with rapier3d's FEM soft bodies.
pub(super) fn peer_section(
    md: &mut String,
    js: &mut Json,
    out: &Path,
    assets: &Path,
    peers: &[Peer],
    quick: bool,
    step: &mut dyn FnMut(&str),
) -> Res<Vec<peer::PeerRow>> {
    let duration = if quick { 0.5 } else { 10.0 };
    let mut rows = Vec::new();
    for (file, params, dt, protocol) in peers {
        step(&format!("rapier3d peer: {file}"));
        rows.push(peer::compare(
            assets, file, params, *dt, duration, *protocol,
        )?);
    }
    writeln!(
        md,
        "## Side by side with rapier3d 0.36 (FEM soft bodies)\n\n\
         rapier3d 0.36.1 (`fem` feature, `SoftBodySolver::Fem`, corotational cells, f32) and \
         our corotational FEM (f64) on the same tetrahedral mesh, Young's modulus, Poisson \
         ratio, lumped masses, fixed nodes, body force and time step, {duration} s from rest. \
         Damping differs in kind (ours: mass-proportional Rayleigh from the paper's \
         parameters; rapier: its cells' damping ratio 1.0).\n\n\
         **Reference: a closed form neither code defines.** The cylinder (a prismatic bar \
         along z) is held over its bottom 10 % and pulled along its axis by a uniform body \
         force, Poisson ratio 0. Linear elasticity gives `u(s) = (rho g / E) (L s - s^2 / 2)` \
         along the axis and nothing across it (`s` from the clamped section, the top of the \
         held slab; `L` the free length; `rho` the mass over the volume): with Poisson ratio 0 \
         the stress is uniaxial, so this is exact for the continuum, and a corotational \
         material gives the same solution (a stretch without rotation). The load puts the \
         free end 1 % of the free length from rest. Error: largest node distance from the \
         closed form at the end, and the free end's mean axial displacement against the \
         closed form's, both % of the closed form's end displacement. The closed form's own \
         error is zero for the continuum; what linear tetrahedra on this mesh can reach \
         (with a held slab for a clamped plane, and the mesh's small departures from a prism) \
         is shown as the mesh floor: the static linear-FEM solution on the same mesh against \
         the closed form, same two measures. An error is meaningful only above that floor, \
         and only once both bodies have settled (speeds at the end). The goal below asks for \
         ours to be no larger on both measures.\n"
    )?;
    let table: Vec<PeerTableRow> = rows
        .iter()
        .map(|r| {
            let c = r.closed_form.as_ref();
            PeerTableRow {
                mesh: r.mesh.clone(),
                protocol: match r.protocol {
                    peer::Protocol::AxialBar => "axial bar, closed form",
                    peer::Protocol::Sideways => "sideways, bottom 10 % held (no closed form)",
                },
                nodes: r.nodes,
                tets: r.tets,
                dt: r.dt,
                steps: r.steps,
                load: r.load,
                ours_median_us: r.ours_median_us,
                rapier_median_us: r.rapier_median_us,
                ours_tip: r.ours_tip,
                rapier_tip: r.rapier_tip,
                closed_form_tip: c.map(|c| c.tip),
                ours_error_pct: c.map(|c| c.ours_error_pct),
                rapier_error_pct: c.map(|c| c.rapier_error_pct),
                mesh_floor_pct: c.map(|c| c.mesh_floor_pct),
                ours_tip_error_pct: c.map(|c| c.ours_tip_error_pct),
                rapier_tip_error_pct: c.map(|c| c.rapier_tip_error_pct),
                floor_tip_error_pct: c.map(|c| c.floor_tip_error_pct),
                ours_speed: r.ours_speed,
                rapier_speed: r.rapier_speed,
            }
        })
        .collect();
    let json_rows = write_rows(&table, md, out, "peer_rapier.csv")?;
    writeln!(md)?;
    js.insert(
        "peer_rapier".into(),
        json!({
            "reference": "closed form: prismatic bar clamped at one end under a uniform axial \
                          body force, Poisson ratio 0, u(s) = (rho g / E) (L s - s^2 / 2)",
            "rows": json_rows,
        }),
    );
    Ok(rows)
}

/// One mesh and load, both codes.
#[derive(serde::Serialize)]
struct PeerTableRow {
    mesh: String,
    protocol: &'static str,
    nodes: usize,
    tets: usize,
    dt: f64,
    steps: usize,
    load: f64,
    ours_median_us: f64,
    rapier_median_us: f64,
    ours_tip: f64,
    rapier_tip: f64,
    closed_form_tip: Option<f64>,
    ours_error_pct: Option<f64>,
    rapier_error_pct: Option<f64>,
    mesh_floor_pct: Option<f64>,
    ours_tip_error_pct: Option<f64>,
    rapier_tip_error_pct: Option<f64>,
    floor_tip_error_pct: Option<f64>,
    ours_speed: f64,
    rapier_speed: f64,
}

impl ReportRow for PeerTableRow {
    const MD_HEAD: &'static [&'static str] = &[
        "mesh",
        "load",
        "nodes / tets",
        "dt",
        "ours us",
        "rapier3d us",
        "rapier / ours time",
        "end displacement ours / rapier / closed form",
        "largest distance % ours / rapier / mesh floor",
        "end error % ours / rapier / mesh floor",
        "speed at end ours / rapier",
    ];

    fn md_cells(&self) -> Vec<String> {
        let opt = |v: Option<f64>, digits: usize| v.map_or("-".into(), |v| format!("{v:.digits$}"));
        vec![
            self.mesh.clone(),
            self.protocol.into(),
            format!("{} / {}", self.nodes, self.tets),
            self.dt.to_string(),
            format!("{:.1}", self.ours_median_us),
            format!("{:.1}", self.rapier_median_us),
            format!("{:.2}", self.rapier_median_us / self.ours_median_us),
            format!(
                "{:.4} / {:.4} / {}",
                self.ours_tip,
                self.rapier_tip,
                opt(self.closed_form_tip, 4)
            ),
            format!(
                "{} / {} / {}",
                opt(self.ours_error_pct, 2),
                opt(self.rapier_error_pct, 2),
                opt(self.mesh_floor_pct, 2)
            ),
            format!(
                "{} / {} / {}",
                opt(self.ours_tip_error_pct, 2),
                opt(self.rapier_tip_error_pct, 2),
                opt(self.floor_tip_error_pct, 2)
            ),
            format!("{:.1e} / {:.1e}", self.ours_speed, self.rapier_speed),
        ]
    }
}
