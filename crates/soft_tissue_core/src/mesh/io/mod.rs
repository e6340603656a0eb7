//! Reading and writing mesh files.
//!
//! | format | extension | read | write |
//! |---|---|---|---|
//! | Gmsh MSH 1, 2.0-2.2 (ASCII, binary), 4.1 (ASCII, binary) | `.msh` | yes | 2.2 ASCII and binary |
//! | VTK legacy unstructured grid (ASCII, binary) | `.vtk` | yes | ASCII and binary |
//! | VTK XML unstructured grid (ascii, base64 binary) | `.vtu` | yes | yes |
//! | TetGen | `.node` + `.ele` | yes | yes |
//! | Wavefront OBJ surface (visual meshes, cages) | `.obj` | surface only | surface only |
//! | STL surface (ASCII, binary) | `.stl` | surface only | surface only |
//! | PLY surface (ASCII, binary either byte order) | `.ply` | surface only | no |
//! | glTF 2.0 triangle primitives, node transforms applied | `.gltf`, `.glb` | surface only | no |
//!
//! Volume files keep their tetrahedra. Second-order tetrahedra are reduced to their corners;
//! hexahedra, wedges and pyramids are split into tetrahedra conformingly (each quadrilateral
//! face is cut along the diagonal through its smallest node, hexahedra and wedges get a centre
//! node); points, lines and surface elements are skipped. Every such change is listed in
//! [`LoadedMesh::notes`]. The boundary surface is always derived from the tetrahedra.
//! Surface readers note what they overruled in a file (a binary STL header's triangle count
//! that its data contradicts) in [`LoadedSurface::notes`], from [`read_surface_with_notes`].
//!
//! Every malformed input gives a [`FormatError`] naming the file, the line (or byte offset,
//! or element) and the problem; no input makes a reader panic.

mod elements;
mod gltf;
mod gmsh;
mod obj;
mod ply;
mod stl;
mod tetgen;
mod text;
mod vtk;

pub use gltf::{gltf_external_uris, parse_gltf};
pub use obj::{SurfaceMesh, parse_obj, write_obj};
pub use ply::parse_ply;
pub use stl::{parse_stl, parse_stl_with_notes, write_stl};

use super::{MeshError, TetMesh};
use crate::Vec3;
use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;
use thiserror::Error;

/// Where in a file a problem was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Location {
    /// 1-based line of a text file.
    Line(usize),
    /// 0-based byte offset in a binary block.
    Byte(usize),
    /// The whole file.
    File,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::Line(l) => write!(f, "line {l}"),
            Location::Byte(b) => write!(f, "byte {b}"),
            Location::File => write!(f, "file"),
        }
    }
}

/// Errors reading or writing a mesh file. Each names the file.
#[derive(Debug, Error)]
pub enum FormatError {
    /// The file could not be read or written.
    #[error("{file}: {source}")]
    Io {
        /// File name.
        file: String,
        /// Underlying error.
        source: std::io::Error,
    },
    /// The file content is malformed.
    #[error("{file}: {location}: {message}")]
    Parse {
        /// File name.
        file: String,
        /// Line or byte offset.
        location: Location,
        /// What is wrong.
        message: String,
    },
    /// The file parsed, but an element in it is unusable.
    #[error("{file}: {element}: {source}")]
    Mesh {
        /// File name.
        file: String,
        /// The element of the file at fault, in the file's own numbering (e.g. `element tag 17`).
        element: String,
        /// The validation error.
        source: MeshError,
    },
    /// The file is valid but not something this library can use (e.g. no tetrahedra).
    #[error("{file}: {message}")]
    Unsupported {
        /// File name.
        file: String,
        /// Why.
        message: String,
    },
}

impl FormatError {
    pub(crate) fn parse(file: &str, location: Location, message: impl Into<String>) -> Self {
        FormatError::Parse {
            file: file.to_string(),
            location,
            message: message.into(),
        }
    }

    pub(crate) fn unsupported(file: &str, message: impl Into<String>) -> Self {
        FormatError::Unsupported {
            file: file.to_string(),
            message: message.into(),
        }
    }

