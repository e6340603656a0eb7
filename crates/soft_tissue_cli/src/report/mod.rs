//! `soft-tissue report`: the paper's tables and figure, speed against error, scaling,
//! stability and the rapier3d peer, measured in one run and written as Markdown, CSV, JSON and
//! PNG charts.
//!
//! Every number comes from running the scenes headless with the built-in scripts and loads;
//! nothing is copied. Goals are checked and a missed goal is reported as missed.

mod budget;
mod peer;
mod plots;
mod sweep;

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use serde_json::json;
use soft_tissue_core::contact::Tool;
use soft_tissue_core::msd::MsdIntegrator;
use soft_tissue_core::precision::{Level, PreciseMethod as LevelMethod};
use soft_tissue_core::scenario::{
    CYLINDER_FEM, CYLINDER_MSD, CageKind, ORGAN_FEM, PreciseMethod, Scene,
};
use soft_tissue_core::stability::{HardCase, Outcome, run_case};
use soft_tissue_core::world::Script;

use plots::{Axis, Series, chart};

use crate::simulate::{add_resting_copies, drive_tool, load_scene};

pub(crate) type Res<T> = Result<T, Box<dyn std::error::Error>>;

#[derive(Args)]
pub struct ReportArgs {
    /// Folder for report.md, report.json and the CSV series (created if missing).
    #[arg(long)]
    out: PathBuf,
    /// Fewer steps and sizes (a smoke run for CI; its numbers are not the report's).
    #[arg(long)]
    quick: bool,
    /// Folder the scenes' mesh files are relative to.
    #[arg(long, default_value = "assets")]
    assets: PathBuf,
    /// Threads the scenes' worlds step on (0: every available core). Default 1, so the
    /// tables compare with earlier runs and their worst-step ratios are not those of a pool
    /// sharing a small machine with the system; the mesh-size table and the thread table
    /// measure one thread and every core whatever this is.
    #[arg(long, default_value_t = 1)]
    threads: usize,
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

fn median(v: &[f64]) -> Option<f64> {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s.get(s.len() / 2).copied()
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

/// MSD bodies step with RK4, as in the paper (scenes default to the implicit integrator).
fn paper_msd(s: &mut soft_tissue_core::precision::BodySettings) {
    if let LevelMethod::Msd(_) = s.precise {
        s.precise = LevelMethod::Msd(MsdIntegrator::Rk4);
    }
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
            b.body_mut().pin(Some(level))?;
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
            s.switches = b.body().switch_count();
        }
    }
    Ok(Run {
        bodies: stats,
        step_us,
    })
}

/// The paper's Fig. 5 protocol: the same scene and interaction run twice in lockstep, every
/// body pinned at its cage level in one and at its precise level in the other; per step, the
/// mean and the largest node distance of the first body between the two, as fractions of its
/// smallest dimension. Also the mean cage step of that body, us.
fn compare_levels(
    scene: &Scene,
    script: &str,
    steps: usize,
    assets: &Path,
) -> Res<(Vec<(f64, f64)>, f64)> {
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
        series.push((sum / n / scale, max / scale));
    }
    Ok((series, cage_us / steps.max(1) as f64))
}

/// A text progress bar on stderr.
struct Progress {
    done: usize,
    total: usize,
    start: Instant,
}

impl Progress {
    fn step(&mut self, what: &str) {
        self.done += 1;
        let width = 30;
        let filled = width * self.done / self.total.max(1);
        eprint!(
            "\r[{}{}] {}/{} {:>6.1} s  {what:<48}",
            "#".repeat(filled),
            ".".repeat(width - filled),
            self.done,
            self.total,
            self.start.elapsed().as_secs_f64()
        );
        let _ = std::io::stderr().flush();
    }
    fn finish(&self) {
        eprintln!();
    }
}

fn us(v: Option<f64>) -> String {
    v.map_or("-".into(), |v| format!("{v:.1}"))
}

fn method_name(m: PreciseMethod) -> &'static str {
    match m {
        PreciseMethod::LinearFem => "FEM linear",
        PreciseMethod::CorotationalFem => "FEM corotational",
        PreciseMethod::PrefactoredFem => "FEM corotational prefactored",
        PreciseMethod::Msd => "MSD (RK4)",
    }
}

/// Today's date (UTC) from the system clock, `YYYY-MM-DD`.
fn today() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    // Civil date from days since 1970-01-01 (H. Hinnant's algorithm).
    let z = (secs / 86_400) as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}")
}

pub(crate) fn write_file(dir: &Path, name: &str, text: &str) -> Res<()> {
    let path = dir.join(name);
    std::fs::write(&path, text).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(())
}

