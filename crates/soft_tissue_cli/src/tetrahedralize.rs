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
