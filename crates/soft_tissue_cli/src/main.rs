//! `soft-tissue`: command-line tool of bevy_soft_tissue (mesh inspection, conversion,
//! generation, scene files).

use clap::{Args, Parser, Subcommand};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::generate::Organ;
use soft_tissue_core::mesh::io::{self, WriteOptions};
use soft_tissue_core::scenario::{PreciseMethod, Scene};
use std::path::{Path, PathBuf};
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
    Mesh(MeshCommand),
    /// Write the paper's scenes as RON files.
    #[command(subcommand)]
    Scene(SceneCommand),
    /// Time the precise solvers per step on a mesh under a load that keeps it deforming
    /// (bottom 10 % fixed, gravity, a swinging force on the top 5 %).
    Bench(BenchArgs),
}

#[derive(Args)]
struct BenchArgs {
    /// Mesh file (.msh, .vtk, .vtu, .node).
    #[arg(
        long,
        conflicts_with = "generated",
        required_unless_present = "generated"
    )]
    mesh: Option<PathBuf>,
    /// A generated body: cylinder, liver, spleen, stomach, pancreas.
    #[arg(long)]
    generated: Option<String>,
    /// Resolution of a generated body (1 = the paper's mesh size).
    #[arg(long, default_value_t = 1.0)]
    resolution: f64,
    /// fem-linear, fem-corotational, msd-rk4, msd-symplectic, msd-implicit, or all.
    #[arg(long, default_value = "all")]
    method: String,
    /// Material: the paper's cylinder or organ FEM parameters; MSD always uses the paper's
    /// cylinder MSD. Default: cylinder for a body named cylinder, organ otherwise.
    #[arg(long)]
    params: Option<String>,
    /// Add gravity (9.81 along -y). Off by default: with the paper's cylinder parameters a
    /// nonlinear model buckles under its own weight, which times a collapse, not a poke.
    #[arg(long)]
    gravity: bool,
    /// Timed steps.
    #[arg(long, default_value_t = 1000)]
    steps: usize,
    /// CG relative tolerance of the implicit methods (default: the method's own, 1e-4 for
    /// corotational FEM, 1e-6 for implicit MSD).
    #[arg(long)]
    cg_tolerance: Option<f64>,
    /// CG iteration cap of the implicit methods (default: the method's own).
    #[arg(long)]
    cg_max_iterations: Option<u32>,
    /// Untimed steps before timing.
    #[arg(long, default_value_t = 100)]
    warmup: usize,
    /// Print one JSON object (an array with --method all).
    #[arg(long)]
    json: bool,
}