    pub(crate) fn io(file: &Path, source: std::io::Error) -> Self {
        FormatError::Io {
            file: file.display().to_string(),
            source,
        }
    }
}

/// The tetrahedral mesh formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    /// Gmsh `.msh` (versions 1, 2.x, 4.1; ASCII or binary, detected from the header).
    Gmsh,
    /// Legacy VTK `.vtk` unstructured grid.
    VtkLegacy,
    /// VTK XML `.vtu` unstructured grid.
    Vtu,
    /// TetGen `.node` + `.ele` pair (either path may be given).
    TetGen,
}

impl MeshFormat {
    /// The format implied by a file extension (case-insensitive).
    pub fn from_path(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "msh" => Some(Self::Gmsh),
            "vtk" => Some(Self::VtkLegacy),
            "vtu" => Some(Self::Vtu),
            "node" | "ele" => Some(Self::TetGen),
            _ => None,
        }
    }
}

/// Options for writing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WriteOptions {
    /// Write binary data where the format has a binary variant (Gmsh 2.2, legacy VTK,
    /// base64-encoded VTU). Default: ASCII.
    pub binary: bool,
}

/// A tetrahedral mesh read from a file, with what the reader changed or dropped.
#[derive(Debug, Clone)]
pub struct LoadedMesh {
    /// The validated mesh.
    pub mesh: TetMesh,
    /// Notes about the conversion (skipped element types with counts, split elements,
    /// reduced element order) followed by the mesh's own warnings, as sentences.
    pub notes: Vec<String>,
}

/// A triangle surface read from a file, with what the reader overruled in it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LoadedSurface {
    /// The surface.
    pub surface: SurfaceMesh,
    /// Notes about the file that the reader worked around (a binary STL header's triangle
    /// count overruled by its data, naming both counts), as sentences. Empty for most files.
    pub notes: Vec<String>,
}

impl From<SurfaceMesh> for LoadedSurface {
    fn from(surface: SurfaceMesh) -> Self {
        Self {
            surface,
            notes: Vec::new(),
        }
    }
}

/// Nodes and tetrahedra as a reader produced them, before validation.
#[derive(Debug, Default)]
pub(crate) struct RawMesh {
    pub positions: Vec<Vec3>,
    pub tets: Vec<[usize; 4]>,
    /// For each tet, the number of the file element it came from (for messages).
    pub origin: Vec<u64>,
    /// What the numbers in `origin` are, e.g. "element tag" or "cell".
    pub origin_label: &'static str,
    /// Skipped element kinds and counts.
    pub skipped: BTreeMap<String, usize>,
    /// Converted element kinds: (elements, tets produced, nodes added).
    pub converted: BTreeMap<&'static str, (usize, usize, usize)>,
    /// Higher-order tetrahedra reduced to their corners.
    pub reduced_order: usize,
    /// Free-form notes from the reader.
    pub extra_notes: Vec<String>,
}

impl RawMesh {
    pub(crate) fn skip(&mut self, what: impl Into<String>) {
        *self.skipped.entry(what.into()).or_insert(0) += 1;
    }

    /// Validates into a [`LoadedMesh`], mapping mesh errors to the file's element numbers.
    pub(crate) fn finish(self, file: &str) -> Result<LoadedMesh, FormatError> {
        let mut notes = self.extra_notes;
        if self.reduced_order > 0 {
            notes.push(format!(
                "{} higher-order tetrahedra were reduced to their four corner nodes",
                self.reduced_order
            ));
        }
        for (kind, (count, tets, added)) in &self.converted {
            notes.push(format!(
                "{count} {kind} were split into {tets} tetrahedra ({added} centre nodes added)"
            ));
        }
        if !self.skipped.is_empty() {
            let list: Vec<String> = self
                .skipped
                .iter()
                .map(|(k, n)| format!("{n} {k}"))
                .collect();
            notes.push(format!("skipped non-volume elements: {}", list.join(", ")));
        }
        if self.tets.is_empty() {
            let what = if self.skipped.is_empty() {
                "no elements".to_string()
            } else {
                notes.last().cloned().unwrap_or_default()
            };
            return Err(FormatError::unsupported(
                file,
                format!("the file has no tetrahedra or other volume elements ({what})"),
            ));
        }
        let origin = self.origin;
        let label = self.origin_label;
        let mesh = TetMesh::new(self.positions, self.tets).map_err(|source| {
            let element = match mesh_error_tet(&source) {
                Some(t) => format!("{label} {}", origin.get(t).copied().unwrap_or(t as u64)),
                None => "mesh".to_string(),
            };
            FormatError::Mesh {
                file: file.to_string(),
                element,
                source,
            }
        })?;
        notes.extend(mesh.warnings().iter().map(|w| w.to_string()));
        Ok(LoadedMesh { mesh, notes })
    }
}