pub fn report(args: &ReportArgs) -> Res<()> {
    std::fs::create_dir_all(&args.out).map_err(|e| format!("{}: {e}", args.out.display()))?;
    let assets = &args.assets;
    let quick = args.quick;
    soft_tissue_core::parallel::set_default_threads(args.threads);
    let threads = soft_tissue_core::parallel::Threads::new(args.threads)?;
    // The mesh-size table's second column: every core.
    let all_cores = soft_tissue_core::parallel::Threads::new(0)?;
    // The scripts' interactions last about 4 s (poke, hold, withdraw) at 100 Hz.
    let steps = if quick { 120 } else { 500 };
    let pairs = [
        (PreciseMethod::LinearFem, PreciseMethod::LinearFem),
        (PreciseMethod::Msd, PreciseMethod::Msd),
        (PreciseMethod::LinearFem, PreciseMethod::Msd),
        (PreciseMethod::Msd, PreciseMethod::LinearFem),
        (
            PreciseMethod::CorotationalFem,
            PreciseMethod::CorotationalFem,
        ),
    ];
    let cages: Vec<(String, CageKind)> = if quick {
        vec![
            ("box".into(), CageKind::BoundingBox),
            ("fitted 64".into(), CageKind::Fitted { vertices: 64 }),
        ]
    } else {
        vec![
            ("box".into(), CageKind::BoundingBox),
            ("fitted 32".into(), CageKind::Fitted { vertices: 32 }),
            ("fitted 64".into(), CageKind::Fitted { vertices: 64 }),
            ("fitted 128".into(), CageKind::Fitted { vertices: 128 }),
        ]
    };
    let resting: Vec<usize> = if quick {
        vec![0, 4, 16]
    } else {
        vec![0, 1, 4, 16, 64, 256]
    };
    let sweep_configs = sweep::configs(quick, ORGAN_FEM.dt);
    let resolutions: Vec<f64> = if quick {
        vec![0.5, 1.0]
    } else {
        vec![0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0]
    };
    let cases = HardCase::all();
    let peers: [(&str, _, f64); 2] = [
        ("meshes/cylinder.vtk", CYLINDER_FEM.params, CYLINDER_FEM.dt),
        ("meshes/liver.vtk", ORGAN_FEM.params, ORGAN_FEM.dt),
    ];
    let mut progress = Progress {
        done: 0,
        total: 2 * pairs.len()
            + 2
            + 2 * cages.len()
            + 2 * resting.len()
            + resolutions.len()
            + sweep_configs.len()
            + 1
            + cases.len()
            + peers.len()
            + 7,
        start: Instant::now(),
    };
    let machine = crate::machine();
    let mut md = String::new();
    let mut js = serde_json::Map::new();
    writeln!(
        md,
        "# Levels of precision: measured report\n\n\
         Generated by `soft-tissue report{}` on {} ({}, {} cores, {} build, worlds on {} \
         thread(s); bench tables on one thread unless stated).\n\
         Step times are wall-clock means over the run's steps at each level; they vary from run \
         to run by a few percent on this shared machine.\n",
        if quick { " --quick" } else { "" },
        today(),
        machine["cpu"].as_str().unwrap_or("unknown"),
        machine["cores"],
        machine["profile"].as_str().unwrap_or("unknown"),
        threads.count(),
    )?;
    if quick {
        writeln!(
            md,
            "**Quick run** ({steps} steps, fewer cages and sizes): a smoke test of the \
             command; the committed report is the full run.\n"
        )?;
    }

    // Tables II and III.
    let mut csv = String::from(
        "table,script,method_a,method_b,body,cage_steps,mean_cage_us,precise_steps,mean_precise_us,switches,worst_jump_pct\n",
    );
    let mut table_json = Vec::new();
    for (table, script) in [("II", "poke-a"), ("III", "push-a-into-b")] {
        writeln!(
            md,
            "## Table {table}: cylinders, `{script}`\n\n\
             Mean step time per body and level, us (the paper's Table {table} layout: each \
             method pair, each body at its cage level and at its precise level).\n\n\
             | A | B | A cage | A precise | B cage | B precise | switches A / B | worst jump A / B % |\n\
             |---|---|---|---|---|---|---|---|"
        )?;
        for (a, b) in pairs {
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
            let (ba, bb) = (&r.bodies[0], &r.bodies[1]);
            writeln!(
                md,
                "| {} | {} | {} | {} | {} | {} | {} / {} | {:.2} / {:.2} |",
                method_name(a),
                method_name(b),
                us(ba.mean_cage_us()),
                us(ba.mean_precise_us()),
                us(bb.mean_cage_us()),
                us(bb.mean_precise_us()),
                ba.switches,
                bb.switches,
                100.0 * ba.worst_jump_ratio,
                100.0 * bb.worst_jump_ratio,
            )?;
            for body in [ba, bb] {
                writeln!(
                    csv,
                    "{table},{script},{},{},{},{},{},{},{},{},{}",
                    method_name(a),
                    method_name(b),
                    body.name,
                    body.cage_steps,
                    us(body.mean_cage_us()),
                    body.precise_steps,
                    us(body.mean_precise_us()),
                    body.switches,
                    100.0 * body.worst_jump_ratio
                )?;
                table_json.push(json!({
                    "table": table, "script": script,
                    "method_a": method_name(a), "method_b": method_name(b),
                    "body": body.name,
                    "mean_cage_us": body.mean_cage_us(),
                    "mean_precise_us": body.mean_precise_us(),
                    "cage_steps": body.cage_steps, "precise_steps": body.precise_steps,
                    "switches": body.switches,
                }));
            }
        }
        writeln!(md)?;
    }
    write_file(&args.out, "tables_2_3.csv", &csv)?;
    js.insert("tables_2_3".into(), json!(table_json));

    // Tables IV and V.
    let organs = load_scene("organs", assets)?;
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
         until touched) and with every body at its precise level throughout.\n\n\
         | body | with cage level: cage | with cage level: precise | without: precise |\n\
         |---|---|---|---|"
    )?;
    let mut csv = String::from(
        "body,with_cage_mean_cage_us,with_cage_mean_precise_us,without_cage_mean_precise_us\n",
    );
    for (b, c) in with_cage.bodies.iter().zip(&without_cage.bodies) {
        let cells = [
            b.name.clone(),
            us(b.mean_cage_us()),
            us(b.mean_precise_us()),
            us(c.mean_precise_us()),
        ];
        writeln!(md, "| {} |", cells.join(" | "))?;
        writeln!(csv, "{}", cells.join(","))?;
    }
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
    write_file(&args.out, "tables_4_5.csv", &csv)?;
    js.insert(
        "tables_4_5".into(),
        json!({
            "with_cage_mean_step_us": with_cage.mean_step_us(),
            "without_cage_mean_step_us": without_cage.mean_step_us(),
            "all_precise_sum_us": all_precise_sum,
        }),
    );
    // The liver's cage against its corotational step, from the same two runs: medians, so
    // the few steps that switch levels (a cage fit, a raise) do not stand for the level.
    let liver_cage = with_cage.bodies.first().and_then(BodyStats::median_cage_us);
    let liver_precise = without_cage
        .bodies
        .first()
        .and_then(BodyStats::median_precise_us);

    // Fig. 5: the cage level's error under the interaction, against the precise level.
    writeln!(
        md,
        "## Fig. 5: error of the cage level\n\n\
         The cylinders under `poke-a` run twice in lockstep, every body held at its cage level \
         in one run and at its precise level in the other; per step the mean and the largest \
         distance between the two runs' nodes of model A, as a percentage of A's smallest \
         dimension, and over the run the mean of the means and the largest (the paper: at \
         most 4 % against FEM, 8.1 % against MSD, box cage). Series in \
         `fig5_<precise>_<cage>.csv`.\n\n\
         | precise | cage | mean % | max % | cage step us |\n|---|---|---|---|---|"
    )?;
    let mut fig5 = Vec::new();
    let mut fig5_series: [Vec<Series>; 2] = [Vec::new(), Vec::new()];
    let mut best_fitted_vs_fem: Option<(String, f64, f64)> = None;
    for (precise, tag) in [
        (PreciseMethod::CorotationalFem, "fem"),
        (PreciseMethod::Msd, "msd"),
    ] {
        for (cage_name, kind) in &cages {
            progress.step(&format!("fig 5: {tag} vs {cage_name}"));
            let mut scene = Scene::paper_cylinders(precise, precise);
            for b in &mut scene.bodies {
                b.cage.kind = *kind;
            }
            let (series, cage_step) = compare_levels(&scene, "poke-a", steps, assets)?;
            let n = series.len().max(1) as f64;
            let mean = 100.0 * series.iter().map(|s| s.0).sum::<f64>() / n;
            let max = 100.0 * series.iter().map(|s| s.1).fold(0.0, f64::max);
            writeln!(
                md,
                "| {} | {cage_name} | {mean:.2} | {max:.2} | {} |",
                method_name(precise),
                us(Some(cage_step))
            )?;
            let mut csv = String::from("step,mean_pct,max_pct\n");
            for (k, (a, b)) in series.iter().enumerate() {
                writeln!(csv, "{},{},{}", k + 1, 100.0 * a, 100.0 * b)?;
            }
            let slot = usize::from(tag == "msd");
            for (which, pick) in [("max", true), ("mean", false)] {
                fig5_series[slot].push(Series {
                    name: format!("{cage_name} {which}"),
                    points: series
                        .iter()
                        .enumerate()
                        .map(|(k, (a, b))| ((k + 1) as f64, 100.0 * if pick { *b } else { *a }))
                        .collect(),
                    line: true,
                    markers: false,
                });
            }
            write_file(
                &args.out,
                &format!("fig5_{tag}_{}.csv", cage_name.replace(' ', "")),
                &csv,
            )?;
            if tag == "fem"
                && *kind != CageKind::BoundingBox
                && best_fitted_vs_fem.as_ref().is_none_or(|b| max < b.1)
            {
                best_fitted_vs_fem = Some((cage_name.clone(), max, cage_step));
            }
            fig5.push(json!({
                "precise": method_name(precise), "cage": cage_name,
                "mean_pct": mean, "max_pct": max, "cage_step_us": cage_step,
            }));
        }
    }
    for (slot, (tag, name)) in [("fem", "corotational FEM"), ("msd", "MSD (RK4)")]
        .into_iter()
        .enumerate()
    {
        chart(
            &args.out.join(format!("fig5_{tag}.png")),
            &format!("Fig. 5: cage level against {name}, cylinders, poke-a"),
            Axis {
                desc: "step",
                log: false,
            },
            Axis {
                desc: "node distance, % of smallest dimension",
                log: false,
            },
            &fig5_series[slot],
        )?;
    }
    writeln!(
        md,
        "\n![Fig. 5 against FEM](fig5_fem.png)\n![Fig. 5 against MSD](fig5_msd.png)\n"
    )?;
    js.insert("fig5".into(), json!(fig5));

    // Scaling with resting bodies.
    writeln!(
        md,
        "## Scaling: one touched organ and N resting ones\n\n\
         `poke-liver` on the organs scene plus N resting copies of its last body laid out \
         beside it; mean whole-step time, us, with level switching (the resting bodies stay \
         at their cage level) and without it (every body at its precise level).\n\n\
         | N resting | with switching | without switching |\n|---|---|---|"
    )?;
    let mut csv = String::from("resting,with_switching_us,without_switching_us\n");
    let mut scaling = Vec::new();
    let scaling_steps = steps.min(200);
    for &n in &resting {
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
                    steps: scaling_steps,
                    pin,
                    resting: n,
                },
                assets,
            )?
            .mean_step_us();
        }
        writeln!(md, "| {n} | {:.1} | {:.1} |", row[0], row[1])?;
        writeln!(csv, "{n},{},{}", row[0], row[1])?;
        scaling.push((n, row[0], row[1]));
    }
    chart(
        &args.out.join("scaling_resting.png"),
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
            Series {
                name: "with switching".into(),
                points: scaling.iter().map(|r| (r.0 as f64, r.1)).collect(),
                line: true,
                markers: true,
            },
            Series {
                name: "all precise".into(),
                points: scaling.iter().map(|r| (r.0 as f64, r.2)).collect(),
                line: true,
                markers: true,
            },
        ],
    )?;
    writeln!(
        md,
        "\n![scaling with resting bodies](scaling_resting.png)\n"
    )?;
    write_file(&args.out, "scaling.csv", &csv)?;
    js.insert(
        "scaling".into(),
        json!(
            scaling
                .iter()
                .map(|(n, a, b)| json!({"resting": n, "with_switching_us": a, "without_switching_us": b}))
                .collect::<Vec<_>>()
        ),
    );
    let mut step = |what: &str| progress.step(what);
    let budget = budget::budget_section(&mut md, &mut js, &args.out, assets, quick, &mut step)?;
    mesh_size_section(
        &mut md,
        &mut js,
        &args.out,
        &resolutions,
        quick,
        &all_cores,
        &mut step,
    )?;
    let sweep_points = speed_error_section(
        &mut md,
        &mut js,
        &args.out,
        assets,
        &sweep_configs,
        steps as f64 * 0.01,
        &mut step,
    )?;
    stability_section(
        &mut md, &mut js, &args.out, assets, &cases, quick, &mut step,
    )?;
    let peer_rows = peer_section(
        &mut md, &mut js, &args.out, assets, &peers, quick, &mut step,
    )?;
    progress.finish();

    // Goals.
    writeln!(md, "## Goals\n")?;
    let verdict = |ok: bool| if ok { "met" } else { "**missed**" };
    if let Some((name, max, cage_us)) = &best_fitted_vs_fem {
        let ratio = liver_precise.zip(liver_cage).map(|(p, c)| p / c);
        writeln!(
            md,
            "- Cage error below the paper's with a fitted cage (max < 4 % against FEM): best \
             fitted cage `{name}`, max {max:.2} %: {}. Cost: the liver's box-cage step (median) \
             is {} us against {} us corotational (ratio {}, goal >= 100: {}); the cylinder's \
             `{name}` cage step is {cage_us:.1} us.",
            verdict(*max < 4.0),
            us(liver_cage),
            us(liver_precise),
            ratio.map_or("-".into(), |r| format!("{r:.0}x")),
            ratio.map_or("undecided", |r| verdict(r >= 100.0)),
        )?;
    }
    writeln!(
        md,
        "- All four organs at their precise level under 1 ms per step: whole step {:.1} us: {}.",
        without_cage.mean_step_us(),
        verdict(without_cage.mean_step_us() < 1000.0)
    )?;
    if let (Some(first), Some(last)) = (scaling.first(), scaling.last()) {
        writeln!(
            md,
            "- {} resting bodies plus one touched under 2x one touched alone: {:.1} us against \
             {:.1} us ({:.2}x): {}.",
            last.0,
            last.1,
            first.1,
            last.1 / first.1,
            verdict(last.1 < 2.0 * first.1)
        )?;
    }
    for (scene, c) in &budget {
        if scene.contains("all precise") {
            let solve = c.stages.get("solve").map_or(0.0, |t| t.mean_us);
            if solve > 0.0 {
                let r = c.step.mean_us / solve;
                writeln!(
                    md,
                    "- Organs all precise: whole step at most 1.4x the sum of the solver steps: {r:.2}x: {}.",
                    verdict(r <= 1.4)
                )?;
            }
            continue;
        }
        if let Some(r) = c.worst_over_precise_median {
            writeln!(
                md,
                "- `{scene}`: largest whole step at most 3x the median of the steps with a precise body: {r:.2}x: {}.",
                verdict(r <= 3.0)
            )?;
        }
        if let Some(r) = c.contact_over_solve {
            writeln!(
                md,
                "- `{scene}`: contact (detect + collide) at most a third of the solvers: {r:.3}: {}.",
                verdict(r <= 0.33)
            )?;
        }
        let worst = c
            .bodies
            .iter()
            .filter_map(|b| b.worst_switch_ratio.map(|r| (r, b.name.as_str())))
            .max_by(|a, b| a.0.total_cmp(&b.0));
        if let Some((r, body)) = worst {
            writeln!(
                md,
                "- `{scene}`: every switch step at most 2x the body's median precise step: worst {r:.2}x ({body}): {}.",
                verdict(r <= 2.0)
            )?;
        }
    }
    let thread_rows = js
        .get("realtime_budget")
        .and_then(|b| b.get("threads"))
        .and_then(|t| t.as_array())
        .cloned()
        .unwrap_or_default();
    for row in &thread_rows {
        let (Some(scene), Some(n), Some(mean), Some(median), Some(same)) = (
            row["scene"].as_str(),
            row["threads"].as_u64(),
            row["speedup_mean"].as_f64(),
            row["speedup_median"].as_f64(),
            row["same_state"].as_bool(),
        ) else {
            continue;
        };
        writeln!(
            md,
            "- `{scene}` all precise at least 1.5x faster on {n} threads than on one, same \
             final state: mean {mean:.2}x, median {median:.2}x, state {}: {}.",
            if same { "identical" } else { "different" },
            verdict(same && mean >= 1.5)
        )?;
    }
    for r in &peer_rows {
        let faster = r.ours_median_us < r.rapier_median_us;
        let as_good = r.ours_error_pct <= r.rapier_error_pct;
        writeln!(
            md,
            "- Our corotational FEM step faster than rapier3d's FEM soft body on `{}` at equal or \
             smaller error against the fine reference: {:.1} us against {:.1} us ({:.1}x), \
             error {:.3} % against {:.3} %: {}.",
            r.mesh,
            r.ours_median_us,
            r.rapier_median_us,
            r.rapier_median_us / r.ours_median_us,
            r.ours_error_pct,
            r.rapier_error_pct,
            verdict(faster && as_good)
        )?;
    }
    if let Some(best) = sweep_points
        .iter()
        .filter(|p| p.config.family == "cage")
        .min_by(|a, b| a.max_pct.total_cmp(&b.max_pct))
    {
        writeln!(
            md,
            "- (Context from the sweep) the most accurate cage setting against the fine \
             corotational reference: `{}`, max {:.2} %, {:.1} us per step.",
            best.config.label, best.max_pct, best.median_us
        )?;
    }
    write_file(&args.out, "report.md", &md)?;
    js.insert("machine".into(), machine);
    js.insert("quick".into(), json!(quick));
    write_file(
        &args.out,
        "report.json",
        &serde_json::to_string_pretty(&serde_json::Value::Object(js))?,
    )?;
    println!("wrote {}", args.out.join("report.md").display());
    Ok(())
}

