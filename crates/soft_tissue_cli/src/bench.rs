//! `soft-tissue bench`: the solvers timed per step on a mesh under a load that keeps it
//! deforming, and the machine every timing names.

use std::path::PathBuf;

use clap::Args;
use soft_tissue_core::mesh::generate::Organ;
use soft_tissue_core::mesh::io;

use crate::Res;

#[derive(Args)]
pub(crate) struct BenchArgs {
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

/// The machine and build, for every timing printed.
pub(crate) fn machine() -> serde_json::Value {
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

pub(crate) fn bench(args: &BenchArgs) -> Res {
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
