//! The paper's Tables II to V and the scaling table: the timed runs of a scene under a
//! script ([`run`]) and the sections' rows, which write themselves to Markdown, CSV and JSON.

use super::*;

/// Tables II and III: the two cylinders under `poke-a` and `push-a-into-b`, each method pair
/// of `pairs`, each body at its cage level and at its precise level. Writes
/// `tables_2_3.csv` and the JSON's `tables_2_3`.
pub(super) fn paper_tables_section(
    md: &mut String,
    js: &mut Json,
    out: &Path,
    assets: &Path,
    pairs: &[(PreciseMethod, PreciseMethod)],
    steps: usize,
    progress: &mut Progress,
) -> Res<()> {
    let mut rows: Vec<PaperTableRow> = Vec::new();
    for (table, script) in [("II", "poke-a"), ("III", "push-a-into-b")] {
        writeln!(
            md,
            "## Table {table}: cylinders, `{script}`\n\n\
             Mean step time per body and level, us (the paper's Table {table} layout: each \
             method pair, each body at its cage level and at its precise level).\n"
        )?;
        let first = rows.len();
        for &(a, b) in pairs {
            progress.step(&format!(
                "table {table}: {} / {}",
                method_name(a),
                method_name(b)
            ));
            let r = run(
                RunSpec {
                    scene: Scene::paper_cylinders(a, b),
                    script,
                    steps,
                    pin: None,
                    resting: 0,
                },
                assets,
            )?;
            for body in &r.bodies[..2] {
                rows.push(PaperTableRow {
                    table,
                    script,
                    method_a: method_name(a),
                    method_b: method_name(b),
                    body: body.name.clone(),
                    cage_steps: body.cage_steps,
                    mean_cage_us: body.mean_cage_us(),
                    precise_steps: body.precise_steps,
                    mean_precise_us: body.mean_precise_us(),
                    switches: body.switches,
                    worst_jump_pct: 100.0 * body.worst_jump_ratio,
                });
            }
        }
        // Both tables go to one CSV and one JSON entry; each has its own Markdown table.
        md.push_str(&table::md_table(&rows[first..]));
        writeln!(md)?;
    }
    write_file(out, "tables_2_3.csv", &table::csv_text(&rows)?)?;
    js.insert("tables_2_3".into(), serde_json::to_value(&rows)?);
    Ok(())
}

/// What the goals take from the organ runs of Tables IV and V.
pub(super) struct OrganRuns {
    /// The liver's median cage step with the cage level, us.
    pub liver_cage_us: Option<f64>,
    /// The liver's median precise step with every body precise, us.
    pub liver_precise_us: Option<f64>,
    /// The mean whole step with every body precise, us.
    pub all_precise_step_us: f64,
}

/// Tables IV and V: the organs under `poke-liver` with the cage level and with every body at
/// its precise level. Writes `tables_4_5.csv` and the JSON's `tables_4_5`.
pub(super) fn organ_tables_section(
    md: &mut String,
    js: &mut Json,
    out: &Path,
    assets: &Path,
    organs: &Scene,
    steps: usize,
    progress: &mut Progress,
) -> Res<OrganRuns> {
    let mut with_cage = None;
    let mut without_cage = None;
    for (label, pin) in [
        ("with the cage level (IV)", None),
        ("without it (V)", Some(Level::Precise)),
    ] {
        progress.step(&format!("organs {label}"));
        let r = run(
            RunSpec {
                scene: organs.clone(),
                script: "poke-liver",
                steps,
                pin,
                resting: 0,
            },
            assets,
        )?;
        if pin.is_none() {
            with_cage = Some(r);
        } else {
            without_cage = Some(r);
        }
    }
    let (with_cage, without_cage) = (
        with_cage.ok_or("organs run missing")?,
        without_cage.ok_or("organs run missing")?,
    );
    writeln!(
        md,
        "## Tables IV and V: organs, `poke-liver`\n\n\
         Mean step time per body, us: with the levels of precision (a body is at its cage level \
         until touched) and with every body at its precise level throughout.\n"
    )?;
    let organ_rows: Vec<OrganTableRow> = with_cage
        .bodies
        .iter()
        .zip(&without_cage.bodies)
        .map(|(b, c)| OrganTableRow {
            body: b.name.clone(),
            with_cage_mean_cage_us: b.mean_cage_us(),
            with_cage_mean_precise_us: b.mean_precise_us(),
            without_cage_mean_precise_us: c.mean_precise_us(),
        })
        .collect();
    let organ_json = write_rows(&organ_rows, md, out, "tables_4_5.csv")?;
    let all_precise_sum: f64 = without_cage
        .bodies
        .iter()
        .filter_map(BodyStats::mean_precise_us)
        .sum();
    writeln!(
        md,
        "\nWhole step (solvers, contact, switching, writeback), mean: {:.1} us with the cage \
         level, {:.1} us without. The four organs' precise steps add up to {:.1} us per step.\n",
        with_cage.mean_step_us(),
        without_cage.mean_step_us(),
        all_precise_sum
    )?;
    js.insert(
        "tables_4_5".into(),
        json!({
            "bodies": organ_json,
            "with_cage_mean_step_us": with_cage.mean_step_us(),
            "without_cage_mean_step_us": without_cage.mean_step_us(),
            "all_precise_sum_us": all_precise_sum,
        }),
    );
    // The liver's cage against its corotational step, from the same two runs: medians, so
    // the few steps that switch levels (a cage fit, a raise) do not stand for the level.
    Ok(OrganRuns {
        liver_cage_us: with_cage.bodies.first().and_then(BodyStats::median_cage_us),
        liver_precise_us: without_cage
            .bodies
            .first()
            .and_then(BodyStats::median_precise_us),
        all_precise_step_us: without_cage.mean_step_us(),
    })
}

