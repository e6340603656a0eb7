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

/// A CSV table built in memory by the `csv` crate, so every file the report writes quotes
/// the same way (RFC 4180: a field holding a comma, a quote or a line break is put in quotes,
/// its quotes doubled).
pub(crate) struct Csv(csv::Writer<Vec<u8>>);

impl Csv {
    /// A table with its header row.
    pub(crate) fn new(header: &[&str]) -> Res<Self> {
        let mut w = csv::WriterBuilder::new()
            .terminator(csv::Terminator::Any(b'\n'))
            .from_writer(Vec::new());
        w.write_record(header)?;
        Ok(Csv(w))
    }

    /// One row; each cell is written with its `Display`.
    pub(crate) fn row<I>(&mut self, cells: I) -> Res<()>
    where
        I: IntoIterator,
        I::Item: std::fmt::Display,
    {
        self.0
            .write_record(cells.into_iter().map(|c| c.to_string()))?;
        Ok(())
    }

    /// Writes the table to `dir/name`.
    pub(crate) fn save(self, dir: &Path, name: &str) -> Res<()> {
        let bytes = self.0.into_inner().map_err(|e| e.to_string())?;
        write_file(dir, name, &String::from_utf8(bytes)?)
    }
}

/// A row of cells of mixed types, each written with its `Display`.
macro_rules! cells {
    ($($c:expr),* $(,)?) => { [$(($c).to_string()),*] };
}
pub(crate) use cells;

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
    let mut csv = Csv::new(&[
        "table",
        "script",
        "method_a",
        "method_b",
        "body",
        "cage_steps",
        "mean_cage_us",
        "precise_steps",
        "mean_precise_us",
        "switches",
        "worst_jump_pct",
    ])?;
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
                csv.row(cells![
                    table,
                    script,
                    method_name(a),
                    method_name(b),
                    body.name,
                    body.cage_steps,
                    us(body.mean_cage_us()),
                    body.precise_steps,
                    us(body.mean_precise_us()),
                    body.switches,
                    100.0 * body.worst_jump_ratio
                ])?;
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
    csv.save(&args.out, "tables_2_3.csv")?;
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
    let mut csv = Csv::new(&[
        "body",
        "with_cage_mean_cage_us",
        "with_cage_mean_precise_us",
        "without_cage_mean_precise_us",
    ])?;
    for (b, c) in with_cage.bodies.iter().zip(&without_cage.bodies) {
        let cells = [
            b.name.clone(),
            us(b.mean_cage_us()),
            us(b.mean_precise_us()),
            us(c.mean_precise_us()),
        ];
        writeln!(md, "| {} |", cells.join(" | "))?;
        csv.row(&cells)?;
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
    csv.save(&args.out, "tables_4_5.csv")?;
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
         at their cage level) and without it (every body at its precise level).\n\n\
         | N resting | with switching | without switching |\n|---|---|---|"
    )?;
    let mut csv = Csv::new(&["resting", "with_switching_us", "without_switching_us"])?;
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
        csv.row(cells![n, row[0], row[1]])?;
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
    csv.save(&args.out, "scaling.csv")?;
    js.insert(
        "scaling".into(),
        json!(
            scaling
                .iter()
                .map(|(n, a, b)| json!({"resting": n, "with_switching_us": a, "without_switching_us": b}))
                .collect::<Vec<_>>()
        ),
    );
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
        match &r.closed_form {
            Some(c) => writeln!(
                md,
                "- Our corotational FEM step faster than rapier3d's FEM soft body on `{}` at \
                 equal or smaller error against the closed form: {:.1} us against {:.1} us \
                 ({:.1}x); largest node distance {:.2} % against {:.2} % (mesh floor {:.2} %), \
                 end displacement {:.2} % against {:.2} % (mesh floor {:.2} %): {}.",
                r.mesh,
                r.ours_median_us,
                r.rapier_median_us,
                r.rapier_median_us / r.ours_median_us,
                c.ours_error_pct,
                c.rapier_error_pct,
                c.mesh_floor_pct,
                c.ours_tip_error_pct,
                c.rapier_tip_error_pct,
                c.floor_tip_error_pct,
                verdict(
                    faster
                        && c.ours_error_pct <= c.rapier_error_pct
                        && c.ours_tip_error_pct <= c.rapier_tip_error_pct
                )
            )?,
            None => writeln!(
                md,
                "- Our corotational FEM step faster than rapier3d's FEM soft body on `{}` (no \
                 closed form: speed only): {:.1} us against {:.1} us ({:.1}x): {}.",
                r.mesh,
                r.ours_median_us,
                r.rapier_median_us,
                r.rapier_median_us / r.ours_median_us,
                verdict(faster)
            )?,
        }
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