fn mesh_error_tet(e: &MeshError) -> Option<usize> {
    match e {
        MeshError::IndexOutOfRange { tet, .. }
        | MeshError::RepeatedNode { tet, .. }
        | MeshError::DegenerateTet { tet, .. }
        | MeshError::DuplicateTet { tet, .. } => Some(*tet),
        MeshError::NonManifoldFace { tets, .. } => tets.first().copied(),
        _ => None,
    }
}

/// Reads a tetrahedral mesh, choosing the format from the extension.
pub fn read_tet_mesh(path: impl AsRef<Path>) -> Result<LoadedMesh, FormatError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let format = MeshFormat::from_path(path).ok_or_else(|| {
        FormatError::unsupported(
            &name,
            "unknown extension: expected .msh, .vtk, .vtu, .node or .ele (an .obj holds only a surface)",
        )
    })?;
    match format {
        MeshFormat::TetGen => {
            let node_path = path.with_extension("node");
            let ele_path = path.with_extension("ele");
            let node = std::fs::read(&node_path).map_err(|e| FormatError::io(&node_path, e))?;
            let ele = std::fs::read(&ele_path).map_err(|e| FormatError::io(&ele_path, e))?;
            tetgen::parse(
                &node,
                &node_path.display().to_string(),
                &ele,
                &ele_path.display().to_string(),
            )
        }
        _ => {
            let bytes = std::fs::read(path).map_err(|e| FormatError::io(path, e))?;
            parse_tet_mesh(&bytes, format, &name)
        }
    }
}

/// Parses a single-file tetrahedral mesh from memory. `name` is used in messages.
/// For TetGen, which needs two files, use [`parse_tetgen`].
pub fn parse_tet_mesh(
    bytes: &[u8],
    format: MeshFormat,
    name: &str,
) -> Result<LoadedMesh, FormatError> {
    // Files whose extension does not match their content are common in mesh libraries (an
    // XML unstructured grid saved as `.vtk`): the content decides between the two VTK forms.
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .map_or(&bytes[..0], |i| &bytes[i..]);
    let format = match format {
        MeshFormat::VtkLegacy if start.starts_with(b"<") => MeshFormat::Vtu,
        MeshFormat::Vtu if start.starts_with(b"# vtk") => MeshFormat::VtkLegacy,
        f => f,
    };
    match format {
        MeshFormat::Gmsh => gmsh::parse(bytes, name),
        MeshFormat::VtkLegacy => vtk::parse_legacy(bytes, name),
        MeshFormat::Vtu => vtk::parse_xml(bytes, name),
        MeshFormat::TetGen => Err(FormatError::unsupported(
            name,
            "TetGen meshes need both the .node and the .ele file: use parse_tetgen",
        )),
    }
}

/// Parses a TetGen mesh from the contents of its `.node` and `.ele` files.
pub fn parse_tetgen(
    node: &[u8],
    node_name: &str,
    ele: &[u8],
    ele_name: &str,
) -> Result<LoadedMesh, FormatError> {
    tetgen::parse(node, node_name, ele, ele_name)
}

/// Reads a triangle surface; the format follows the extension (`.obj`, `.stl` ASCII or
/// binary, `.ply` ASCII or binary, `.gltf` with its buffers beside it, `.glb`). The notes
/// [`read_surface_with_notes`] gives are dropped.
pub fn read_surface(path: impl AsRef<Path>) -> Result<SurfaceMesh, FormatError> {
    read_surface_with_notes(path).map(|read| read.surface)
}

