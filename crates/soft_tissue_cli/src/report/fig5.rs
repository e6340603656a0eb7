//! Fig. 5: the cage level's error under the interaction against the precise level, the
//! paper's cage MSD and the calibrated dynamics side by side, with the fit floor.

use super::*;

/// The paper's Fig. 5 section (see [`compare_levels`]): the cylinders under `poke-a` with
/// every cage of `cages`, moved by `dynamics`, against corotational FEM and MSD (RK4).
/// Returns the best fitted cage against FEM: name, max %, cage step us.
#[allow(clippy::too_many_arguments)]
pub(super) fn fig5_section(
    md: &mut String,
    js: &mut Json,
    out: &Path,
    assets: &Path,
    cages: &[(String, CageKind)],
    steps: usize,
    progress: &mut Progress,
) -> Res<Option<(String, f64, f64)>> {
    writeln!(
        *md,
        "## Fig. 5: error of the cage level\n\n\
         The cylinders under `poke-a` run twice in lockstep, every body held at its cage level \
         in one run and at its precise level in the other; per step the mean and the largest \
         distance between the two runs' nodes of model A, as a percentage of A's smallest \
         dimension, and over the run the mean of the means and the largest (the paper: at \
         most 4 % against FEM, 8.1 % against MSD, box cage). Each cage moves by the paper's \
         cage MSD (stiffness 50, mass 20, damping 0.3) and, the default, by dynamics \
         calibrated against the precise model. `fit floor`: the largest surface distance of \
         the best cage fit to the precise run's surface at each step (least squares, as a \
         down-switch fits), the error no dynamics of that cage can go much below: a cage \
         moves the surface only through its Green coordinates, and a local dent under the \
         tool is not among the shapes a coarse cage spans. Series in \
         `fig5_<precise>_<cage>_<dynamics>.csv`.\n"
    )?;
    let mut fig5 = Vec::new();
    let mut fig5_series: [Vec<Series>; 2] = [Vec::new(), Vec::new()];
    let mut best_fitted_vs_fem: Option<(String, f64, f64)> = None;
    for (precise, tag) in [
        (PreciseMethod::CorotationalFem, "fem"),
        (PreciseMethod::MsdImplicit, "msd"),
    ] {
        for (cage_name, kind) in cages {
            for (dynamics, dyn_tag) in [
                (CageDynamics::Paper, "paper"),
                (CageDynamics::Calibrated, "calibrated"),
            ] {
                progress.step(&format!("fig 5: {tag} vs {cage_name} ({dyn_tag})"));
                let mut scene = Scene::paper_cylinders(precise, precise);
                for b in &mut scene.bodies {
                    b.cage.kind = *kind;
                    b.cage.dynamics = dynamics;
                }
                let (series, cage_step) = compare_levels(&scene, "poke-a", steps, assets)?;
                let n = series.len().max(1) as f64;
                let mean = 100.0 * series.iter().map(|s| s.mean).sum::<f64>() / n;
                let max = 100.0 * series.iter().map(|s| s.max).fold(0.0, f64::max);
                // The fit floor over the steps whose fit converged (the same in both runs:
                // both take it from the precise run).
                let fits: Vec<f64> = series.iter().filter_map(|s| s.fit).collect();
                let this_floor = 100.0 * fits.iter().copied().fold(0.0, f64::max);
                let per_step: Vec<Fig5StepRow> = series
                    .iter()
                    .enumerate()
                    .map(|(k, g)| Fig5StepRow {
                        step: k + 1,
                        mean_pct: 100.0 * g.mean,
                        max_pct: 100.0 * g.max,
                        fit_floor_pct: g.fit.map(|f| 100.0 * f),
                    })
                    .collect();
                write_file(
                    out,
                    &format!("fig5_{tag}_{}_{dyn_tag}.csv", cage_name.replace(' ', "")),
                    &super::table::csv_text(&per_step)?,
                )?;
                let slot = usize::from(tag == "msd");
                // The chart: the largest distance per step of every cage, both dynamics.
                fig5_series[slot].push(Series {
                    name: format!("{cage_name} {dyn_tag}"),
                    points: series
                        .iter()
                        .enumerate()
                        .map(|(k, g)| ((k + 1) as f64, 100.0 * g.max))
                        .collect(),
                    line: true,
                    markers: false,
                });
                if tag == "fem"
                    && dynamics == CageDynamics::Calibrated
                    && *kind != CageKind::BoundingBox
                    && best_fitted_vs_fem.as_ref().is_none_or(|b| max < b.1)
                {
                    best_fitted_vs_fem = Some((cage_name.clone(), max, cage_step));
                }
                fig5.push(Fig5Row {
                    precise: method_name(precise),
                    cage: cage_name.clone(),
                    dynamics: dyn_tag,
                    mean_pct: mean,
                    max_pct: max,
                    cage_step_us: cage_step,
                    fit_floor_max_pct: this_floor,
                    fit_unconverged_steps: series.len() - fits.len(),
                    steps: series.len(),
                });
            }
        }
    }
    md.push_str(&super::table::md_table(&fig5));
    for (slot, (tag, name)) in [("fem", "corotational FEM"), ("msd", "MSD (RK4)")]
        .into_iter()
        .enumerate()
    {
        chart(
            &out.join(format!("fig5_{tag}.png")),
            &format!("Fig. 5: largest cage-level distance against {name}, cylinders, poke-a"),
            Axis {
                desc: "step",
                log: false,
            },
            Axis {
                desc: "largest node distance, % of smallest dimension",
                log: false,
            },
            &fig5_series[slot],
        )?;
    }
    writeln!(
        *md,
        "\n![Fig. 5 against FEM](fig5_fem.png)\n![Fig. 5 against MSD](fig5_msd.png)\n"
    )?;
    js.insert("fig5".into(), serde_json::to_value(&fig5)?);
    Ok(best_fitted_vs_fem)
}