/// The paper's Fig. 5 section (see [`compare_levels`]): the cylinders under `poke-a` with
/// every cage of `cages`, moved by `dynamics`, against corotational FEM and MSD (RK4).
/// Returns the best fitted cage against FEM: name, max %, cage step us.
#[allow(clippy::too_many_arguments)]
fn fig5_section(
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
         `fig5_<precise>_<cage>_<dynamics>.csv`.\n\n\
         | precise | cage | paper mean % | paper max % | calibrated mean % | calibrated max % \
         | fit floor max % | cage step us, paper / calibrated |\n|---|---|---|---|---|---|---|---|"
    )?;
    let mut fig5 = Vec::new();
    let mut fig5_series: [Vec<Series>; 2] = [Vec::new(), Vec::new()];
    let mut best_fitted_vs_fem: Option<(String, f64, f64)> = None;
    for (precise, tag) in [
        (PreciseMethod::CorotationalFem, "fem"),
        (PreciseMethod::MsdImplicit, "msd"),
    ] {
        for (cage_name, kind) in cages {
            let mut row = Vec::new();
            let mut floor = (0.0f64, 0usize);
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
                floor = (this_floor, series.len() - fits.len());
                let mut csv = Csv::new(&["step", "mean_pct", "max_pct", "fit_floor_pct"])?;
                for (k, g) in series.iter().enumerate() {
                    csv.row(cells![
                        k + 1,
                        100.0 * g.mean,
                        100.0 * g.max,
                        g.fit.map_or(String::new(), |f| (100.0 * f).to_string())
                    ])?;
                }
                csv.save(
                    out,
                    &format!("fig5_{tag}_{}_{dyn_tag}.csv", cage_name.replace(' ', "")),
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
                row.push((mean, max, cage_step));
                fig5.push(json!({
                    "precise": method_name(precise), "cage": cage_name, "dynamics": dyn_tag,
                    "mean_pct": mean, "max_pct": max, "cage_step_us": cage_step,
                    "fit_floor_max_pct": this_floor,
                    "fit_unconverged_steps": series.len() - fits.len(),
                }));
            }
            writeln!(
                *md,
                "| {} | {cage_name} | {:.2} | {:.2} | {:.2} | {:.2} | {} | {} / {} |",
                method_name(precise),
                row[0].0,
                row[0].1,
                row[1].0,
                row[1].1,
                if floor.1 == 0 {
                    format!("{:.2}", floor.0)
                } else if floor.1 >= steps {
                    format!("- (no fit of the {steps} converged)")
                } else {
                    format!(
                        "{:.2} ({} of {steps} fits did not converge)",
                        floor.0, floor.1
                    )
                },
                us(Some(row[0].2)),
                us(Some(row[1].2)),
            )?;
        }
    }
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
    js.insert("fig5".into(), json!(fig5));
    Ok(best_fitted_vs_fem)
}

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
    let all_names: Vec<String> = names
        .iter()
        .map(|n| format!("{n}_{n_all}_threads"))
        .collect();
    let mut header = vec!["resolution", "nodes", "tets", "surface"];
    header.extend(names.iter().copied());
    header.extend(all_names.iter().map(String::as_str));
    let mut csv = Csv::new(&header)?;
    let mut failures = Vec::new();
    for r in &rows {
        let cells: Vec<String> = r
            .median_us
            .iter()
            .zip(&r.median_all_us)
            .map(|(a, b)| match b {
                Some(b) => format!("{} / {}", us_or_error(a), us_or_error(b)),
                None => us_or_error(a),
            })
            .collect();
        for (k, (a, b)) in r.median_us.iter().zip(&r.median_all_us).enumerate() {
            for e in [a.as_ref().err(), b.as_ref().and_then(|b| b.as_ref().err())]
                .into_iter()
                .flatten()
            {
                failures.push(format!("resolution {}, {}: {e}", r.resolution, names[k]));
            }
        }
        writeln!(
            md,
            "| {} | {} | {} | {} | {} |",
            r.resolution,
            r.nodes,
            r.tets,
            r.surface,
            cells.join(" | ")
        )?;
        let csv_cell = |v: &Result<f64, String>| match v {
            Ok(t) => t.to_string(),
            Err(e) => format!("failed: {e}"),
        };
        let mut row = cells![r.resolution, r.nodes, r.tets, r.surface].to_vec();
        row.extend(r.median_us.iter().map(csv_cell));
        row.extend(
            r.median_all_us
                .iter()
                .map(|v| v.as_ref().map_or("-".into(), csv_cell)),
        );
        csv.row(row)?;
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
    if !failures.is_empty() {
        writeln!(md, "\nFailed measurements (whole messages):\n")?;
        for f in &failures {
            writeln!(md, "- {}", f.replace(['\n', '\r'], " "))?;
        }
    }
    csv.save(out, "mesh_size.csv")?;
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
                .filter_map(|r| r.median_us[k].as_ref().ok().map(|t| (r.nodes as f64, *t)))
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
    fn by_name<T: serde::Serialize>(
        names: &[&str],
        v: &[T],
    ) -> serde_json::Map<String, serde_json::Value> {
        names
            .iter()
            .zip(v)
            .map(|(n, e)| ((*n).to_string(), json!(e)))
            .collect()
    }
    js.insert(
        "mesh_size_growth_exponent".into(),
        json!({ "one_thread": by_name(&names, &exp_one), "all_threads": by_name(&names, &exp_all),
                "threads": n_all }),
    );
    js.insert(
        "mesh_size".into(),
        json!(
            rows.iter()
                .map(|r| json!({
                    "resolution": r.resolution, "nodes": r.nodes, "tets": r.tets,
                    "surface": r.surface,
                    "median_us": by_name(&names, &r.median_us.iter().map(time_json).collect::<Vec<_>>()),
                    "median_all_threads_us": by_name(&names, &r.median_all_us.iter()
                        .map(|v| v.as_ref().map_or(serde_json::Value::Null, time_json))
                        .collect::<Vec<_>>()),
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
         node distance, % of the liver's smallest dimension. The cages are calibrated against \
         corotational FEM unless marked `paper` (the paper's cage MSD). `MSD` keeps the scene's \
         constant spring stiffness (the paper's); `MSD ... material` fits its springs to the \
         liver's FEM material. A setting is on the Pareto front when no other is both faster \
         and more accurate (largest distance).\n\n\
         The reference's own convergence: the same run at half its step ({}) is {:.4} % away \
         at most ({:.5} % mean).\n\n\
         | setting | step us | mean % | max % | Pareto |\n|---|---|---|---|---|",
        reference.config.label,
        reference.halved,
        reference.halving_max_pct,
        reference.halving_mean_pct,
    )?;
    let mut csv = Csv::new(&[
        "setting",
        "family",
        "dt",
        "median_us",
        "mean_pct",
        "max_pct",
        "pareto",
    ])?;
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
        csv.row(cells![
            p.config.label,
            p.config.family,
            p.config.dt,
            p.median_us,
            p.mean_pct,
            p.max_pct,
            p.pareto
        ])?;
    }
    csv.save(out, "speed_error.csv")?;
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
            "reference": reference.config.label,
            "reference_halved": reference.halved,
            "reference_halving_max_pct": reference.halving_max_pct,
            "reference_halving_mean_pct": reference.halving_mean_pct,
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
    let mut csv = Csv::new(&[
        "case",
        "solver",
        "dt",
        "outcome",
        "steps",
        "inverted",
        "flat",
        "end_energy",
        "peak_energy",
        "disturbed_distance",
        "final_distance",
    ])?;
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
        csv.row(cells![
            c.name,
            c.method_name(),
            r.dt,
            outcome,
            r.steps,
            r.inverted,
            r.flat,
            r.end_energy,
            r.peak_energy,
            r.disturbed_distance,
            r.final_distance
        ])?;
        rows.push(json!({
            "case": c.name, "solver": c.method_name(), "dt": r.dt, "outcome": outcome,
            "steps": r.steps, "end_energy": r.end_energy, "peak_energy": r.peak_energy,
            "final_distance": r.final_distance,
        }));
    }
    writeln!(md)?;
    csv.save(out, "stability.csv")?;
    js.insert("stability".into(), json!(rows));
    Ok(())
}

