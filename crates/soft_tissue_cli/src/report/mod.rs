//! `soft-tissue report`: the paper's tables and figure, speed against error, scaling,
//! stability and the rapier3d peer, measured in one run and written as Markdown, CSV, JSON and
//! PNG charts.
//!
//! Every number comes from running the scenes headless with the built-in scripts and loads;
//! nothing is copied. Goals are checked and a missed goal is reported as missed.

mod budget;
mod fig5;
mod goals;
mod mesh_size;
mod peer;
mod peer_section;
mod plots;
mod speed_error;
mod stability;
mod sweep;
mod table;
mod tables;

use tables::{OrganTableRow, PaperTableRow, ScalingRow};

pub(crate) use table::{Csv, ReportRow, cells, write_file, write_rows};

use fig5::fig5_section;
use mesh_size::mesh_size_section;
use peer_section::peer_section;
use speed_error::speed_error_section;
use stability::stability_section;

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use serde_json::json;
use soft_tissue_core::cage::CageDynamics;
use soft_tissue_core::contact::Tool;
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
    /// Run only the speed-against-error sweep (printed, and written to
    /// `speed_against_error.md` and its CSV in `--out`), not the whole report.
    #[arg(long)]
    only_sweep: bool,
    /// With `--only-sweep`: only the settings whose family contains this text (for example
    /// `BDF2`, `cage`).
    #[arg(long, requires = "only_sweep")]
    sweep_family: Option<String>,
    /// With `--only-sweep`: run each chosen family at these multiples of the paper's step
    /// instead of the report's own list (for example `1,0.5,0.25` for an order of
    /// convergence).
    #[arg(long, value_delimiter = ',', requires = "only_sweep")]
    sweep_scales: Option<Vec<f64>>,
    /// Only the Fig. 5 section (the cage level's error, paper and calibrated cage
    /// dynamics), for quick comparisons of cage settings.
    #[arg(long)]
    fig5_only: bool,
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
    if !s.precise.is_fem() {
        s.precise = LevelMethod::MsdRk4;
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

/// The reference measurement the header's run-to-run spread comes from: the median step of
/// corotational FEM on the generated liver (resolution 1, organ parameters, the bench load,
/// one thread), us. The report takes it at its start, middle and end.
fn spread_probe(quick: bool) -> Res<f64> {
    use soft_tissue_core::bench::{BenchBody, BenchMethod};
    use soft_tissue_core::mesh::generate::Organ;
    use soft_tissue_core::scenario::CYLINDER_MSD;
    let steps = if quick { 20 } else { 200 };
    let mesh = Organ::Liver.generate(1.0)?;
    let m = BenchMethod::FemCorotational;
    let mut body = BenchBody::new(
        &mesh,
        m,
        (&ORGAN_FEM.params, ORGAN_FEM.dt),
        (&CYLINDER_MSD.params, CYLINDER_MSD.dt),
        false,
        64,
    )?;
    let one = soft_tissue_core::parallel::Threads::new(1)?;
    Ok(one.run(|| body.run(m, &mesh, steps / 10, steps))?.median_us)
}

/// The header's sentence on the run-to-run spread, from the probe's repeats (us).
fn spread_sentence(probes: &[f64], quick: bool) -> String {
    let lo = probes.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = probes.iter().copied().fold(0.0, f64::max);
    format!(
        "Run-to-run spread, measured in this run: the same reference measurement (median \
         corotational FEM step of the generated liver at resolution 1, {} steps, one thread) \
         taken {} times spread over the run gave {} us, largest over smallest {:.2} ({:.0} %). \
         Differences between settings smaller than that are not resolved.",
        if quick { 20 } else { 200 },
        probes.len(),
        probes
            .iter()
            .map(|p| format!("{p:.1}"))
            .collect::<Vec<_>>()
            .join(" / "),
        hi / lo,
        100.0 * (hi / lo - 1.0),
    )
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

/// A measured time, us, or a short form of the error that stopped the measurement, for a
/// Markdown cell (the JSON keeps the whole message).
fn us_or_error(v: &Result<f64, String>) -> String {
    match v {
        Ok(t) => format!("{t:.1}"),
        Err(e) => format!("failed: {}", short_error(e)),
    }
}

/// The first 60 characters of an error message, cut at a word, without the characters that
/// would break a Markdown table.
fn short_error(e: &str) -> String {
    let clean: String = e
        .chars()
        .map(|c| {
            if matches!(c, '|' | '\n' | '\r') {
                ' '
            } else {
                c
            }
        })
        .collect();
    if clean.chars().count() <= 60 {
        return clean;
    }
    let cut: String = clean.chars().take(60).collect();
    let cut = cut.rsplit_once(' ').map_or(cut.as_str(), |(head, _)| head);
    format!("{cut}...")
}

/// A measured time for the JSON: the number, or `{"error": message}`.
fn time_json(v: &Result<f64, String>) -> serde_json::Value {
    match v {
        Ok(t) => json!(t),
        Err(e) => json!({ "error": e }),
    }
}

fn method_name(m: PreciseMethod) -> &'static str {
    match m {
        PreciseMethod::LinearFem => "FEM linear",
        PreciseMethod::CorotationalFem => "FEM corotational",
        PreciseMethod::PrefactoredFem => "FEM corotational prefactored",
        // The report's MSD bodies step with RK4 (`paper_msd`).
        _ => "MSD (RK4)",
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
    if args.only_sweep {
        let (mut md, mut js) = (String::new(), serde_json::Map::new());
        let configs = sweep::select(
            sweep::configs(quick, ORGAN_FEM.dt),
            args.sweep_family.as_deref(),
            args.sweep_scales.as_deref(),
            ORGAN_FEM.dt,
        )?;
        speed_error_section(
            &mut md,
            &mut js,
            &args.out,
            assets,
            &configs,
            steps as f64 * 0.01,
            &mut |what: &str| eprintln!("{what}"),
        )?;
        let path = args.out.join("speed_against_error.md");
        std::fs::write(&path, &md).map_err(|e| format!("{}: {e}", path.display()))?;
        println!("{md}");
        return Ok(());
    }
    let pairs = [
        (PreciseMethod::LinearFem, PreciseMethod::LinearFem),
        (PreciseMethod::MsdImplicit, PreciseMethod::MsdImplicit),
        (PreciseMethod::LinearFem, PreciseMethod::MsdImplicit),
        (PreciseMethod::MsdImplicit, PreciseMethod::LinearFem),
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
    if args.fig5_only {
        let mut progress = Progress {
            done: 0,
            total: 4 * cages.len(),
            start: Instant::now(),
        };
        let mut md = String::from("# Fig. 5 only\n\n");
        let mut js = Json::new();
        fig5_section(
            &mut md,
            &mut js,
            &args.out,
            assets,
            &cages,
            steps,
            &mut progress,
        )?;
        progress.finish();
        write_file(&args.out, "report.md", &md)?;
        js.insert("quick".into(), json!(quick));
        write_file(
            &args.out,
            "report.json",
            &serde_json::to_string_pretty(&serde_json::Value::Object(js))?,
        )?;
        println!("wrote {}", args.out.join("report.md").display());
        return Ok(());
    }
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
    let peers: [Peer; 2] = [
        (
            "meshes/cylinder.vtk",
            CYLINDER_FEM.params,
            CYLINDER_FEM.dt,
            peer::Protocol::AxialBar,
        ),
        (
            "meshes/liver.vtk",
            ORGAN_FEM.params,
            ORGAN_FEM.dt,
            peer::Protocol::Sideways,
        ),
    ];
    let mut progress = Progress {
        done: 0,
        total: 2 * pairs.len()
            + 2
            + 4 * cages.len()
            + 2 * resting.len()
            + resolutions.len()
            + sweep_configs.len()
            + 2
            + cases.len()
            + peers.len()
            + 3
            + 7,
        start: Instant::now(),
    };
    let machine = crate::machine();
    // The header goes on top at the end, once the spread it states has been measured.
    let mut md = String::new();
    let mut js = serde_json::Map::new();
    let mut probes = Vec::with_capacity(3);
    progress.step("spread probe 1/3");
    probes.push(spread_probe(quick)?);

    // Tables II and III.
    let mut rows: Vec<PaperTableRow> = Vec::new();
    for (table, script) in [("II", "poke-a"), ("III", "push-a-into-b")] {
        writeln!(
            md,
            "## Table {table}: cylinders, `{script}`\n\n\
             Mean step time per body and level, us (the paper's Table {table} layout: each \
             method pair, each body at its cage level and at its precise level).\n"
        )?;
        let first = rows.len();
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
        md.push_str(&table::md_table(&rows[first..]));
        writeln!(md)?;
    }
    write_file(&args.out, "tables_2_3.csv", &table::csv_text(&rows)?)?;
    js.insert("tables_2_3".into(), serde_json::to_value(&rows)?);

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
    let organ_json = write_rows(&organ_rows, &mut md, &args.out, "tables_4_5.csv")?;
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
    let liver_cage = with_cage.bodies.first().and_then(BodyStats::median_cage_us);
    let liver_precise = without_cage
        .bodies
        .first()
        .and_then(BodyStats::median_precise_us);

    // Fig. 5: the cage level's error under the interaction, against the precise level.
    let best_fitted_vs_fem = fig5_section(
        &mut md,
        &mut js,
        &args.out,
        assets,
        &cages,
        steps,
        &mut progress,
    )?;

    // Scaling with resting bodies.
    writeln!(
        md,
        "## Scaling: one touched organ and N resting ones\n\n\
         `poke-liver` on the organs scene plus N resting copies of its last body laid out \
         beside it; mean whole-step time, us, with level switching (the resting bodies stay \
         at their cage level) and without it (every body at its precise level).\n"
    )?;
    let mut scaling_rows = Vec::new();
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
        scaling_rows.push(ScalingRow {
            resting: n,
            with_switching_us: row[0],
            without_switching_us: row[1],
        });
        scaling.push((n, row[0], row[1]));
    }
    let scaling_json = write_rows(&scaling_rows, &mut md, &args.out, "scaling.csv")?;
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
    js.insert("scaling".into(), scaling_json);
    progress.step("spread probe 2/3");
    probes.push(spread_probe(quick)?);
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
    progress.step("spread probe 3/3");
    probes.push(spread_probe(quick)?);
    progress.finish();
    let mut header = String::new();
    writeln!(
        header,
        "# Levels of precision: measured report\n\n\
         Generated by `soft-tissue report{}` on {} ({}, {} cores, {} build, worlds on {} \
         thread(s); bench tables on one thread unless stated).\n\
         Step times are wall-clock means over the run's steps at each level unless stated. {}\n",
        if quick { " --quick" } else { "" },
        today(),
        machine["cpu"].as_str().unwrap_or("unknown"),
        machine["cores"],
        machine["profile"].as_str().unwrap_or("unknown"),
        threads.count(),
        spread_sentence(&probes, quick),
    )?;
    if quick {
        writeln!(
            header,
            "**Quick run** ({steps} steps, fewer cages and sizes): a smoke test of the \
             command; the committed report is the full run.\n"
        )?;
    }
    md.insert_str(0, &header);
    let probe_steps = if quick { 20 } else { 200 };
    js.insert(
        "run_to_run_spread".into(),
        json!({
            "probe": "median corotational FEM step, generated liver at resolution 1, one thread",
            "steps": probe_steps,
            "median_us": probes,
            "max_over_min": probes.iter().copied().fold(0.0, f64::max)
                / probes.iter().copied().fold(f64::INFINITY, f64::min),
        }),
    );

    goals::goals_section(
        &mut md,
        &js,
        &goals::Inputs {
            best_fitted_vs_fem: &best_fitted_vs_fem,
            liver_cage,
            liver_precise,
            all_precise_step_us: without_cage.mean_step_us(),
            scaling: &scaling,
            budget: &budget,
            peer_rows: &peer_rows,
            sweep_points: &sweep_points,
        },
    )?;
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

/// A peer comparison: mesh file, FEM parameters, time step and protocol.
type Peer = (
    &'static str,
    soft_tissue_core::material::FemParams,
    f64,
    peer::Protocol,
);

#[cfg(test)]
mod tests;
