//! `soft-tissue cage`: cages built around a mesh, and meshes deformed by a cage through 3D
//! Green coordinates.

use std::path::{Path, PathBuf};

use clap::Subcommand;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::io::{self, WriteOptions};

use crate::Res;

#[derive(Subcommand)]
pub(crate) enum CageCommand {
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

/// Runs a `cage` command.
pub(crate) fn run(command: CageCommand) -> Res {
    match command {
        CageCommand::Deform {
            cage_rest,
            cage_deformed,
            mesh,
            out,
        } => cage_deform(&cage_rest, &cage_deformed, &mesh, &out),
        CageCommand::Build {
            mesh,
            kind,
            vertices,
            margin,
            out,
        } => cage_build(&mesh, &kind, vertices, margin, &out),
    }
}

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