/// Side by side with rapier3d's FEM soft bodies.
fn peer_section(
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
         ours to be no larger on both measures.\n\n\
         | mesh | load | nodes / tets | dt | ours us | rapier3d us | rapier / ours time | \
         end displacement ours / rapier / closed form | largest distance % ours / rapier / \
         mesh floor | end error % ours / rapier / mesh floor | speed at end ours / rapier \
         |\n|---|---|---|---|---|---|---|---|---|---|---|"
    )?;
    let mut csv = Csv::new(&[
        "mesh",
        "protocol",
        "nodes",
        "tets",
        "dt",
        "steps",
        "load",
        "ours_median_us",
        "rapier_median_us",
        "ours_tip",
        "rapier_tip",
        "closed_form_tip",
        "ours_error_pct",
        "rapier_error_pct",
        "mesh_floor_pct",
        "ours_tip_error_pct",
        "rapier_tip_error_pct",
        "floor_tip_error_pct",
        "ours_speed",
        "rapier_speed",
    ])?;
    let opt = |v: Option<f64>, digits: usize| v.map_or("-".into(), |v| format!("{v:.digits$}"));
    for r in &rows {
        let c = r.closed_form.as_ref();
        let protocol = match r.protocol {
            peer::Protocol::AxialBar => "axial bar, closed form",
            peer::Protocol::Sideways => "sideways, bottom 10 % held (no closed form)",
        };
        writeln!(
            md,
            "| {} | {protocol} | {} / {} | {} | {:.1} | {:.1} | {:.2} | {:.4} / {:.4} / {} | \
             {} / {} / {} | {} / {} / {} | {:.1e} / {:.1e} |",
            r.mesh,
            r.nodes,
            r.tets,
            r.dt,
            r.ours_median_us,
            r.rapier_median_us,
            r.rapier_median_us / r.ours_median_us,
            r.ours_tip,
            r.rapier_tip,
            opt(c.map(|c| c.tip), 4),
            opt(c.map(|c| c.ours_error_pct), 2),
            opt(c.map(|c| c.rapier_error_pct), 2),
            opt(c.map(|c| c.mesh_floor_pct), 2),
            opt(c.map(|c| c.ours_tip_error_pct), 2),
            opt(c.map(|c| c.rapier_tip_error_pct), 2),
            opt(c.map(|c| c.floor_tip_error_pct), 2),
            r.ours_speed,
            r.rapier_speed
        )?;
        let raw = |v: Option<f64>| v.map_or(String::new(), |v| v.to_string());
        csv.row(cells![
            r.mesh,
            protocol,
            r.nodes,
            r.tets,
            r.dt,
            r.steps,
            r.load,
            r.ours_median_us,
            r.rapier_median_us,
            r.ours_tip,
            r.rapier_tip,
            raw(c.map(|c| c.tip)),
            raw(c.map(|c| c.ours_error_pct)),
            raw(c.map(|c| c.rapier_error_pct)),
            raw(c.map(|c| c.mesh_floor_pct)),
            raw(c.map(|c| c.ours_tip_error_pct)),
            raw(c.map(|c| c.rapier_tip_error_pct)),
            raw(c.map(|c| c.floor_tip_error_pct)),
            r.ours_speed,
            r.rapier_speed
        ])?;
    }
    writeln!(md)?;
    csv.save(out, "peer_rapier.csv")?;
    js.insert(
        "peer_rapier".into(),
        json!({
            "reference": "closed form: prismatic bar clamped at one end under a uniform axial \
                          body force, Poisson ratio 0, u(s) = (rho g / E) (L s - s^2 / 2)",
            "rows": rows.iter()
                .map(|r| json!({
                    "mesh": r.mesh, "protocol": format!("{:?}", r.protocol),
                    "nodes": r.nodes, "tets": r.tets, "dt": r.dt, "steps": r.steps,
                    "load": r.load,
                    "ours_median_us": r.ours_median_us, "rapier_median_us": r.rapier_median_us,
                    "ours_tip": r.ours_tip, "rapier_tip": r.rapier_tip,
                    "closed_form_tip": r.closed_form.as_ref().map(|c| c.tip),
                    "ours_error_pct": r.closed_form.as_ref().map(|c| c.ours_error_pct),
                    "rapier_error_pct": r.closed_form.as_ref().map(|c| c.rapier_error_pct),
                    "mesh_floor_pct": r.closed_form.as_ref().map(|c| c.mesh_floor_pct),
                    "ours_tip_error_pct": r.closed_form.as_ref().map(|c| c.ours_tip_error_pct),
                    "rapier_tip_error_pct": r.closed_form.as_ref().map(|c| c.rapier_tip_error_pct),
                    "floor_tip_error_pct": r.closed_form.as_ref().map(|c| c.floor_tip_error_pct),
                    "ours_speed": r.ours_speed, "rapier_speed": r.rapier_speed,
                }))
                .collect::<Vec<_>>(),
        }),
    );
    Ok(rows)
}