pub(crate) type Json = serde_json::Map<String, serde_json::Value>;

/// Step time against mesh size: the generated liver at several resolutions.
fn mesh_size_section(
    md: &mut String,
    js: &mut Json,
    out: &Path,
    resolutions: &[f64],
    quick: bool,
    threads: &soft_tissue_core::parallel::Threads,
    step: &mut dyn FnMut(&str),
) -> Res<()> {
    let steps = if quick { 20 } else { 200 };
    let rows = sweep::mesh_size(resolutions, steps, threads, step)?;
    let names: Vec<&str> = sweep::SIZE_METHODS.iter().map(|m| m.name()).collect();
    let n_all = threads.count();
    writeln!(
        md,
        "## Step time against mesh size\n\n\
         The generated liver at several resolutions (1 is the paper's mesh size) under \
         `soft-tissue bench`'s load (base held, a swinging force on the top), organ FEM \
         parameters, median of {steps} steps per method, us, on one thread / on {n_all} \
         threads (the same results; large bodies split their element loop). Cages: the box \
         and a fitted cage of about 64 vertices; their step is the cage MSD plus every surface \
         vertex.\n\n\
         | resolution | nodes | tets | surface vertices | {} |\n|---|---|---|---|{}",
        names.join(" | "),
        "---|".repeat(names.len())
    )?;
    let mut csv = format!(
        "resolution,nodes,tets,surface,{},{}\n",
        names.join(","),
        names
            .iter()
            .map(|n| format!("{n}_{n_all}_threads"))
            .collect::<Vec<_>>()
            .join(",")
    );
    for r in &rows {
        let cells: Vec<String> = r
            .median_us
            .iter()
            .zip(&r.median_all_us)
            .map(|(a, b)| match b {
                Some(_) => format!("{} / {}", us(*a), us(*b)),
                None => us(*a),
            })
            .collect();
        writeln!(
            md,
            "| {} | {} | {} | {} | {} |",
            r.resolution,
            r.nodes,
            r.tets,
            r.surface,
            cells.join(" | ")
        )?;
        let one: Vec<String> = r.median_us.iter().map(|v| us(*v)).collect();
        let all: Vec<String> = r.median_all_us.iter().map(|v| us(*v)).collect();
        writeln!(
            csv,
            "{},{},{},{},{},{}",
            r.resolution,
            r.nodes,
            r.tets,
            r.surface,
            one.join(","),
            all.join(",")
        )?;
    }
    let exponent = |all: bool| -> Vec<Option<f64>> {
        (0..names.len())
            .map(|k| sweep::growth_exponent(&rows, k, all))
            .collect()
    };
    let (exp_one, exp_all) = (exponent(false), exponent(true));
    let fmt_exp = |e: &Option<f64>| e.map_or("-".into(), |p| format!("{p:.2}"));
    writeln!(
        md,
        "| growth exponent (fit of time = a tets^p) | | | | {} |",
        exp_one
            .iter()
            .zip(&exp_all)
            .map(|(a, b)| if b.is_some() {
                format!("{} / {}", fmt_exp(a), fmt_exp(b))
            } else {
                fmt_exp(a)
            })
            .collect::<Vec<_>>()
            .join(" | ")
    )?;
    write_file(out, "mesh_size.csv", &csv)?;
    // Memory of the FEM methods.
    let fem: Vec<usize> = (0..names.len())
        .filter(|&k| rows.iter().any(|r| r.matrix_bytes[k].is_some()))
        .collect();
    writeln!(
        md,
        "\nMatrices and factors held per body (values and indices), MiB: the block system, \
         rest stiffness and block Cholesky factor of linear and corotational FEM; the scalar \
         Laplacian and per-axis-pattern scalar factor of the prefactored model.\n\n\
         | resolution | tets | {} |\n|---|---|{}",
        fem.iter()
            .map(|&k| names[k])
            .collect::<Vec<_>>()
            .join(" | "),
        "---|".repeat(fem.len())
    )?;
    for r in &rows {
        writeln!(
            md,
            "| {} | {} | {} |",
            r.resolution,
            r.tets,
            fem.iter()
                .map(|&k| r.matrix_bytes[k].map_or("-".into(), |b| format!(
                    "{:.2}",
                    b as f64 / (1024.0 * 1024.0)
                )))
                .collect::<Vec<_>>()
                .join(" | ")
        )?;
    }
    let series: Vec<Series> = names
        .iter()
        .enumerate()
        .map(|(k, name)| Series {
            name: (*name).into(),
            points: rows
                .iter()
                .filter_map(|r| r.median_us[k].map(|t| (r.nodes as f64, t)))
                .collect(),
            line: true,
            markers: true,
        })
        .collect();
    chart(
        &out.join("mesh_size.png"),
        "Step time against mesh size (generated liver, one thread)",
        Axis {
            desc: "nodes",
            log: true,
        },
        Axis {
            desc: "median step, us",
            log: true,
        },
        &series,
    )?;
    writeln!(md, "\n![step time against mesh size](mesh_size.png)\n")?;
    let per_method = |v: &[Option<f64>]| -> serde_json::Map<String, serde_json::Value> {
        names
            .iter()
            .zip(v)
            .map(|(n, e)| ((*n).to_string(), json!(e)))
            .collect()
    };
    js.insert(
        "mesh_size_growth_exponent".into(),
        json!({ "one_thread": per_method(&exp_one), "all_threads": per_method(&exp_all),
                "threads": n_all }),
    );
    js.insert(
        "mesh_size".into(),
        json!(
            rows.iter()
                .map(|r| json!({
                    "resolution": r.resolution, "nodes": r.nodes, "tets": r.tets,
                    "surface": r.surface,
                    "median_us": per_method(&r.median_us),
                    "median_all_threads_us": per_method(&r.median_all_us),
                    "matrix_bytes": names.iter().zip(&r.matrix_bytes)
                        .map(|(n, v)| ((*n).to_string(), json!(v)))
                        .collect::<serde_json::Map<_, _>>(),
                }))
                .collect::<Vec<_>>()
        ),
    );
    Ok(())
}

