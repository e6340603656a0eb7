//! `soft-tissue`: command-line tool of bevy_soft_tissue (mesh inspection, conversion,
//! generation, scene files, cages, benchmarks, headless simulation).

mod haptics_bench;
mod realtime;
mod report;
mod simulate;

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
    /// Time the solvers per step on a mesh under a load that keeps it deforming
    /// (bottom 10 % fixed, a swinging force on the top 5 %, optional gravity).
    Bench(BenchArgs),
    /// Build cages and deform meshes with Green coordinates.
    #[command(subcommand)]
    Cage(CageCommand),
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

#[derive(Subcommand)]
enum CageCommand {
    /// Embed a mesh's vertices in a rest cage and write them deformed by a deformed cage
    /// (3D Green coordinates). Both cages are OBJ files with the same triangles. The mesh is
    /// an OBJ surface (written as OBJ) or a tetrahedral mesh (written in OUT's format). Fails,
    /// naming the vertex, if one lies outside the rest cage.
    Deform {
        /// The cage the mesh was modelled in (OBJ).
        #[arg(long)]
        cage_rest: PathBuf,
        /// The same cage, moved (OBJ, same triangles).
        #[arg(long)]
        cage_deformed: PathBuf,
        /// The mesh to deform (.obj, .msh, .vtk, .vtu, .node).
        #[arg(long)]
        mesh: PathBuf,
        /// Output file.
        #[arg(long)]
        out: PathBuf,
    },
    /// Build a cage around a mesh (every vertex enclosed with a margin) and write it as OBJ.
    Build {
        /// The mesh (.obj, .msh, .vtk, .vtu, .node).
        #[arg(long)]
        mesh: PathBuf,
        /// box (the paper's bounding box) or fitted (shrink-wrapped to the mesh).
        #[arg(long, default_value = "fitted")]
        kind: String,
        /// Vertex budget of a fitted cage.
        #[arg(long, default_value_t = 64)]
        vertices: usize,
        /// Smallest distance from a mesh vertex to the cage (default: 2 % of the bounding-box
        /// diagonal).
        #[arg(long)]
        margin: Option<f64>,
        /// Output OBJ file.
        #[arg(long)]
        out: PathBuf,
    },
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
    /// fem-linear, fem-corotational, msd-rk4, msd-symplectic, msd-implicit, cage-box,
    /// cage-fitted, cage (both cages), or all. Several may be given separated by commas.
    #[arg(long, default_value = "all")]
    method: String,
    /// Vertex budget of the fitted cage.
    #[arg(long, default_value_t = 64)]
    cage_vertices: usize,
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
    /// Time integrator of the FEM methods and of implicit MSD: backward-euler (the
    /// default) or bdf2 (second order, see docs/solvers.md).
    #[arg(long, default_value = "backward-euler")]
    integrator: String,
    /// Corotational FEM's rotation tolerance, radians (default: the library's, 1e-10).
    #[arg(long)]
    rotation_tolerance: Option<f64>,
    /// Untimed steps before timing.
    #[arg(long, default_value_t = 100)]
    warmup: usize,
    /// Print one JSON object (an array with --method all).
    #[arg(long)]
    json: bool,
    /// Threads the steps run on (0, the default: every available core). Large bodies split
    /// their element loop over them; results are identical for every count.
    #[arg(long, default_value_t = 0)]
    threads: usize,
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
    /// Mesh the inside of a closed triangle surface (.obj, .stl, .ply, .gltf, .glb) into
    /// tetrahedra; the output format follows OUT's extension. Prints what it repaired and how near the mesh is to the
    /// surface (`--json` for one JSON object).
    Tetrahedralize(TetrahedralizeArgs),
}