/// A peer comparison: mesh file, FEM parameters, time step and protocol.
type Peer = (
    &'static str,
    soft_tissue_core::material::FemParams,
    f64,
    peer::Protocol,
);

#[cfg(test)]
mod tests {
    use super::*;

    fn out_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!(
            "soft-tissue-report-test-{name}-{}",
            std::process::id()
        ));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn read_back(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
        let mut r = csv::Reader::from_path(path).unwrap();
        let header = r.headers().unwrap().iter().map(String::from).collect();
        let rows = r
            .records()
            .map(|rec| rec.unwrap().iter().map(String::from).collect())
            .collect();
        (header, rows)
    }

    /// A cell with a comma, a quote and a line break comes back whole from a real CSV
    /// parser, the other columns in place.
    #[test]
    fn csv_cells_with_commas_and_quotes_read_back_intact() {
        let dir = out_dir("csv");
        let name = "a \"quoted\", name\nover two lines";
        let mut csv = Csv::new(&["name", "value", "flag"]).unwrap();
        csv.row(cells![name, 1.5, true]).unwrap();
        csv.row(cells!["plain", -2, false]).unwrap();
        csv.save(&dir, "t.csv").unwrap();
        let (header, rows) = read_back(&dir.join("t.csv"));
        assert_eq!(header, ["name", "value", "flag"]);
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0], [name, "1.5", "true"]);
        assert_eq!(rows[1], ["plain", "-2", "false"]);
        std::fs::remove_dir_all(dir).ok();
    }

    /// `stability.csv` keeps its columns for a case whose name has a comma and a quote (the
    /// hard cases' own names have commas: "dt 3x its limit, refuse"); it used to be written
    /// with the name unquoted, one column too many.
    #[test]
    fn stability_csv_keeps_its_columns_for_names_with_commas_and_quotes() {
        let dir = out_dir("stability");
        let mut case = HardCase::all()
            .into_iter()
            .find(|c| c.name == "dt 3x its limit, refuse")
            .expect("the refusing RK4 case");
        case.name = "dt 3x its \"limit\", refuse";
        let assets = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets"));
        let (mut md, mut js) = (String::new(), Json::new());
        stability_section(&mut md, &mut js, &dir, assets, &[case], true, &mut |_| {}).unwrap();
        let (header, rows) = read_back(&dir.join("stability.csv"));
        assert_eq!(header.len(), 11);
        assert_eq!(header[0], "case");
        assert_eq!(header[3], "outcome");
        assert_eq!(rows.len(), 1);
        assert_eq!(rows[0].len(), 11);
        assert_eq!(rows[0][0], "dt 3x its \"limit\", refuse");
        assert_eq!(rows[0][1], "MSD RK4");
        assert!(rows[0][3].starts_with("refused"), "{}", rows[0][3]);
        assert!(rows[0][4].parse::<usize>().is_ok(), "steps: {}", rows[0][4]);
        std::fs::remove_dir_all(dir).ok();
    }

    /// A measurement that failed shows a short form of its error in the table, the whole
    /// message in the JSON (it used to be a bare "-").
    #[test]
    fn a_failed_measurement_shows_its_error() {
        let long = "matrix not positive definite at degree of freedom 12 (node 4, axis 0): the \
                    body may lack constraints against rigid motion | or a parameter is bad";
        let cell = us_or_error(&Err(long.to_string()));
        assert!(
            cell.starts_with("failed: matrix not positive definite"),
            "{cell}"
        );
        assert!(cell.ends_with("..."), "{cell}");
        assert!(cell.len() < 80 && !cell.contains('|'), "{cell}");
        assert_eq!(us_or_error(&Ok(12.345)), "12.3");
        assert_eq!(time_json(&Err(long.to_string()))["error"], long);
        assert_eq!(time_json(&Ok(2.5)), json!(2.5));
    }

    /// The header's spread sentence states the repeats it was given and their ratio.
    #[test]
    fn the_spread_sentence_states_the_measured_ratio() {
        let s = spread_sentence(&[100.0, 110.0, 105.0], true);
        assert!(s.contains("100.0 / 110.0 / 105.0 us"), "{s}");
        assert!(s.contains("largest over smallest 1.10 (10 %)"), "{s}");
        assert!(s.contains("3 times"), "{s}");
    }
}
