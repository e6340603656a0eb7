//! `soft-tissue mesh`: inspect, convert and generate tetrahedral meshes (the surface mesher
//! is in `tetrahedralize.rs`).

use std::path::{Path, PathBuf};

use clap::{Args, Subcommand};
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::generate::Organ;
use soft_tissue_core::mesh::io::{self, WriteOptions};

use crate::Res;
use crate::tetrahedralize::{TetrahedralizeArgs, tetrahedralize};

#[derive(Subcommand)]
pub(crate) enum MeshCommand {
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
pub(crate) struct GenerateArgs {
    /// cylinder, liver, spleen, stomach, pancreas, or organs (all four, placed touching).
    body: String,
    /// Resolution: 1 reproduces the paper's mesh sizes; 2 halves the lattice spacing.
    #[arg(long, default_value_t = 1.0)]
    resolution: f64,
    /// Output folder (created if missing).
    #[arg(long)]
    out: PathBuf,
}

/// Runs a `mesh` command.
pub(crate) fn run(command: MeshCommand) -> Res {
    match command {
        MeshCommand::Info { file, json } => info(&file, json),
        MeshCommand::Convert {
            input,
            output,
            binary,
        } => convert(&input, &output, binary),
        MeshCommand::Generate(args) => generate(&args),
        MeshCommand::Tetrahedralize(args) => tetrahedralize(&args),
    }
}

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