#[derive(Args)]
struct TetrahedralizeArgs {
    /// The surface (.obj, .stl, .ply, .gltf or .glb; ASCII or binary).
    input: PathBuf,
    /// The tetrahedral mesh to write (.msh, .vtk, .vtu, .node).
    #[arg(long)]
    out: PathBuf,
    /// About this many tetrahedra (default 1500 when no edge length is given).
    #[arg(long)]
    target_tets: Option<usize>,
    /// Lattice spacing, about the interior edge length, in the surface's units.
    #[arg(long, conflicts_with = "target_tets")]
    edge_length: Option<f64>,
    /// Smallest dihedral angle kept, degrees.
    #[arg(long, default_value_t = 8.0)]
    quality: f64,
    /// Multiply every coordinate by this on reading: the surface's unit in scene units
    /// (our organs use 1 unit = 10 cm, so a surface in millimetres takes 0.01).
    #[arg(long, default_value_t = 1.0)]
    units: f64,
    /// Print the report as one JSON object.
    #[arg(long)]
    json: bool,
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
    /// Write cylinders.scene.ron and organs.scene.ron (the paper's parameters) into DIR.
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
        Command::Mesh(MeshCommand::Tetrahedralize(args)) => tetrahedralize(&args),
        Command::Scene(SceneCommand::Export { out }) => export_scenes(&out),
        Command::Bench(args) => bench(&args),
        Command::Simulate(args) => simulate::simulate(&args),
        Command::HapticsBench(args) => haptics_bench::haptics_bench(&args),
        Command::Report(args) => report::report(&args),
        Command::Cage(CageCommand::Deform {
            cage_rest,
            cage_deformed,
            mesh,
            out,
        }) => cage_deform(&cage_rest, &cage_deformed, &mesh, &out),
        Command::Cage(CageCommand::Build {
            mesh,
            kind,
            vertices,
            margin,
            out,
        }) => cage_build(&mesh, &kind, vertices, margin, &out),
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

fn tetrahedralize(args: &TetrahedralizeArgs) -> Res {
    use soft_tissue_core::mesh::tetrahedralize::{TetrahedralizeOptions, tetrahedralize};
    let name = args.input.display().to_string();
    let io::LoadedSurface { mut surface, notes } = io::read_surface_with_notes(&args.input)?;
    if !(args.units.is_finite() && args.units > 0.0) {
        return Err(format!("--units must be positive, found {}", args.units).into());
    }
    for p in &mut surface.positions {
        *p *= args.units;
    }
    let options = TetrahedralizeOptions {
        edge_length: args.edge_length,
        target_tets: args.target_tets.or(Some(1500)),
        min_dihedral_deg: args.quality,
    };
    let start = std::time::Instant::now();
    let (mesh, r) = tetrahedralize(&surface, &options).map_err(|e| format!("{name}: {e}"))?;
    let seconds = start.elapsed().as_secs_f64();
    io::write_tet_mesh(&mesh, &args.out, WriteOptions::default())?;
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "input": name, "output": args.out.display().to_string(),
                "triangles": surface.triangles.len(), "notes": notes, "seconds": seconds,
                "report": r, "shortfall": r.shortfall(),
            }))?
        );
        return Ok(());
    }
    let d = r.defects;
    // What the reader overruled in the file, one line each, before what the repair did.
    let notes: String = notes.iter().map(|n| format!("\nnote: {n}")).collect();
    println!(
        "{name}: {} vertices, {} triangles{notes}\n\
         repaired: {} duplicate vertices welded, {} unused vertices, {} degenerate and {} \
         duplicate triangles dropped, {} triangles turned; {} boundary edges (holes), {} \
         non-manifold edges; {} small separate pieces dropped, {} inner pieces kept as \
         cavities, {} inside the union dropped, {} triangles buried where parts overlap\n\
         mesh: {} nodes, {} tetrahedra ({}, spacing {:.4}), dihedral {:.1} .. {:.1} deg\n\
         volume {:.6} against {:.6} enclosed ({:+.2} %; {:+.2} % before the boundary nodes \
         moved out to restore what the chords lost)\n\
         boundary to surface {:.3e}, surface to boundary {:.3e} ({:.2} % / {:.2} % of the \
         diagonal {:.4}); {} boundary nodes projected onto the surface, {} then moved onto \
         creases and corners, {} boundary edges split\n\
         {:.2} s -> {}",
        surface.positions.len(),
        surface.triangles.len(),
        d.duplicate_vertices,
        d.unused_vertices,
        d.degenerate_triangles,
        d.duplicate_triangles,
        d.flipped_triangles,
        d.boundary_edges,
        d.non_manifold_edges,
        d.specks_dropped,
        d.cavities,
        d.inner_pieces_dropped,
        d.buried_triangles,
        r.nodes,
        r.tets,
        if r.graded {
            format!(
                "graded: meshed {:.2} times finer, the boundary coarsened where the surface is \
                 flat",
                r.finer
            )
        } else {
            "uniform".to_owned()
        },
        r.spacing,
        r.min_dihedral_deg,
        r.max_dihedral_deg,
        r.volume,
        r.enclosed_volume,
        100.0 * (r.volume / r.enclosed_volume - 1.0),
        100.0 * (r.chord_volume / r.enclosed_volume - 1.0),
        r.mesh_to_surface,
        r.surface_to_mesh,
        100.0 * r.mesh_to_surface / r.bbox_diagonal,
        100.0 * r.surface_to_mesh / r.bbox_diagonal,
        r.bbox_diagonal,
        r.projected_nodes,
        r.snapped_nodes,
        r.split_edges,
        seconds,
        args.out.display()
    );
    if let Some(short) = r.shortfall() {
        eprintln!("warning: {name}: {short}");
    }
    Ok(())
}