/// Parses a triangle surface from bytes, the format named by `name`'s extension (OBJ, STL,
/// PLY, or a self-contained binary glTF `.glb`; a `.gltf` needs its side files: read it with
/// [`read_surface`]).
pub fn parse_surface(data: &[u8], name: &str) -> Result<SurfaceMesh, FormatError> {
    let ext = Path::new(name)
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("obj") => parse_obj(data, name),
        Some("stl") => parse_stl_with_notes(data, name).map(|l| l.surface),
        Some("ply") => parse_ply(data, name),
        Some("glb") => gltf::read_beside(data, Path::new(name)),
        _ => Err(FormatError::unsupported(
            name,
            "unknown surface extension: expected .obj, .stl, .ply or .glb",
        )),
    }
}

/// Reads a triangle surface as [`read_surface`] does, with notes on what the reader
/// overruled in the file.
pub fn read_surface_with_notes(path: impl AsRef<Path>) -> Result<LoadedSurface, FormatError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let data = std::fs::read(path).map_err(|e| FormatError::io(path, e))?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("obj") => parse_obj(&data, &name).map(LoadedSurface::from),
        Some("stl") => parse_stl_with_notes(&data, &name),
        Some("ply") => parse_ply(&data, &name).map(LoadedSurface::from),
        Some("gltf" | "glb") => gltf::read_beside(&data, path).map(LoadedSurface::from),
        _ => Err(FormatError::unsupported(
            &name,
            "unknown surface extension: expected .obj, .stl, .ply, .gltf or .glb",
        )),
    }
}

/// Writes a tetrahedral mesh; the format follows the extension (`.msh` writes Gmsh 2.2,
/// `.node`/`.ele` write both TetGen files, `.obj` writes the boundary surface).
pub fn write_tet_mesh(
    mesh: &TetMesh,
    path: impl AsRef<Path>,
    options: WriteOptions,
) -> Result<(), FormatError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let is_obj = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("obj"));
    if is_obj {
        let bytes = write_obj(&SurfaceMesh::boundary_of(mesh));
        return std::fs::write(path, bytes).map_err(|e| FormatError::io(path, e));
    }
    let format = MeshFormat::from_path(path).ok_or_else(|| {
        FormatError::unsupported(
            &name,
            "unknown extension: expected .msh, .vtk, .vtu, .node, .ele or .obj",
        )
    })?;
    match format {
        MeshFormat::TetGen => {
            let (node, ele) = tetgen::write(mesh);
            let node_path = path.with_extension("node");
            let ele_path = path.with_extension("ele");
            std::fs::write(&node_path, node).map_err(|e| FormatError::io(&node_path, e))?;
            std::fs::write(&ele_path, ele).map_err(|e| FormatError::io(&ele_path, e))
        }
        _ => {
            let bytes = write_tet_mesh_bytes(mesh, format, options, &name)?;
            std::fs::write(path, bytes).map_err(|e| FormatError::io(path, e))
        }
    }
}

/// Serialises a tetrahedral mesh to bytes in a single-file format.
pub fn write_tet_mesh_bytes(
    mesh: &TetMesh,
    format: MeshFormat,
    options: WriteOptions,
    name: &str,
) -> Result<Vec<u8>, FormatError> {
    match format {
        MeshFormat::Gmsh => Ok(gmsh::write_v22(mesh, options.binary)),
        MeshFormat::VtkLegacy => vtk::write_legacy(mesh, options.binary, name),
        MeshFormat::Vtu => vtk::write_xml(mesh, options.binary, name),
        MeshFormat::TetGen => Err(FormatError::unsupported(
            name,
            "TetGen needs two files: use write_tet_mesh with a .node or .ele path",
        )),
    }
}

/// Writes a TetGen mesh to two byte buffers: the `.node` and the `.ele` file.
pub fn write_tetgen_bytes(mesh: &TetMesh) -> (Vec<u8>, Vec<u8>) {
    tetgen::write(mesh)
}