#[derive(Subcommand)]
enum MeshCommand {
    /// Print counts, bounding box, volume, element quality and warnings of a mesh file
    /// (.msh, .vtk, .vtu, .node/.ele). Exits non-zero with the error on bad input.
    Info {
        /// The mesh file.
        file: PathBuf,
        /// Print one JSON object instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Convert between formats; the output format follows OUT's extension
    /// (.msh = Gmsh 2.2, .vtk, .vtu, .node/.ele = TetGen, .obj = boundary surface only).
    Convert {
        /// Input mesh file.
        input: PathBuf,
        /// Output file.
        output: PathBuf,
        /// Write binary data where the format allows it (Gmsh, legacy VTK, VTU base64).
        #[arg(long)]
        binary: bool,
    },
    /// Generate the paper's cylinder or organ-like meshes with the built-in mesher and write
    /// them as legacy VTK files (NAME.vtk) into DIR. Same command, same bytes.
    Generate(GenerateArgs),
}

#[derive(Args)]
struct GenerateArgs {
    /// cylinder, liver, spleen, stomach, pancreas, or organs (all four, placed touching).
    body: String,
    /// Resolution: 1 reproduces the paper's mesh sizes; 2 halves the lattice spacing.
    #[arg(long, default_value_t = 1.0)]
    resolution: f64,
    /// Output folder (created if missing).
    #[arg(long)]
    out: PathBuf,
}

#[derive(Subcommand)]
enum SceneCommand {
    /// Write cylinders.ron and organs.ron (the paper's parameters) into DIR.
    Export {
        /// Output folder (created if missing).
        #[arg(long)]
        out: PathBuf,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Mesh(MeshCommand::Info { file, json }) => info(&file, json),
        Command::Mesh(MeshCommand::Convert {
            input,
            output,
            binary,
        }) => convert(&input, &output, binary),
        Command::Mesh(MeshCommand::Generate(args)) => generate(&args),
        Command::Scene(SceneCommand::Export { out }) => export_scenes(&out),
        Command::Bench(args) => bench(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

type Res = Result<(), Box<dyn std::error::Error>>;

fn info(file: &Path, json: bool) -> Res {
    let loaded = io::read_tet_mesh(file)?;
    let m = &loaded.mesh;
    let q = m.quality();
    let b = m.bbox();
    if json {
        let v = serde_json::json!({
            "file": file.display().to_string(),
            "nodes": m.node_count(),
            "tets": m.tet_count(),
            "surface_triangles": m.surface().triangles().len(),
            "surface_vertices": m.surface().vertices().len(),
            "edges": m.edges().len(),
            "volume": m.volume(),
            "bbox_min": [b.min.x, b.min.y, b.min.z],
            "bbox_max": [b.max.x, b.max.y, b.max.z],
            "components": m.component_count(),
            "quality": q,
            "warnings": loaded.notes,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!("file:              {}", file.display());
        println!("nodes:             {}", m.node_count());
        println!("tetrahedra:        {}", m.tet_count());
        println!(
            "surface:           {} triangles, {} vertices",
            m.surface().triangles().len(),
            m.surface().vertices().len()
        );
        println!("edges:             {}", m.edges().len());
        println!("volume:            {:.6}", m.volume());
        println!(
            "bounding box:      [{:.4}, {:.4}, {:.4}] .. [{:.4}, {:.4}, {:.4}]",
            b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z
        );
        println!("components:        {}", m.component_count());
        println!(
            "dihedral angles:   {:.2} .. {:.2} degrees (worst tet {})",
            q.min_dihedral_deg, q.max_dihedral_deg, q.worst_tet
        );
        println!(
            "aspect ratio:      max {:.3}, mean {:.3} (1 = regular)",
            q.max_aspect_ratio, q.mean_aspect_ratio
        );
        println!(
            "tet volume:        {:.3e} .. {:.3e}",
            q.min_volume, q.max_volume
        );
        for n in &loaded.notes {
            println!("warning:           {n}");
        }
    }
    Ok(())
}

fn convert(input: &Path, output: &Path, binary: bool) -> Res {
    let loaded = io::read_tet_mesh(input)?;
    for n in &loaded.notes {
        eprintln!("warning: {n}");
    }
    io::write_tet_mesh(&loaded.mesh, output, WriteOptions { binary })?;
    println!(
        "wrote {} ({} nodes, {} tetrahedra)",
        output.display(),
        loaded.mesh.node_count(),
        loaded.mesh.tet_count()
    );
    Ok(())
}

fn write_generated(mesh: &TetMesh, organ: Organ, dir: &Path) -> Res {
    let path = dir.join(format!("{}.vtk", organ.name()));
    io::write_tet_mesh(mesh, &path, WriteOptions::default())?;
    let (pn, pt, ps) = organ.paper_counts();
    println!(
        "{:9} nodes {:5} (paper {pn}), tets {:5} (paper {pt}), surface triangles {:5} (paper {ps}), min dihedral {:.1} deg -> {}",
        organ.name(),
        mesh.node_count(),
        mesh.tet_count(),
        mesh.surface().triangles().len(),
        mesh.quality().min_dihedral_deg,
        path.display()
    );
    Ok(())
}

fn generate(args: &GenerateArgs) -> Res {
    let organs: Vec<Organ> = if args.body == "organs" {
        Organ::ORGANS.to_vec()
    } else {
        vec![args.body.parse::<Organ>()?]
    };
    std::fs::create_dir_all(&args.out)?;
    for organ in organs {
        let mesh = organ.generate(args.resolution)?;
        write_generated(&mesh, organ, &args.out)?;
    }
    Ok(())
}

fn export_scenes(out: &Path) -> Res {
    std::fs::create_dir_all(out)?;
    let scenes = [
        Scene::paper_cylinders(PreciseMethod::LinearFem, PreciseMethod::LinearFem),
        Scene::paper_organs(),
    ];
    for s in scenes {
        let path = out.join(format!("{}.ron", s.name));
        std::fs::write(&path, s.to_ron())?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// The machine and build, for every timing printed.
fn machine() -> serde_json::Value {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into());
    let cores = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    // Without debug assertions: a release build, or the optimised test profile.
    let profile = if cfg!(debug_assertions) {
        "debug"
    } else {
        "optimised"
    };
    serde_json::json!({ "cpu": cpu, "cores": cores, "profile": profile, "threads_used": 1 })
}

fn bench(args: &BenchArgs) -> Res {
    use soft_tissue_core::bench::{BenchBody, BenchMethod, BenchReport};
    use soft_tissue_core::scenario::{CYLINDER_FEM, CYLINDER_MSD, ORGAN_FEM};
    let (mesh, name) = match (&args.mesh, &args.generated) {
        (Some(path), _) => {
            let loaded = io::read_tet_mesh(path)?;
            let stem = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            (loaded.mesh, stem)
        }
        (None, Some(body)) => {
            let organ: Organ = body.parse()?;
            (organ.generate(args.resolution)?, organ.name().to_string())
        }
        (None, None) => return Err("give --mesh FILE or --generated NAME".into()),
    };
    let params = args.params.clone().unwrap_or_else(|| {
        if name == "cylinder" {
            "cylinder".into()
        } else {
            "organ".into()
        }
    });
    let fem = match params.as_str() {
        "cylinder" => CYLINDER_FEM,
        "organ" => ORGAN_FEM,
        other => {
            return Err(format!("unknown --params '{other}': expected cylinder or organ").into());
        }
    };
    let methods: Vec<BenchMethod> = if args.method == "all" {
        BenchMethod::ALL.to_vec()
    } else {
        vec![args.method.parse::<BenchMethod>()?]
    };
    let machine = machine();
    // Each method runs on its own; one that fails (for example an explicit integrator refusing
    // a step above its stability limit) is reported in its row and makes the exit status
    // non-zero, without hiding the others.
    let run_one = |method: BenchMethod| -> Result<BenchReport, Box<dyn std::error::Error>> {
        let mut body = BenchBody::new(
            &mesh,
            method,
            (&fem.params, fem.dt),
            (&CYLINDER_MSD.params, CYLINDER_MSD.dt),
            args.gravity,
        )?;
        if args.cg_tolerance.is_some() || args.cg_max_iterations.is_some() {
            let (tol, cap) = match method {
                BenchMethod::MsdImplicit => (1e-6, 50),
                _ => (1e-4, 20),
            };
            body.set_cg(
                args.cg_tolerance.unwrap_or(tol),
                args.cg_max_iterations.unwrap_or(cap),
            )?;
        }
        Ok(body.run(method, &mesh, args.warmup, args.steps)?)
    };
    let results: Vec<(BenchMethod, Result<BenchReport, String>)> = methods
        .into_iter()
        .map(|m| (m, run_one(m).map_err(|e| e.to_string())))
        .collect();
    if args.json {
        let items: Vec<serde_json::Value> = results
            .iter()
            .map(|(m, r)| {
                let mut v = match r {
                    Ok(r) => serde_json::to_value(r).expect("plain data"),
                    Err(e) => serde_json::json!({ "method": m.name(), "error": e }),
                };
                v["mesh"] = serde_json::json!(name);
                v["params"] = serde_json::json!(params);
                v["machine"] = machine.clone();
                v
            })
            .collect();
        let out = if items.len() == 1 {
            items[0].clone()
        } else {
            serde_json::Value::Array(items)
        };
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        println!(
            "{name}: {} nodes, {} tets; {} params; machine: {}, {} cores, {} build, 1 thread",
            mesh.node_count(),
            mesh.tet_count(),
            params,
            machine["cpu"].as_str().unwrap_or("?"),
            machine["cores"],
            machine["profile"].as_str().unwrap_or("?")
        );
        println!(
            "{:<18} {:>7} {:>10} {:>10} {:>10} {:>10} {:>8} {:>9} {:>8}",
            "method",
            "dt",
            "min us",
            "median us",
            "p99 us",
            "mean us",
            "cg it",
            "substeps",
            "max def"
        );
        for (m, r) in &results {
            match r {
                Ok(r) => println!(
                    "{:<18} {:>7} {:>10.1} {:>10.1} {:>10.1} {:>10.1} {:>8.2} {:>9.2} {:>7.1}%",
                    r.method,
                    r.dt,
                    r.min_us,
                    r.median_us,
                    r.p99_us,
                    r.mean_us,
                    r.mean_cg_iterations,
                    r.mean_substeps,
                    100.0 * r.max_displacement_ratio
                ),
                Err(e) => println!("{:<18} error: {e}", m.name()),
            }
        }
    }
    let failed: Vec<&str> = results
        .iter()
        .filter(|(_, r)| r.is_err())
        .map(|(m, _)| m.name())
        .collect();
    if !failed.is_empty() {
        return Err(format!("{} failed: {}", failed.join(", "), "see the rows above").into());
    }
    Ok(())
}