/// One step of a Fig. 5 run: the distances between the two runs, % of the smallest
/// dimension (the fit floor empty where the fit did not converge).
#[derive(serde::Serialize)]
struct Fig5StepRow {
    step: usize,
    mean_pct: f64,
    max_pct: f64,
    fit_floor_pct: Option<f64>,
}

impl ReportRow for Fig5StepRow {
    const MD_HEAD: &'static [&'static str] = &["step", "mean %", "max %", "fit floor %"];

    fn md_cells(&self) -> Vec<String> {
        vec![
            self.step.to_string(),
            format!("{:.3}", self.mean_pct),
            format!("{:.3}", self.max_pct),
            self.fit_floor_pct.map_or("-".into(), |f| format!("{f:.3}")),
        ]
    }
}

/// One precise method, cage and cage dynamics of Fig. 5, over the run.
#[derive(serde::Serialize)]
struct Fig5Row {
    precise: &'static str,
    cage: String,
    dynamics: &'static str,
    mean_pct: f64,
    max_pct: f64,
    cage_step_us: f64,
    fit_floor_max_pct: f64,
    fit_unconverged_steps: usize,
    steps: usize,
}

impl Fig5Row {
    /// The fit floor's cell: its largest value, and how many fits did not converge.
    fn floor_cell(&self) -> String {
        let (floor, missed, steps) = (
            self.fit_floor_max_pct,
            self.fit_unconverged_steps,
            self.steps,
        );
        if missed == 0 {
            format!("{floor:.2}")
        } else if missed >= steps {
            format!("- (no fit of the {steps} converged)")
        } else {
            format!("{floor:.2} ({missed} of {steps} fits did not converge)")
        }
    }
}