fn export_scenes(out: &Path) -> Res {
    std::fs::create_dir_all(out)?;
    let scenes = [
        Scene::paper_cylinders(PreciseMethod::LinearFem, PreciseMethod::LinearFem),
        Scene::paper_organs(),
        Scene::large_organs(),
    ];
    for s in scenes {
        let path = out.join(format!("{}.scene.ron", s.name));
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
    let mut methods: Vec<BenchMethod> = Vec::new();
    for m in args.method.split(',').map(str::trim) {
        match m {
            "all" => methods.extend(BenchMethod::ALL),
            "cage" => methods.extend([BenchMethod::CageBox, BenchMethod::CageFitted]),
            other => methods.push(other.parse::<BenchMethod>()?),
        }
    }
    methods.dedup();
    let bdf2 = match args.integrator.as_str() {
        "backward-euler" => false,
        "bdf2" => true,
        other => {
            return Err(
                format!("unknown --integrator '{other}': expected backward-euler or bdf2").into(),
            );
        }
    };
    let threads = soft_tissue_core::parallel::Threads::new(args.threads)?;
    let mut machine = machine();
    machine["threads_used"] = serde_json::json!(threads.count());
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
            args.cage_vertices,
        )?;
        body.set_bdf2(bdf2)?;
        if let Some(tolerance) = args.rotation_tolerance {
            body.set_rotation_tolerance(tolerance)?;
        }
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
        Ok(threads.run(|| body.run(method, &mesh, args.warmup, args.steps))?)
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
            "{name}: {} nodes, {} tets; {} params; machine: {}, {} cores, {} build, {} thread(s)",
            mesh.node_count(),
            mesh.tet_count(),
            params,
            machine["cpu"].as_str().unwrap_or("?"),
            machine["cores"],
            machine["profile"].as_str().unwrap_or("?"),
            threads.count()
        );
        println!(
            "{:<18} {:>7} {:>10} {:>10} {:>10} {:>10} {:>10} {:>8} {:>9} {:>8}",
            "method",
            "dt",
            "min us",
            "median us",
            "p99 us",
            "max us",
            "mean us",
            "cg it",
            "substeps",
            "max def"
        );
        for (m, r) in &results {
            match r {
                Ok(r) => {
                    println!(
                        "{:<18} {:>7} {:>10.1} {:>10.1} {:>10.1} {:>10.1} {:>10.1} {:>8.2} {:>9.2} {:>7.1}%",
                        r.method,
                        r.dt,
                        r.min_us,
                        r.median_us,
                        r.p99_us,
                        r.max_us,
                        r.mean_us,
                        r.mean_cg_iterations,
                        r.mean_substeps,
                        100.0 * r.max_displacement_ratio
                    );
                    for (stage, t) in &r.stages {
                        println!(
                            "  {:<16} {:>7} {:>10.1} {:>10.1} {:>10.1} {:>10.1} {:>10.1}",
                            stage, "", t.min_us, t.median_us, t.p99_us, t.max_us, t.mean_us
                        );
                    }
                }
                Err(e) => println!("{:<18} error: {e}", m.name()),
            }
        }
        for (_, r) in &results {
            if let Ok(r) = r
                && r.points > 0
            {
                println!(
                    "{}: {} cage vertices, {} surface points: median {:.2} us per 1000 points",
                    r.method,
                    r.cage_vertices,
                    r.points,
                    r.median_us * 1000.0 / r.points as f64
                );
            }
        }
        let median = |name: &str| {
            results.iter().find_map(|(m, r)| match r {
                Ok(r) if m.name() == name => Some(r.median_us),
                _ => None,
            })
        };
        for cage in ["cage-box", "cage-fitted"] {
            if let (Some(fem), Some(c)) = (median("fem-corotational"), median(cage)) {
                println!(
                    "fem-corotational / {cage} median step time: {:.0}x",
                    fem / c
                );
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

/// Reads an OBJ surface.
fn read_obj(path: &Path) -> Result<io::SurfaceMesh, Box<dyn std::error::Error>> {
    let data = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(io::parse_obj(&data, &path.display().to_string())?)
}

fn is_obj(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("obj"))
}

fn cage_deform(rest: &Path, deformed: &Path, mesh: &Path, out: &Path) -> Res {
    use soft_tissue_core::Vec3;
    use soft_tissue_core::cage::{Cage, GreenCoordinates};
    let rest_surface = read_obj(rest)?;
    let deformed_surface = read_obj(deformed)?;
    if rest_surface.positions.len() != deformed_surface.positions.len()
        || rest_surface.triangles != deformed_surface.triangles
    {
        return Err(format!(
            "{} ({} vertices, {} triangles) and {} ({} vertices, {} triangles) are not the same cage",
            rest.display(),
            rest_surface.positions.len(),
            rest_surface.triangles.len(),
            deformed.display(),
            deformed_surface.positions.len(),
            deformed_surface.triangles.len()
        )
        .into());
    }
    let cage = Cage::from_surface(&rest_surface).map_err(|e| format!("{}: {e}", rest.display()))?;
    let points: Vec<Vec3>;
    let mut obj = None;
    let mut tet = None;
    if is_obj(mesh) {
        let s = read_obj(mesh)?;
        points = s.positions.clone();
        obj = Some(s);
    } else {
        let loaded = io::read_tet_mesh(mesh)?;
        points = loaded.mesh.positions().to_vec();
        tet = Some(loaded.mesh);
    }
    let coords =
        GreenCoordinates::new(&cage, &points).map_err(|e| format!("{}: {e}", mesh.display()))?;
    let mut terms = vec![Vec3::zeros(); cage.triangles().len()];
    coords.face_terms(&deformed_surface.positions, &mut terms);
    let mut moved = vec![Vec3::zeros(); points.len()];
    coords.evaluate(&deformed_surface.positions, &terms, &mut moved)?;
    if let Some(mut s) = obj {
        s.positions = moved;
        std::fs::write(out, io::write_obj(&s)).map_err(|e| format!("{}: {e}", out.display()))?;
    } else if let Some(m) = tet {
        let tets = m.tets().iter().map(|t| t.map(|i| i as usize)).collect();
        let moved_mesh = TetMesh::new(moved, tets).map_err(|e| format!("deformed mesh: {e}"))?;
        io::write_tet_mesh(&moved_mesh, out, WriteOptions::default())?;
    }
    println!(
        "deformed {} points with a {}-vertex cage -> {}",
        points.len(),
        cage.vertices().len(),
        out.display()
    );
    Ok(())
}

fn cage_build(mesh: &Path, kind: &str, vertices: usize, margin: Option<f64>, out: &Path) -> Res {
    use soft_tissue_core::cage::{FitOptions, box_cage, fitted_cage};
    let (points, surface, volume) = if is_obj(mesh) {
        let s = read_obj(mesh)?;
        (s.positions, s.triangles, None)
    } else {
        let loaded = io::read_tet_mesh(mesh)?;
        let v = loaded.mesh.volume();
        (
            loaded.mesh.positions().to_vec(),
            loaded.mesh.surface().triangles().to_vec(),
            Some(v),
        )
    };
    let mut options = FitOptions::for_points(&points, vertices);
    if let Some(m) = margin {
        options.margin = m;
    }
    let cage = match kind {
        "box" => box_cage(&points, options.margin)?,
        "fitted" => fitted_cage(&points, &surface, &options)?,
        other => return Err(format!("unknown --kind '{other}': expected box or fitted").into()),
    };
    std::fs::write(out, io::write_obj(&cage.to_surface()))
        .map_err(|e| format!("{}: {e}", out.display()))?;
    print!(
        "{kind} cage: {} vertices, {} triangles, margin {:.4}, volume {:.4}",
        cage.vertices().len(),
        cage.triangles().len(),
        options.margin,
        cage.volume()
    );
    if let Some(v) = volume {
        print!(" ({:.2}x the mesh volume)", cage.volume() / v);
    }
    println!(" -> {}", out.display());
    Ok(())
}
