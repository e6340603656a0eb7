//! The solvers' hard cases: what each method does with them.

use super::*;

/// The solvers' hard cases and how each ended.
pub(super) fn stability_section(
    md: &mut String,
    js: &mut Json,
    out: &Path,
    assets: &Path,
    cases: &[HardCase],
    quick: bool,
    step: &mut dyn FnMut(&str),
) -> Res<()> {
    let steps = if quick { 300 } else { 10_000 };
    let path = assets.join("meshes/cylinder.vtk");
    let mesh = soft_tissue_core::mesh::io::read_tet_mesh(&path)
        .map_err(|e| format!("{}: {e}", path.display()))?
        .mesh;
    writeln!(
        md,
        "## Stability: the hard cases\n\n\
         The paper's cylinder (bottom 10 % fixed, gravity off), {steps} steps per case after \
         the disturbance starts (`soft_tissue_core::stability`, the cases the test suite \
         checks). Outcome: stable (every step at the requested step), substepped (explicit \
         MSD above its limit, split), refused (a clear error on the first step) or failed. \
         Energy: largest after the disturbance over the energy when it ended (bounded: at \
         most 1.01). Distances from rest as fractions of the width.\n"
    )?;
    let mut rows = Vec::new();
    for c in cases {
        step(&format!("stability: {} ({})", c.name, c.method_name()));
        let r = run_case(
            &mesh,
            c,
            (&CYLINDER_FEM.params, CYLINDER_FEM.dt),
            (&CYLINDER_MSD.params, CYLINDER_MSD.dt),
            steps,
        )?;
        let outcome = match &r.outcome {
            Outcome::Stable => "stable".to_string(),
            Outcome::Substepped(n) => format!("substepped ({n} per step)"),
            Outcome::Refused(m) => format!("refused: {m}"),
            Outcome::Failed { step, message } => format!("**failed** at step {step}: {message}"),
        };
        rows.push(StabilityRow {
            case: c.name.to_string(),
            solver: c.method_name().to_string(),
            dt: r.dt,
            outcome,
            steps: r.steps,
            inverted: r.inverted,
            flat: r.flat,
            end_energy: r.end_energy,
            peak_energy: r.peak_energy,
            disturbed_distance: r.disturbed_distance,
            final_distance: r.final_distance,
        });
    }
    let json = write_rows(&rows, md, out, "stability.csv")?;
    writeln!(md)?;
    js.insert("stability".into(), json);
    Ok(())
}

/// One hard case run with one solver.
#[derive(serde::Serialize)]
struct StabilityRow {
    case: String,
    solver: String,
    dt: f64,
    outcome: String,
    steps: usize,
    inverted: usize,
    flat: usize,
    end_energy: f64,
    peak_energy: f64,
    disturbed_distance: f64,
    final_distance: f64,
}

impl ReportRow for StabilityRow {
    const MD_HEAD: &'static [&'static str] = &[
        "case",
        "solver",
        "dt",
        "outcome",
        "inverted / flat at start",
        "energy peak / end",
        "distance disturbed",
        "distance at end",
    ];

    fn md_cells(&self) -> Vec<String> {
        let ratio = if self.end_energy > 0.0 {
            format!("{:.3}", self.peak_energy / self.end_energy)
        } else {
            "-".into()
        };
        vec![
            self.case.clone(),
            self.solver.clone(),
            format!("{:.4}", self.dt),
            self.outcome.clone(),
            format!("{} / {}", self.inverted, self.flat),
            ratio,
            format!("{:.3}", self.disturbed_distance),
            format!("{:.2e}", self.final_distance),
        ]
    }
}