impl ReportRow for Fig5Row {
    const MD_HEAD: &'static [&'static str] = &[
        "precise",
        "cage",
        "paper mean %",
        "paper max %",
        "calibrated mean %",
        "calibrated max %",
        "fit floor max %",
        "cage step us, paper / calibrated",
    ];

    /// A row alone: its own dynamics' columns filled, the other's empty.
    fn md_cells(&self) -> Vec<String> {
        let paper = self.dynamics == "paper";
        let pick = |v: String| {
            if paper {
                (v, "-".into())
            } else {
                ("-".into(), v)
            }
        };
        let (pm, cm) = pick(format!("{:.2}", self.mean_pct));
        let (px, cx) = pick(format!("{:.2}", self.max_pct));
        let (ps, cs) = pick(us(Some(self.cage_step_us)));
        vec![
            self.precise.into(),
            self.cage.clone(),
            pm,
            px,
            cm,
            cx,
            self.floor_cell(),
            format!("{ps} / {cs}"),
        ]
    }

    /// One Markdown row per method and cage: the paper's dynamics beside the calibrated.
    fn md_rows(rows: &[Self]) -> Vec<Vec<String>> {
        rows.chunks(2)
            .map(|pair| match pair {
                [p, c] => vec![
                    p.precise.into(),
                    p.cage.clone(),
                    format!("{:.2}", p.mean_pct),
                    format!("{:.2}", p.max_pct),
                    format!("{:.2}", c.mean_pct),
                    format!("{:.2}", c.max_pct),
                    // Both runs take the floor from the precise run: the calibrated one's.
                    c.floor_cell(),
                    format!(
                        "{} / {}",
                        us(Some(p.cage_step_us)),
                        us(Some(c.cage_step_us))
                    ),
                ],
                [one] => one.md_cells(),
                _ => Vec::new(),
            })
            .collect()
    }
}

/// One step of the Fig. 5 protocol, as fractions of the first body's smallest dimension.
#[derive(Debug, Clone, Copy)]
struct LevelGap {
    /// Mean node distance between the cage run and the precise run.
    mean: f64,
    /// Largest node distance.
    max: f64,
    /// Largest surface distance of the best cage fit to the precise run's surface: how
    /// close a cage of this shape can follow, whatever moves it. `None` when the fit did not
    /// converge.
    fit: Option<f64>,
}

/// The paper's Fig. 5 protocol: the same scene and interaction run twice in lockstep, every
/// body pinned at its cage level in one and at its precise level in the other; per step, the
/// distances of the first body between the two ([`LevelGap`]). Also the mean cage step of that
/// body, us.
fn compare_levels(
    scene: &Scene,
    script: &str,
    steps: usize,
    assets: &Path,
) -> Res<(Vec<LevelGap>, f64)> {
    let mut worlds = Vec::with_capacity(2);
    for level in [Level::Cage, Level::Precise] {
        let mut w = sweep::build_world(scene, assets, &paper_msd)?;
        for b in w.bodies_mut() {
            b.body_mut().pin(Some(level))?;
        }
        let s = Script::builtin(script, &w)?;
        let ti = w.add_tool(Tool::new(s.name.clone(), s.tool)?);
        worlds.push((w, s, ti));
    }
    let dt = worlds[0].0.config().dt;
    let mut series = Vec::with_capacity(steps);
    let mut cage_us = 0.0;
    for k in 0..steps {
        let t = (k + 1) as f64 * dt;
        for (w, s, ti) in &mut worlds {
            drive_tool(w, s, *ti, t, dt)?;
            w.step_fixed()?;
        }
        let fit = {
            let b = worlds[1].0.bodies_mut()[0].body_mut();
            let r = b.fit_cage_now()?;
            b.last_fit().converged.then_some(r)
        };
        let (cage, precise) = (&worlds[0].0.bodies()[0], &worlds[1].0.bodies()[0]);
        cage_us += cage.diagnostics().step_us;
        let scale = precise.body().smallest_dimension();
        let (mut sum, mut max) = (0.0f64, 0.0f64);
        let (a, b) = (
            cage.body().node_positions(),
            precise.body().node_positions(),
        );
        for (p, q) in a.iter().zip(b) {
            let d = (p - q).norm();
            sum += d;
            max = max.max(d);
        }
        let n = a.len().max(1) as f64;
        series.push(LevelGap {
            mean: sum / n / scale,
            max: max / scale,
            fit: fit.map(|f| f / scale),
        });
    }
    Ok((series, cage_us / steps.max(1) as f64))
}