/// Speed against error: every level and setting against a fine-step corotational reference.
fn speed_error_section(
    md: &mut String,
    js: &mut Json,
    out: &Path,
    assets: &Path,
    configs: &[sweep::Config],
    duration: f64,
    step: &mut dyn FnMut(&str),
) -> Res<Vec<sweep::Point>> {
    let scene = load_scene("organs", assets)?;
    let (reference, points) =
        sweep::speed_against_error(&scene, assets, "poke-liver", configs, duration, step)?;
    writeln!(
        md,
        "## Speed against error\n\n\
         The organs under `poke-liver` for {duration} s, every body held at one level with one \
         setting; the liver's nodes against the {} (CG tolerance 1e-8) at the same times. \
         Time: the liver's median step (its heat field included), us. Error: mean and largest \
         node distance, % of the liver's smallest dimension. The MSD and the cages keep the paper's own parameters (not fitted to the \
         FEM material), so their error includes that model difference, as in Fig. 5. A setting \
         is on the Pareto front when no other is both faster and more accurate (largest \
         distance).\n\n\
         | setting | step us | mean % | max % | Pareto |\n|---|---|---|---|---|",
        reference.label
    )?;
    let mut csv = String::from("setting,family,dt,median_us,mean_pct,max_pct,pareto\n");
    let mut sorted: Vec<&sweep::Point> = points.iter().collect();
    sorted.sort_by(|a, b| a.median_us.total_cmp(&b.median_us));
    for p in &sorted {
        writeln!(
            md,
            "| {} | {:.1} | {:.3} | {:.3} | {} |",
            p.config.label,
            p.median_us,
            p.mean_pct,
            p.max_pct,
            if p.pareto { "yes" } else { "" }
        )?;
        writeln!(
            csv,
            "{},{},{},{},{},{},{}",
            p.config.label,
            p.config.family,
            p.config.dt,
            p.median_us,
            p.mean_pct,
            p.max_pct,
            p.pareto
        )?;
    }
    write_file(out, "speed_error.csv", &csv)?;
    let mut families: Vec<&str> = Vec::new();
    for p in &points {
        if !families.contains(&p.config.family) {
            families.push(p.config.family);
        }
    }
    let mut series: Vec<Series> = families
        .iter()
        .map(|f| Series {
            name: (*f).into(),
            points: points
                .iter()
                .filter(|p| p.config.family == *f)
                .map(|p| (p.median_us, p.max_pct))
                .collect(),
            line: false,
            markers: true,
        })
        .collect();
    let mut front: Vec<(f64, f64)> = sorted
        .iter()
        .filter(|p| p.pareto)
        .map(|p| (p.median_us, p.max_pct))
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    series.push(Series {
        name: "Pareto front".into(),
        points: front,
        line: true,
        markers: false,
    });
    chart(
        &out.join("speed_error.png"),
        "Speed against error (organs, poke-liver, the liver)",
        Axis {
            desc: "median step, us",
            log: true,
        },
        Axis {
            desc: "largest node distance to the reference, %",
            log: true,
        },
        &series,
    )?;
    writeln!(md, "\n![speed against error](speed_error.png)\n")?;
    js.insert(
        "speed_error".into(),
        json!({
            "reference": reference.label,
            "points": points.iter().map(|p| json!({
                "setting": p.config.label, "family": p.config.family, "dt": p.config.dt,
                "median_us": p.median_us, "mean_pct": p.mean_pct, "max_pct": p.max_pct,
                "pareto": p.pareto,
            })).collect::<Vec<_>>(),
        }),
    );
    Ok(points)
}

