//! `soft-tissue report`: the paper's tables and figure, speed against error, scaling,
//! stability and the rapier3d peer, measured in one run and written as Markdown, CSV, JSON and
//! PNG charts.
//!
//! Every number comes from running the scenes headless with the built-in scripts and loads;
//! nothing is copied. Goals are checked and a missed goal is reported as missed.

mod budget;
mod contact;
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

use tables::{organ_tables_section, paper_tables_section, scaling_section};

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
    /// Only the contact section (the contact cases against their closed forms).
    #[arg(long)]
    contact_only: bool,
}

fn median(v: &[f64]) -> Option<f64> {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s.get(s.len() / 2).copied()
}

/// MSD bodies step with RK4, as in the paper (scenes default to the implicit integrator).
fn paper_msd(s: &mut soft_tissue_core::precision::BodySettings) {
    if !s.precise.is_fem() {
        s.precise = LevelMethod::MsdRk4;
    }
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
        // A count that came out short grows rather than overflowing the bar.
        self.total = self.total.max(self.done);
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
    if args.contact_only {
        let mut progress = Progress {
            done: 0,
            total: contact::steps(quick),
            start: Instant::now(),
        };
        let mut md = String::from("# Contact only\n\n");
        let mut js = Json::new();
        let mut step = |what: &str| progress.step(what);
        contact::contact_section(&mut md, &mut js, &args.out, assets, quick, &mut step)?;
        progress.finish();
        print!("{md}");
        write_file(&args.out, "report.md", &md)?;
        write_file(
            &args.out,
            "report.json",
            &serde_json::to_string_pretty(&serde_json::Value::Object(js))?,
        )?;
        return Ok(());
    }
    if args.fig5_only {
        let mut progress = Progress {
            done: 0,
            total: 6 * cages.len(),
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
            + 6 * cages.len()
            + 2 * resting.len()
            + resolutions.len()
            + sweep_configs.len()
            + 2
            + cases.len()
            + peers.len()
            + 3
            + contact::steps(quick),
        start: Instant::now(),
    };
    let machine = crate::bench::machine();
    // The header goes on top at the end, once the spread it states has been measured.
    let mut md = String::new();
    let mut js = serde_json::Map::new();
    let mut probes = Vec::with_capacity(3);
    progress.step("spread probe 1/3");
    probes.push(spread_probe(quick)?);

    paper_tables_section(
        &mut md,
        &mut js,
        &args.out,
        assets,
        &pairs,
        steps,
        &mut progress,
    )?;
    let organs = load_scene("organs", assets)?;
    let organ_runs = organ_tables_section(
        &mut md,
        &mut js,
        &args.out,
        assets,
        &organs,
        steps,
        &mut progress,
    )?;

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

    let scaling = scaling_section(
        &mut md,
        &mut js,
        &args.out,
        assets,
        &organs,
        &resting,
        steps.min(200),
        &mut progress,
    )?;
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
    contact::contact_section(&mut md, &mut js, &args.out, assets, quick, &mut step)?;
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
            liver_cage: organ_runs.liver_cage_us,
            liver_precise: organ_runs.liver_precise_us,
            all_precise_step_us: organ_runs.all_precise_step_us,
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
