//! Fig. 5: the cage level's error under the interaction against the precise level, the
//! paper's cage MSD, the calibrated and the condensed dynamics side by side, with the fit
//! floor.

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
         cage MSD (stiffness 50, mass 20, damping 0.3), by dynamics calibrated against the \
         precise model (the default: its mass, stiffness and damping projected onto the \
         cage's shapes) and by condensed dynamics (opt-in, \
         `soft_tissue_core::calibration::condense_cage`: the stiffness the precise model \
         shows through the cage's coordinates, whose lowest frequencies are the precise \
         model's). `fit floor`: the largest surface distance of \
         the best cage fit to the precise run's surface at each step (least squares, as a \
         down-switch fits), the error no dynamics of that cage can go much below: a cage \
         moves the surface only through its Green coordinates, and a local dent under the \
         tool is not among the shapes a coarse cage spans. Where some fits did not converge \
         the cell gives the largest over the converged fits, then over all fits (a fit that \
         stopped early is farther than the best, so the true largest lies between), and how \
         many did not; `none` where none converged. Series in \
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
            // Every run takes the fit floor from the same precise run: the first run's fits
            // serve the others.
            let mut fits: Option<Vec<Option<FitAt>>> = None;
            for (dynamics, condense, dyn_tag) in [
                (CageDynamics::Paper, false, "paper"),
                (CageDynamics::Calibrated, false, "calibrated"),
                (CageDynamics::Calibrated, true, "condensed"),
            ] {
                progress.step(&format!("fig 5: {tag} vs {cage_name} ({dyn_tag})"));
                let mut scene = Scene::paper_cylinders(precise, precise);
                for b in &mut scene.bodies {
                    b.cage.kind = *kind;
                    b.cage.dynamics = dynamics;
                }
                let (series, cage_step) =
                    compare_levels(&scene, "poke-a", steps, assets, fits.is_none(), condense)?;
                let fits = fits.get_or_insert_with(|| series.iter().map(|s| s.fit).collect());
                let n = series.len().max(1) as f64;
                let mean = 100.0 * series.iter().map(|s| s.mean).sum::<f64>() / n;
                let max = 100.0 * series.iter().map(|s| s.max).fold(0.0, f64::max);
                // The fit floor over the steps whose fit converged, and over every fit.
                let converged: Vec<f64> = fits
                    .iter()
                    .flatten()
                    .filter(|f| f.converged)
                    .map(|f| 100.0 * f.distance)
                    .collect();
                let floor =
                    (!converged.is_empty()).then(|| converged.iter().copied().fold(0.0, f64::max));
                let all_fits = fits
                    .iter()
                    .flatten()
                    .map(|f| 100.0 * f.distance)
                    .fold(0.0, f64::max);
                let per_step: Vec<Fig5StepRow> = series
                    .iter()
                    .zip(fits.iter())
                    .enumerate()
                    .map(|(k, (g, f))| Fig5StepRow {
                        step: k + 1,
                        mean_pct: 100.0 * g.mean,
                        max_pct: 100.0 * g.max,
                        fit_floor_pct: f.filter(|f| f.converged).map(|f| 100.0 * f.distance),
                        fit_pct: f.map(|f| 100.0 * f.distance),
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
                    && dyn_tag == "calibrated"
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
                    fit_floor_max_pct: floor,
                    fit_all_max_pct: all_fits,
                    fit_unconverged_steps: series.len() - converged.len(),
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
/// dimension; the fit's largest surface distance, and as the fit floor where the fit
/// converged (empty where it did not).
#[derive(serde::Serialize)]
struct Fig5StepRow {
    step: usize,
    mean_pct: f64,
    max_pct: f64,
    fit_floor_pct: Option<f64>,
    fit_pct: Option<f64>,
}

impl ReportRow for Fig5StepRow {
    const MD_HEAD: &'static [&'static str] = &["step", "mean %", "max %", "fit floor %", "fit %"];

    fn md_cells(&self) -> Vec<String> {
        let cell = |v: Option<f64>| v.map_or("-".into(), |f| format!("{f:.3}"));
        vec![
            self.step.to_string(),
            format!("{:.3}", self.mean_pct),
            format!("{:.3}", self.max_pct),
            cell(self.fit_floor_pct),
            cell(self.fit_pct),
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
    /// The largest fit distance over the steps whose fit converged; `None` where none did.
    fit_floor_max_pct: Option<f64>,
    /// The largest fit distance over every step's fit, converged or not (an upper bound).
    fit_all_max_pct: f64,
    fit_unconverged_steps: usize,
    steps: usize,
}

impl Fig5Row {
    /// The fit floor's cell: its largest value over the converged fits, then over all fits
    /// where some did not converge (the true largest lies between), and how many did not;
    /// `none` where none converged.
    fn floor_cell(&self) -> String {
        let (missed, steps, all) = (self.fit_unconverged_steps, self.steps, self.fit_all_max_pct);
        match self.fit_floor_max_pct {
            None => format!("none (no fit of the {steps} converged; {all:.2} over all fits)"),
            Some(floor) if missed == 0 => format!("{floor:.2}"),
            Some(floor) => format!(
                "{floor:.2} converged, {all:.2} all ({missed} of {steps} fits did not converge)"
            ),
        }
    }
}

impl ReportRow for Fig5Row {
    const MD_HEAD: &'static [&'static str] = &[
        "precise",
        "cage",
        "paper mean / max %",
        "calibrated mean / max %",
        "condensed mean / max %",
        "fit floor max %",
        "cage step us, paper / calibrated / condensed",
    ];

    /// A row alone: its own dynamics' column filled, the others empty.
    fn md_cells(&self) -> Vec<String> {
        let cell = |d: &str| {
            if self.dynamics == d {
                format!("{:.2} / {:.2}", self.mean_pct, self.max_pct)
            } else {
                "-".into()
            }
        };
        vec![
            self.precise.into(),
            self.cage.clone(),
            cell("paper"),
            cell("calibrated"),
            cell("condensed"),
            self.floor_cell(),
            us(Some(self.cage_step_us)),
        ]
    }

    /// One Markdown row per method and cage: the three dynamics side by side.
    fn md_rows(rows: &[Self]) -> Vec<Vec<String>> {
        rows.chunks(3)
            .map(|three| match three {
                [p, c, k] => {
                    let cell = |r: &Self| format!("{:.2} / {:.2}", r.mean_pct, r.max_pct);
                    vec![
                        p.precise.into(),
                        p.cage.clone(),
                        cell(p),
                        cell(c),
                        cell(k),
                        // Every run takes the floor from the same precise run.
                        p.floor_cell(),
                        format!(
                            "{} / {} / {}",
                            us(Some(p.cage_step_us)),
                            us(Some(c.cage_step_us)),
                            us(Some(k.cage_step_us))
                        ),
                    ]
                }
                _ => three
                    .iter()
                    .map(|r| r.md_cells())
                    .next()
                    .unwrap_or_default(),
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
    /// The cage fit to the precise run's surface, when asked for.
    fit: Option<FitAt>,
}

/// The best cage fit to the precise run's surface at one step: its largest surface distance
/// (how close a cage of this shape can follow, whatever moves it) and whether the fit
/// converged (otherwise the distance is that of the best fit found, an upper bound).
#[derive(Debug, Clone, Copy)]
struct FitAt {
    distance: f64,
    converged: bool,
}

/// The paper's Fig. 5 protocol: the same scene and interaction run twice in lockstep, every
/// body pinned at its cage level in one and at its precise level in the other; per step, the
/// distances of the first body between the two ([`LevelGap`]), with the cage fit to the
/// precise run's surface if `with_fit`, every body's cage condensed if `condense`. Also the
/// mean cage step of that body, us.
fn compare_levels(
    scene: &Scene,
    script: &str,
    steps: usize,
    assets: &Path,
    with_fit: bool,
    condense: bool,
) -> Res<(Vec<LevelGap>, f64)> {
    let mut worlds = Vec::with_capacity(2);
    for level in [Level::Cage, Level::Precise] {
        let mut w = sweep::build_world(scene, assets, &paper_msd)?;
        for b in w.bodies_mut() {
            if condense {
                soft_tissue_core::calibration::condense_cage(b.model_mut())?;
            }
            b.model_mut().pin(Some(level))?;
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
        let fit = if with_fit {
            let b = worlds[1].0.bodies_mut()[0].model_mut();
            let r = b.fit_cage_now()?;
            Some(FitAt {
                distance: r / b.smallest_dimension(),
                converged: b.last_fit().converged,
            })
        } else {
            None
        };
        let (cage, precise) = (&worlds[0].0.bodies()[0], &worlds[1].0.bodies()[0]);
        cage_us += cage.diagnostics().step_us;
        let scale = precise.model().smallest_dimension();
        let (mut sum, mut max) = (0.0f64, 0.0f64);
        let (a, b) = (
            cage.model().node_positions(),
            precise.model().node_positions(),
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
            fit,
        });
    }
    Ok((series, cage_us / steps.max(1) as f64))
}