/// The solvers' hard cases and how each ended.
fn stability_section(
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
         most 1.01). Distances from rest as fractions of the width.\n\n\
         | case | solver | dt | outcome | inverted / flat at start | energy peak / end | \
         distance disturbed | distance at end |\n|---|---|---|---|---|---|---|---|"
    )?;
    let mut csv = String::from(
        "case,solver,dt,outcome,steps,inverted,flat,end_energy,peak_energy,disturbed_distance,final_distance\n",
    );
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
        let ratio = if r.end_energy > 0.0 {
            format!("{:.3}", r.peak_energy / r.end_energy)
        } else {
            "-".into()
        };
        writeln!(
            md,
            "| {} | {} | {:.4} | {} | {} / {} | {} | {:.3} | {:.2e} |",
            c.name,
            c.method_name(),
            r.dt,
            outcome,
            r.inverted,
            r.flat,
            ratio,
            r.disturbed_distance,
            r.final_distance
        )?;
        writeln!(
            csv,
            "{},{},{},\"{}\",{},{},{},{},{},{},{}",
            c.name,
            c.method_name(),
            r.dt,
            outcome.replace('"', "'"),
            r.steps,
            r.inverted,
            r.flat,
            r.end_energy,
            r.peak_energy,
            r.disturbed_distance,
            r.final_distance
        )?;
        rows.push(json!({
            "case": c.name, "solver": c.method_name(), "dt": r.dt, "outcome": outcome,
            "steps": r.steps, "end_energy": r.end_energy, "peak_energy": r.peak_energy,
            "final_distance": r.final_distance,
        }));
    }
    writeln!(md)?;
    write_file(out, "stability.csv", &csv)?;
    js.insert("stability".into(), json!(rows));
    Ok(())
}