/// Scaling: `poke-liver` on the organs plus each count of `resting` resting copies, with
/// level switching and with every body precise, `steps` steps each. Writes `scaling.csv`,
/// `scaling_resting.png` and the JSON's `scaling`; returns (N, with switching, without) in us.
#[allow(clippy::too_many_arguments)]
pub(super) fn scaling_section(
    md: &mut String,
    js: &mut Json,
    out: &Path,
    assets: &Path,
    organs: &Scene,
    resting: &[usize],
    steps: usize,
    progress: &mut Progress,
) -> Res<Vec<(usize, f64, f64)>> {
    writeln!(
        md,
        "## Scaling: one touched organ and N resting ones\n\n\
         `poke-liver` on the organs scene plus N resting copies of its last body laid out \
         beside it; mean whole-step time, us, with level switching (the resting bodies stay \
         at their cage level) and without it (every body at its precise level).\n"
    )?;
    let mut rows = Vec::new();
    for &n in resting {
        let mut row = [0.0; 2];
        for (slot, pin) in [(0, None), (1, Some(Level::Precise))] {
            progress.step(&format!(
                "scaling: {n} resting, {}",
                ["switching", "all precise"][slot]
            ));
            row[slot] = run(
                RunSpec {
                    scene: organs.clone(),
                    script: "poke-liver",
                    steps,
                    pin,
                    resting: n,
                },
                assets,
            )?
            .mean_step_us();
        }
        rows.push(ScalingRow {
            resting: n,
            with_switching_us: row[0],
            without_switching_us: row[1],
        });
    }
    let json = write_rows(&rows, md, out, "scaling.csv")?;
    let series = |name: &str, us: fn(&ScalingRow) -> f64| Series {
        name: name.into(),
        points: rows.iter().map(|r| (r.resting as f64, us(r))).collect(),
        line: true,
        markers: true,
    };
    chart(
        &out.join("scaling_resting.png"),
        "One touched organ and N resting ones: whole step",
        Axis {
            desc: "resting bodies N",
            log: false,
        },
        Axis {
            desc: "mean step, us",
            log: false,
        },
        &[
            series("with switching", |r| r.with_switching_us),
            series("all precise", |r| r.without_switching_us),
        ],
    )?;
    writeln!(
        md,
        "\n![scaling with resting bodies](scaling_resting.png)\n"
    )?;
    js.insert("scaling".into(), json);
    Ok(rows
        .iter()
        .map(|r| (r.resting, r.with_switching_us, r.without_switching_us))
        .collect())
}

/// A cylinder of Tables II and III under one method pair.
#[derive(serde::Serialize)]
struct PaperTableRow {
    pub table: &'static str,
    pub script: &'static str,
    pub method_a: &'static str,
    pub method_b: &'static str,
    pub body: String,
    pub cage_steps: u64,
    pub mean_cage_us: Option<f64>,
    pub precise_steps: u64,
    pub mean_precise_us: Option<f64>,
    pub switches: u64,
    pub worst_jump_pct: f64,
}

impl ReportRow for PaperTableRow {
    const MD_HEAD: &'static [&'static str] = &[
        "A",
        "B",
        "A cage",
        "A precise",
        "B cage",
        "B precise",
        "switches A / B",
        "worst jump A / B %",
    ];

    /// A body without its partner: the B columns empty.
    fn md_cells(&self) -> Vec<String> {
        vec![
            self.method_a.into(),
            self.method_b.into(),
            us(self.mean_cage_us),
            us(self.mean_precise_us),
            "-".into(),
            "-".into(),
            format!("{} / -", self.switches),
            format!("{:.2} / -", self.worst_jump_pct),
        ]
    }

    /// One Markdown row per method pair: its two bodies side by side, as the paper's tables.
    fn md_rows(rows: &[Self]) -> Vec<Vec<String>> {
        rows.chunks(2)
            .filter_map(|pair| match pair {
                [a, b] => Some(vec![
                    a.method_a.into(),
                    a.method_b.into(),
                    us(a.mean_cage_us),
                    us(a.mean_precise_us),
                    us(b.mean_cage_us),
                    us(b.mean_precise_us),
                    format!("{} / {}", a.switches, b.switches),
                    format!("{:.2} / {:.2}", a.worst_jump_pct, b.worst_jump_pct),
                ]),
                _ => None,
            })
            .collect()
    }
}

