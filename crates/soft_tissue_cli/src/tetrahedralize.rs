//! `soft-tissue mesh tetrahedralize`: a closed triangle surface meshed into tetrahedra, with
//! what the repair found and how near the mesh lies to the surface.

use std::path::PathBuf;

use clap::Args;
use soft_tissue_core::mesh::io::{self, WriteOptions};

use crate::Res;

#[derive(Args)]
pub(crate) struct TetrahedralizeArgs {
    /// The surface (.obj, .stl, .ply, .gltf or .glb; ASCII or binary).
    input: PathBuf,
    /// The tetrahedral mesh to write (.msh, .vtk, .vtu, .node).
    #[arg(long)]
    out: PathBuf,
    /// About this many tetrahedra (default 1500 when no edge length is given); with
    /// --max-distance, the smallest count tried.
    #[arg(long)]
    target_tets: Option<usize>,
    /// Lattice spacing, about the interior edge length, in the surface's units.
    #[arg(long, conflicts_with_all = ["target_tets", "max_distance"])]
    edge_length: Option<f64>,
    /// Grow the count until the boundary lies within PCT % of the bounding box's diagonal
    /// of the surface both ways (and the volume within 3 %), up to --max-tets. The walls'
    /// thickness, and the spacing and count that follow it, are printed first (seconds).
    #[arg(long, value_name = "PCT")]
    max_distance: Option<f64>,
    /// The largest count --max-distance asks for: a try whose count (asked, or estimated from
    /// the walls or the last try) would pass it is not made, and the command says so; a try at
    /// a spacing may make more than its estimate.
    #[arg(long, default_value_t = 100_000, requires = "max_distance")]
    max_tets: usize,
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

pub(crate) fn tetrahedralize(args: &TetrahedralizeArgs) -> Res {
    use soft_tissue_core::mesh::tetrahedralize::{TetrahedralizeOptions, tetrahedralize};
    let name = args.input.display().to_string();
    let io::LoadedSurface { mut surface, notes } = io::read_surface_with_notes(&args.input)?;
    if !(args.units.is_finite() && args.units > 0.0) {
        return Err(format!("--units must be positive, found {}", args.units).into());
    }
    for p in &mut surface.positions {
        *p *= args.units;
    }
    let start = std::time::Instant::now();
    let (mesh, r, search) = match args.max_distance {
        None => {
            let options = TetrahedralizeOptions {
                edge_length: args.edge_length,
                target_tets: args.target_tets.or(Some(1500)),
                min_dihedral_deg: args.quality,
            };
            let (mesh, r) =
                tetrahedralize(&surface, &options).map_err(|e| format!("{name}: {e}"))?;
            (mesh, r, None)
        }
        Some(pct) => {
            let search = to_distance(args, &surface, pct, start, &name)?;
            (search.mesh, search.report, Some(search.tries_and_more))
        }
    };
    let seconds = start.elapsed().as_secs_f64();
    io::write_tet_mesh(&mesh, &args.out, WriteOptions::default())?;
    if args.json {
        let mut v = serde_json::json!({
            "input": name, "output": args.out.display().to_string(),
            "triangles": surface.triangles.len(), "notes": notes, "seconds": seconds,
            "report": r, "shortfall": r.shortfall(),
        });
        if let Some(s) = &search {
            v["search"] = serde_json::json!({
                "tries": s.tries, "reached": s.reached, "walls": s.advice,
                "shortfall": s.shortfall,
            });
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
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
    match search.and_then(|s| s.shortfall) {
        Some(short) => eprintln!("warning: {name}: {short}"),
        None => {
            if let Some(short) = r.shortfall() {
                eprintln!("warning: {name}: {short}");
            }
        }
    }
    Ok(())
}

/// What the distance search leaves beside the kept mesh.
struct SearchSummary {
    tries: Vec<soft_tissue_core::mesh::tetrahedralize::DistanceTry>,
    reached: bool,
    advice: Option<soft_tissue_core::mesh::tetrahedralize::WallAdvice>,
    shortfall: Option<String>,
}

/// The kept mesh of a distance search, its report and the rest.
struct Searched {
    mesh: soft_tissue_core::mesh::TetMesh,
    report: soft_tissue_core::mesh::tetrahedralize::TetrahedralizeReport,
    tries_and_more: SearchSummary,
}

/// `--max-distance PCT`: the walls' advice and each try printed as they come (on stderr
/// with `--json`, so that stdout stays one JSON object).
fn to_distance(
    args: &TetrahedralizeArgs,
    surface: &io::SurfaceMesh,
    pct: f64,
    start: std::time::Instant,
    name: &str,
) -> Result<Searched, Box<dyn std::error::Error>> {
    use soft_tissue_core::mesh::tetrahedralize::{DistanceGoal, tetrahedralize_to_distance};
    if !(pct.is_finite() && pct > 0.0) {
        return Err(format!("--max-distance must be positive, found {pct}").into());
    }
    let goal = DistanceGoal {
        max_distance: pct / 100.0,
        start_tets: args.target_tets.unwrap_or(1500),
        max_tets: args.max_tets,
        min_dihedral_deg: args.quality,
    };
    let json = args.json;
    let say = move |line: String| {
        if json {
            eprintln!("{line}");
        } else {
            println!("{line}");
        }
    };
    let s = tetrahedralize_to_distance(
        surface,
        &goal,
        &mut |a| {
            say(format!(
                "{name}: {} ({:.1} s)",
                a.describe(),
                start.elapsed().as_secs_f64()
            ))
        },
        &mut |t| {
            let asked = match (t.target_tets, t.spacing) {
                (Some(n), _) => format!("{n} tetrahedra asked"),
                (None, Some(h)) => format!("spacing {h:.4} asked"),
                (None, None) => String::new(),
            };
            say(format!(
                "try: {asked}, {} tetrahedra made: {:.2} % of the diagonal, volume {:+.2} % \
                 ({:.1} s)",
                t.tets,
                100.0 * t.distance,
                100.0 * t.volume,
                start.elapsed().as_secs_f64()
            ))
        },
    )
    .map_err(|e| format!("{name}: {e}"))?;
    let shortfall = s.shortfall();
    Ok(Searched {
        mesh: s.mesh,
        report: s.report,
        tries_and_more: SearchSummary {
            tries: s.tries,
            reached: s.reached,
            advice: s.advice,
            shortfall,
        },
    })
}