/// Side by side with rapier3d's FEM soft bodies.
fn peer_section(
    md: &mut String,
    js: &mut Json,
    out: &Path,
    assets: &Path,
    peers: &[(&str, soft_tissue_core::material::FemParams, f64)],
    quick: bool,
    step: &mut dyn FnMut(&str),
) -> Res<Vec<peer::PeerRow>> {
    let duration = if quick { 0.5 } else { 10.0 };
    let mut rows = Vec::new();
    for (file, params, dt) in peers {
        step(&format!("rapier3d peer: {file}"));
        rows.push(peer::compare(assets, file, params, *dt, duration)?);
    }
    writeln!(
        md,
        "## Side by side with rapier3d 0.36 (FEM soft bodies)\n\n\
         rapier3d 0.36.1 (`fem` feature, `SoftBodySolver::Fem`, corotational cells, f32) and \
         our corotational FEM (f64) on the same tetrahedral mesh, Young's modulus, Poisson \
         ratio, lumped masses, fixed nodes (bottom 10 % along y) and time step, under the same \
         sideways body force, sized so our linear FEM's static tip deflection is 5 % of the \
         height; {duration} s from rest. Damping differs in kind (ours: mass-proportional \
         Rayleigh from the paper's parameters; rapier: its cells' damping ratio 1.0). \
         Reference: our corotational FEM at a tenth of the step, CG tolerance 1e-8. \
         Deflection: mean sideways displacement of the top 5 % nodes at the end. Error: \
         largest node distance to the reference at the end, % of the smallest dimension.\n\n\
         | mesh | nodes / tets | dt | ours us | rapier3d us | rapier / ours time | \
         deflection ours / rapier / reference | rapier / ours deflection | error ours % | \
         error rapier % | speed at end ours / rapier |\n|---|---|---|---|---|---|---|---|---|---|---|"
    )?;
    let mut csv = String::from(
        "mesh,nodes,tets,dt,steps,load,ours_median_us,rapier_median_us,ours_deflection,rapier_deflection,reference_deflection,ours_error_pct,rapier_error_pct,ours_speed,rapier_speed\n",
    );
    for r in &rows {
        writeln!(
            md,
            "| {} | {} / {} | {} | {:.1} | {:.1} | {:.2} | {:.4} / {:.4} / {:.4} | {:.3} | \
             {:.3} | {:.3} | {:.1e} / {:.1e} |",
            r.mesh,
            r.nodes,
            r.tets,
            r.dt,
            r.ours_median_us,
            r.rapier_median_us,
            r.rapier_median_us / r.ours_median_us,
            r.ours_deflection,
            r.rapier_deflection,
            r.reference_deflection,
            r.rapier_deflection / r.ours_deflection,
            r.ours_error_pct,
            r.rapier_error_pct,
            r.ours_speed,
            r.rapier_speed
        )?;
        writeln!(
            csv,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            r.mesh,
            r.nodes,
            r.tets,
            r.dt,
            r.steps,
            r.load,
            r.ours_median_us,
            r.rapier_median_us,
            r.ours_deflection,
            r.rapier_deflection,
            r.reference_deflection,
            r.ours_error_pct,
            r.rapier_error_pct,
            r.ours_speed,
            r.rapier_speed
        )?;
    }
    writeln!(md)?;
    write_file(out, "peer_rapier.csv", &csv)?;
    js.insert(
        "peer_rapier".into(),
        json!(
            rows.iter()
                .map(|r| json!({
                    "mesh": r.mesh, "nodes": r.nodes, "tets": r.tets, "dt": r.dt,
                    "ours_median_us": r.ours_median_us, "rapier_median_us": r.rapier_median_us,
                    "ours_deflection": r.ours_deflection, "rapier_deflection": r.rapier_deflection,
                    "reference_deflection": r.reference_deflection,
                    "ours_error_pct": r.ours_error_pct, "rapier_error_pct": r.rapier_error_pct,
                }))
                .collect::<Vec<_>>()
        ),
    );
    Ok(rows)
}
