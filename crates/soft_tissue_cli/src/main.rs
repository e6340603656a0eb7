//! `soft-tissue`: command-line tool of bevy_soft_tissue (mesh inspection, conversion,
//! generation, scene files, cages, benchmarks, headless simulation).

mod bench;
mod cage;
mod haptics_bench;
mod logger;
mod mesh;
mod realtime;
mod report;
mod scene;
mod simulate;
mod tetrahedralize;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "soft-tissue",
    version,
    about = "Levels-of-precision soft-tissue simulation: mesh and scene tools"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Inspect, convert and generate tetrahedral meshes.
    #[command(subcommand)]
    Mesh(mesh::MeshCommand),
    /// Write the paper's scenes as RON files.
    #[command(subcommand)]
    Scene(scene::SceneCommand),
    /// Time the solvers per step on a mesh under a load that keeps it deforming
    /// (bottom 10 % fixed, a swinging force on the top 5 %, optional gravity).
    Bench(bench::BenchArgs),
    /// Build cages and deform meshes with Green coordinates.
    #[command(subcommand)]
    Cage(cage::CageCommand),
    /// Run a scene headless under a scripted tool (levels switching, contact, heat), with a
    /// JSON line per step on request.
    Simulate(simulate::SimulateArgs),
    /// Run a scene in real time while the 1 kHz haptic thread replays a session; print the
    /// haptic loop's period distribution, missed deadlines and force continuity.
    HapticsBench(haptics_bench::HapticsBenchArgs),
    /// Measure the paper's tables, the cage level's error and the scaling; write
    /// report.md, report.json and CSV series to a folder.
    Report(report::ReportArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    logger::install();
    let result = match cli.command {
        Command::Mesh(command) => mesh::run(command),
        Command::Scene(command) => scene::run(command),
        Command::Bench(args) => bench::bench(&args),
        Command::Simulate(args) => simulate::simulate(&args),
        Command::HapticsBench(args) => haptics_bench::haptics_bench(&args),
        Command::Report(args) => report::report(&args),
        Command::Cage(command) => cage::run(command),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// What a command returns: nothing, or the error printed before a non-zero exit.
type Res = Result<(), Box<dyn std::error::Error>>;