/// An organ of Tables IV and V: with the cage level and without it.
#[derive(serde::Serialize)]
struct OrganTableRow {
    pub body: String,
    pub with_cage_mean_cage_us: Option<f64>,
    pub with_cage_mean_precise_us: Option<f64>,
    pub without_cage_mean_precise_us: Option<f64>,
}

impl ReportRow for OrganTableRow {
    const MD_HEAD: &'static [&'static str] = &[
        "body",
        "with cage level: cage",
        "with cage level: precise",
        "without: precise",
    ];

    fn md_cells(&self) -> Vec<String> {
        vec![
            self.body.clone(),
            us(self.with_cage_mean_cage_us),
            us(self.with_cage_mean_precise_us),
            us(self.without_cage_mean_precise_us),
        ]
    }
}

/// One touched organ and `resting` resting ones: the mean whole step, us.
#[derive(serde::Serialize)]
struct ScalingRow {
    pub resting: usize,
    pub with_switching_us: f64,
    pub without_switching_us: f64,
}

impl ReportRow for ScalingRow {
    const MD_HEAD: &'static [&'static str] = &["N resting", "with switching", "without switching"];

    fn md_cells(&self) -> Vec<String> {
        vec![
            self.resting.to_string(),
            format!("{:.1}", self.with_switching_us),
            format!("{:.1}", self.without_switching_us),
        ]
    }
}

/// What one run measured for one body.
#[derive(Debug, Clone, Default)]
struct BodyStats {
    name: String,
    cage_steps: u64,
    cage_us: f64,
    precise_steps: u64,
    precise_us: f64,
    switches: u64,
    worst_jump_ratio: f64,
    /// Step times at the cage level and at the precise level, us.
    cage_samples: Vec<f64>,
    precise_samples: Vec<f64>,
}

impl BodyStats {
    fn median_cage_us(&self) -> Option<f64> {
        median(&self.cage_samples)
    }
    fn median_precise_us(&self) -> Option<f64> {
        median(&self.precise_samples)
    }
    fn mean_cage_us(&self) -> Option<f64> {
        (self.cage_steps > 0).then(|| self.cage_us / self.cage_steps as f64)
    }
    fn mean_precise_us(&self) -> Option<f64> {
        (self.precise_steps > 0).then(|| self.precise_us / self.precise_steps as f64)
    }
}

/// One run of a scene under a script.
struct Run {
    bodies: Vec<BodyStats>,
    /// Whole-step time per step, us.
    step_us: Vec<f64>,
}

impl Run {
    fn mean_step_us(&self) -> f64 {
        self.step_us.iter().sum::<f64>() / self.step_us.len().max(1) as f64
    }
}

/// How a run is set up.
struct RunSpec<'a> {
    scene: Scene,
    script: &'a str,
    steps: usize,
    /// Pin every body at this level (no switching).
    pin: Option<Level>,
    resting: usize,
}

fn run(spec: RunSpec<'_>, assets: &Path) -> Res<Run> {
    let mut scene = spec.scene;
    let mut world = sweep::build_world(&scene, assets, &paper_msd)?;
    if spec.resting > 0 {
        add_resting_copies(&mut scene, spec.resting, &world);
        world = sweep::build_world(&scene, assets, &paper_msd)?;
    }
    if let Some(level) = spec.pin {
        for b in world.bodies_mut() {
            b.model_mut().pin(Some(level))?;
        }
    }
    let script = Script::builtin(spec.script, &world)?;
    let ti = world.add_tool(Tool::new(script.name.clone(), script.tool)?);
    let dt = world.config().dt;
    let mut stats: Vec<BodyStats> = world
        .bodies()
        .iter()
        .map(|b| BodyStats {
            name: b.name().to_string(),
            ..BodyStats::default()
        })
        .collect();
    let mut step_us = Vec::with_capacity(spec.steps);
    for k in 0..spec.steps {
        let t = (k + 1) as f64 * dt;
        drive_tool(&mut world, &script, ti, t, dt)?;
        world.step_fixed()?;
        step_us.push(world.stage_times().total_us());
        for (s, b) in stats.iter_mut().zip(world.bodies()) {
            let d = b.diagnostics();
            match d.level {
                Level::Cage => {
                    s.cage_steps += 1;
                    s.cage_us += d.step_us;
                    s.cage_samples.push(d.step_us);
                }
                Level::Precise => {
                    s.precise_steps += 1;
                    s.precise_us += d.step_us;
                    s.precise_samples.push(d.step_us);
                }
            }
            if let Some(sw) = d.switched {
                s.worst_jump_ratio = s.worst_jump_ratio.max(sw.jump_ratio);
            }
            s.switches = b.model().switch_count();
        }
    }
    Ok(Run {
        bodies: stats,
        step_us,
    })
}
