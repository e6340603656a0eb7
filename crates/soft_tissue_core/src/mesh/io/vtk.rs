//! VTK unstructured grids: legacy `.vtk` (our reader and writer, ASCII and big-endian binary,
//! versions up to 5.1) and XML `.vtu` (read and base64 write through `vtkio`, plus our own
//! ASCII writer).
//!
//! The legacy reader is ours because `vtkio`'s legacy parser reports failures without a
//! location ("Parse error: Tag"); this one names the line or byte offset.

use super::elements::{VolumeKind, split};
use super::text::{Cursor, Res, parse_f64, parse_i64, show};
use super::{FormatError, LoadedMesh, RawMesh};
use crate::Vec3;
use crate::mesh::TetMesh;
use std::fmt::Write as _;

/// What a VTK cell type becomes.
enum CellUse {
    Tet { reduced: bool },
    Split(VolumeKind, bool),
    Skip(&'static str),
}

fn cell_use(ty: u8) -> (CellUse, Option<usize>) {
    use CellUse::*;
    match ty {
        10 => (Tet { reduced: false }, Some(4)),
        24 => (Tet { reduced: true }, Some(10)),
        11 | 12 => (Split(VolumeKind::Hexahedron, ty == 11), Some(8)),
        25 => (Split(VolumeKind::Hexahedron, false), Some(20)),
        29 => (Split(VolumeKind::Hexahedron, false), Some(27)),
        13 => (Split(VolumeKind::Wedge, false), Some(6)),
        26 => (Split(VolumeKind::Wedge, false), Some(15)),
        14 => (Split(VolumeKind::Pyramid, false), Some(5)),
        27 => (Split(VolumeKind::Pyramid, false), Some(13)),
        1 | 2 => (Skip("vertices"), None),
        3 | 4 | 21 | 35 => (Skip("lines"), None),
        5 | 6 | 7 | 22 | 34 => (Skip("triangles or polygons"), None),
        8 | 9 | 23 | 28 | 30 => (Skip("quadrilaterals"), None),
        _ => (Skip("cells of other types"), None),
    }
}

fn cell_name(ty: u8) -> &'static str {
    match ty {
        10 => "tetra",
        24 => "quadratic tetra",
        11 => "voxel",
        12 => "hexahedron",
        13 => "wedge",
        14 => "pyramid",
        _ => "cell",
    }
}

/// Adds cells to `raw`. `cells` yields (cell index, VTK type, point indices).
fn add_cells<'c>(
    raw: &mut RawMesh,
    file: &str,
    point_count: usize,
    cells: impl Iterator<Item = (usize, u8, &'c [u64])>,
) -> Res<()> {
    raw.origin_label = "cell";
    for (k, ty, pts) in cells {
        let (u, expected) = cell_use(ty);
        if let Some(n) = expected
            && pts.len() != n
        {
            return Err(FormatError::parse(
                file,
                super::Location::File,
                format!(
                    "cell {k} of type {ty} ({}) has {} points, needs {n}",
                    cell_name(ty),
                    pts.len()
                ),
            ));
        }
        if let CellUse::Skip(what) = u {
            raw.skip(what);
            continue;
        }
        let mut idx = [0usize; 27];
        for (i, &p) in pts.iter().enumerate().take(27) {
            if p as usize >= point_count || p > usize::MAX as u64 {
                return Err(FormatError::parse(
                    file,
                    super::Location::File,
                    format!("cell {k} refers to point {p}, but there are {point_count} points"),
                ));
            }
            idx[i] = p as usize;
        }
        match u {
            CellUse::Tet { reduced } => {
                raw.tets.push([idx[0], idx[1], idx[2], idx[3]]);
                raw.origin.push(k as u64);
                raw.reduced_order += usize::from(reduced);
            }
            CellUse::Split(kind, voxel) => {
                let corners: Vec<usize> = if voxel {
                    // VTK voxel order (x fastest) to hexahedron order (counter-clockwise).
                    [0, 1, 3, 2, 4, 5, 7, 6].iter().map(|&i| idx[i]).collect()
                } else {
                    idx[..kind.corners()].to_vec()
                };
                split(raw, kind, &corners, k as u64);
            }
            CellUse::Skip(_) => {}
        }
    }
    Ok(())
}

#[derive(Clone, Copy)]
enum Scalar {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    U64,
    I64,
    F32,
    F64,
}

impl Scalar {
    fn parse(tok: &str) -> Option<Self> {
        Some(match tok.to_ascii_lowercase().as_str() {
            "unsigned_char" => Self::U8,
            "char" => Self::I8,
            "unsigned_short" => Self::U16,
            "short" => Self::I16,
            "unsigned_int" => Self::U32,
            "int" => Self::I32,
            "unsigned_long" | "vtktypeuint64" | "vtkidtype" => Self::U64,
            "long" | "vtktypeint64" => Self::I64,
            "float" => Self::F32,
            "double" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::U8 | Self::I8 => 1,
            Self::U16 | Self::I16 => 2,
            Self::U32 | Self::I32 | Self::F32 => 4,
            Self::U64 | Self::I64 | Self::F64 => 8,
        }
    }

    /// Decodes one big-endian value.
    fn decode(self, b: &[u8]) -> f64 {
        let mut a = [0u8; 8];
        a[..b.len()].copy_from_slice(b);
        match self {
            Self::U8 => f64::from(b[0]),
            Self::I8 => f64::from(b[0] as i8),
            Self::U16 => f64::from(u16::from_be_bytes([a[0], a[1]])),
            Self::I16 => f64::from(i16::from_be_bytes([a[0], a[1]])),
            Self::U32 => f64::from(u32::from_be_bytes([a[0], a[1], a[2], a[3]])),
            Self::I32 => f64::from(i32::from_be_bytes([a[0], a[1], a[2], a[3]])),
            Self::U64 => u64::from_be_bytes(a) as f64,
            Self::I64 => i64::from_be_bytes(a) as f64,
            Self::F32 => f64::from(f32::from_be_bytes([a[0], a[1], a[2], a[3]])),
            Self::F64 => f64::from_be_bytes(a),
        }
    }
}

struct Legacy<'a> {
    c: Cursor<'a>,
    binary: bool,
}

impl<'a> Legacy<'a> {
    /// Reads `n` numbers of type `ty` (ASCII tokens or big-endian binary).
    fn numbers(&mut self, n: usize, ty: Scalar, what: &str) -> Res<Vec<f64>> {
        let mut out =
            Vec::with_capacity(n.min(self.c.data.len() - self.c.pos.min(self.c.data.len())));
        if self.binary {
            let size = ty.size();
            let total = n.checked_mul(size).ok_or_else(|| {
                self.c
                    .err_byte(self.c.pos, format!("{what}: count {n} is too large"))
            })?;
            let bytes = self.c.bytes(total, what)?;
            out.extend(bytes.chunks_exact(size).map(|b| ty.decode(b)));
        } else {
            for i in 0..n {
                let Some((at, tok)) = self.c.next_token() else {
                    return Err(self.c.err_at(
                        self.c.data.len(),
                        format!("file ends after {i} of the {n} values of {what}"),
                    ));
                };
                let v = parse_f64(tok).ok_or_else(|| {
                    self.c
                        .err_at(at, format!("{what}: '{}' is not a number", show(tok)))
                })?;
                out.push(v);
            }
        }
        Ok(out)
    }

    /// Reads `n` non-negative integers.
    fn integers(&mut self, n: usize, ty: Scalar, what: &str) -> Res<Vec<u64>> {
        let start = self.c.pos;
        let values = self.numbers(n, ty, what)?;
        values
            .into_iter()
            .map(|v| {
                if v >= 0.0 && v.fract() == 0.0 && v < 1.8e19 {
                    Ok(v as u64)
                } else {
                    Err(self
                        .c
                        .err_at(start, format!("{what}: {v} is not a non-negative integer")))
                }
            })
            .collect()
    }
}

fn keyword_fields(line: &[u8]) -> Vec<String> {
    super::text::tokens(line)
        .map(|t| String::from_utf8_lossy(t).into_owned())
        .collect()
}

fn field_usize(c: &Cursor<'_>, at: usize, fields: &[String], i: usize, what: &str) -> Res<usize> {
    let tok = fields
        .get(i)
        .ok_or_else(|| c.err_at(at, format!("{} needs {what}", fields[0])))?;
    parse_i64(tok.as_bytes())
        .and_then(|v| usize::try_from(v).ok())
        .ok_or_else(|| {
            c.err_at(
                at,
                format!(
                    "{what}: '{}' is not a non-negative integer",
                    show(tok.as_bytes())
                ),
            )
        })
}

/// Parses a legacy VTK file.
pub(crate) fn parse_legacy(data: &[u8], name: &str) -> Res<LoadedMesh> {
    let mut c = Cursor::new(data, name);
    let first = c.raw_line().unwrap_or_default();
    let Some(rest) = first
        .to_ascii_lowercase()
        .strip_prefix(b"# vtk datafile version")
        .map(|r| r.to_vec())
    else {
        return Err(c.err_at(
            0,
            "not a legacy VTK file: the first line must be '# vtk DataFile Version x.x'",
        ));
    };
    let version: f64 = parse_f64(rest.trim_ascii()).unwrap_or(3.0);
    let _title = c.raw_line();
    let (at, mode) = c.expect_line("ASCII or BINARY")?;
    let binary = match mode.to_ascii_uppercase().as_slice() {
        b"ASCII" => false,
        b"BINARY" => true,
        _ => {
            return Err(c.err_at(
                at,
                format!("third line must be ASCII or BINARY, found '{}'", show(mode)),
            ));
        }
    };
    let (at, dataset) = c.expect_line("DATASET")?;
    let ds = keyword_fields(dataset);
    if ds.len() != 2 || !ds[0].eq_ignore_ascii_case("DATASET") {
        return Err(c.err_at(
            at,
            format!(
                "expected 'DATASET UNSTRUCTURED_GRID', found '{}'",
                show(dataset)
            ),
        ));
    }
    match ds[1].to_ascii_uppercase().as_str() {
        "UNSTRUCTURED_GRID" => {}
        "POLYDATA" => {
            return Err(FormatError::unsupported(
                name,
                "the file has no tetrahedra: it is a POLYDATA surface, not a volume mesh",
            ));
        }
        other => {
            return Err(FormatError::unsupported(
                name,
                format!(
                    "dataset {other} is not supported: only UNSTRUCTURED_GRID holds tetrahedra"
                ),
            ));
        }
    }
    let mut r = Legacy { c, binary };
    let mut points: Option<Vec<f64>> = None;
    let mut cells: Option<(Vec<u64>, Vec<u64>)> = None; // (offsets with leading 0, connectivity)
    let mut types: Option<Vec<u64>> = None;
    while let Some((at, line)) = r.c.next_line() {
        let f = keyword_fields(line);
        match f[0].to_ascii_uppercase().as_str() {
            "POINTS" => {
                let n = field_usize(&r.c, at, &f, 1, "a point count")?;
                let ty = f.get(2).and_then(|t| Scalar::parse(t)).ok_or_else(|| {
                    r.c.err_at(at, "POINTS needs a data type such as float or double")
                })?;
                let count = n
                    .checked_mul(3)
                    .ok_or_else(|| r.c.err_at(at, "point count too large"))?;
                points = Some(r.numbers(count, ty, "POINTS")?);
            }
            "CELLS" => {
                let a = field_usize(&r.c, at, &f, 1, "a cell count")?;
                let b = field_usize(&r.c, at, &f, 2, "a size")?;
                if version >= 5.0 {
                    let mut arrays = Vec::new();
                    for (want, n) in [("OFFSETS", a), ("CONNECTIVITY", b)] {
                        let (at2, l2) = r.c.expect_line(want)?;
                        let f2 = keyword_fields(l2);
                        if !f2[0].eq_ignore_ascii_case(want) {
                            return Err(r
                                .c
                                .err_at(at2, format!("expected {want}, found '{}'", show(l2))));
                        }
                        let ty = f2.get(1).and_then(|t| Scalar::parse(t)).ok_or_else(|| {
                            r.c.err_at(
                                at2,
                                format!("{want} needs a data type such as vtktypeint64"),
                            )
                        })?;
                        arrays.push(r.integers(n, ty, want)?);
                    }
                    let conn = arrays.pop().unwrap_or_default();
                    let offsets = arrays.pop().unwrap_or_default();
                    cells = Some((offsets, conn));
                } else {
                    let list = r.integers(b, Scalar::I32, "CELLS")?;
                    let mut offsets = vec![0u64];
                    let mut conn = Vec::with_capacity(list.len());
                    let mut i = 0usize;
                    for k in 0..a {
                        let Some(&n) = list.get(i) else {
                            return Err(r.c.err_at(at, format!("CELLS declares {a} cells in {b} values, but the values end at cell {k}")));
                        };
                        let end = i.saturating_add(1).saturating_add(n as usize);
                        if end > list.len() {
                            return Err(r.c.err_at(
                                at,
                                format!(
                                    "cell {k} declares {n} points, past the {b} values of CELLS"
                                ),
                            ));
                        }
                        conn.extend_from_slice(&list[i + 1..end]);
                        offsets.push(conn.len() as u64);
                        i = end;
                    }
                    if i != list.len() {
                        return Err(r.c.err_at(
                            at,
                            format!("CELLS declares size {b}, but its {a} cells use {i} values"),
                        ));
                    }
                    cells = Some((offsets, conn));
                }
            }
            "CELL_TYPES" => {
                let n = field_usize(&r.c, at, &f, 1, "a count")?;
                types = Some(r.integers(n, Scalar::I32, "CELL_TYPES")?);
            }
            "METADATA" => {
                // Skip until the blank line that ends the metadata block.
                while let Some(l) = r.c.raw_line() {
                    if l.is_empty() {
                        break;
                    }
                }
            }
            "POINT_DATA" | "CELL_DATA" | "FIELD" => break,
            other => {
                return Err(r.c.err_at(
                    at,
                    format!(
                        "unexpected keyword '{}' in an unstructured grid",
                        show(other.as_bytes())
                    ),
                ));
            }
        }
    }
    let c = &r.c;
    let points = points.ok_or_else(|| c.err_at(c.data.len(), "the file has no POINTS"))?;
    let (offsets, conn) = cells.ok_or_else(|| c.err_at(c.data.len(), "the file has no CELLS"))?;
    let types = types.ok_or_else(|| c.err_at(c.data.len(), "the file has no CELL_TYPES"))?;
    build(name, &points, &offsets, &conn, &types)
}

/// Shared by both VTK flavours: offsets has a leading 0 and one entry per cell after it.
fn build(
    name: &str,
    points: &[f64],
    offsets: &[u64],
    conn: &[u64],
    types: &[u64],
) -> Res<LoadedMesh> {
    let n_cells = offsets.len().saturating_sub(1);
    if types.len() != n_cells {
        return Err(FormatError::parse(
            name,
            super::Location::File,
            format!("{} cell types for {n_cells} cells", types.len()),
        ));
    }
    let mut raw = RawMesh {
        positions: points
            .chunks_exact(3)
            .map(|p| Vec3::new(p[0], p[1], p[2]))
            .collect(),
        ..Default::default()
    };
    let point_count = raw.positions.len();
    let mut list = Vec::with_capacity(n_cells);
    for k in 0..n_cells {
        let (a, b) = (offsets[k] as usize, offsets[k + 1] as usize);
        if a > b || b > conn.len() {
            return Err(FormatError::parse(
                name,
                super::Location::File,
                format!(
                    "cell {k}: offsets {a}..{b} do not fit the {} connectivity entries",
                    conn.len()
                ),
            ));
        }
        let ty = u8::try_from(types[k]).unwrap_or(u8::MAX);
        list.push((k, ty, &conn[a..b]));
    }
    add_cells(&mut raw, name, point_count, list.into_iter())?;
    raw.finish(name)
}

/// Parses a VTK XML unstructured grid (`.vtu`) through `vtkio`.
pub(crate) fn parse_xml(data: &[u8], name: &str) -> Res<LoadedMesh> {
    use vtkio::model::{DataSet, Piece, VertexNumbers};
    // vtkio 0.7.0-rc2 unwraps optional elements while converting XML to its model (found by
    // fuzzing: a Piece without <Points> panics in xml.rs). Until that is fixed upstream, a
    // panic inside vtkio becomes an error here. With `panic = "abort"` this guard cannot help.
    let count = |needle: &[u8]| data.windows(needle.len()).filter(|w| *w == needle).count();
    if count(b"<Points") < count(b"<Piece ") {
        return Err(FormatError::parse(
            name,
            super::Location::File,
            "malformed VTK XML: a <Piece> has no <Points>",
        ));
    }
    let parsed = std::panic::catch_unwind(|| vtkio::Vtk::parse_xml(data)).map_err(|payload| {
        let why = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown".into());
        FormatError::parse(
            name,
            super::Location::File,
            format!("malformed VTK XML: a required element is missing (vtkio failed: {why})"),
        )
    })?;
    let vtk = parsed.map_err(|e| {
        FormatError::parse(name, super::Location::File, format!("invalid VTK XML: {e}"))
    })?;
    let pieces = match vtk.data {
        DataSet::UnstructuredGrid { pieces, .. } => pieces,
        DataSet::PolyData { .. } => {
            return Err(FormatError::unsupported(
                name,
                "the file has no tetrahedra: it is PolyData (a surface), not a volume mesh",
            ));
        }
        _ => {
            return Err(FormatError::unsupported(
                name,
                "only UnstructuredGrid VTK files hold tetrahedra",
            ));
        }
    };
    let mut points = Vec::new();
    let mut offsets = vec![0u64];
    let mut conn = Vec::new();
    let mut types = Vec::new();
    for (pi, piece) in pieces.into_iter().enumerate() {
        let piece = match piece {
            Piece::Inline(p) => p,
            _ => {
                return Err(FormatError::unsupported(
                    name,
                    format!("piece {pi} is stored in another file (parallel VTU is not supported)"),
                ));
            }
        };
        let base = (points.len() / 3) as u64;
        let p: Vec<f64> = piece.points.cast_into().ok_or_else(|| {
            FormatError::parse(
                name,
                super::Location::File,
                format!("piece {pi}: points are not numeric"),
            )
        })?;
        if !p.len().is_multiple_of(3) {
            return Err(FormatError::parse(
                name,
                super::Location::File,
                format!(
                    "piece {pi}: {} point coordinates is not a multiple of 3",
                    p.len()
                ),
            ));
        }
        points.extend(p);
        let (c, o) = match piece.cells.cell_verts {
            VertexNumbers::XML {
                connectivity,
                offsets,
            } => (connectivity, offsets),
            legacy @ VertexNumbers::Legacy { .. } => legacy.into_xml(),
        };
        let start = conn.len() as u64;
        let mut prev = 0u64;
        let skip = usize::from(o.len() == piece.cells.types.len() + 1 && o.first() == Some(&0));
        for &off in &o[skip..] {
            if off < prev {
                return Err(FormatError::parse(
                    name,
                    super::Location::File,
                    format!("piece {pi}: offsets decrease ({prev} then {off})"),
                ));
            }
            prev = off;
            let Some(at) = start.checked_add(off) else {
                return Err(FormatError::parse(
                    name,
                    super::Location::File,
                    format!("piece {pi}: offset {off} is out of range"),
                ));
            };
            offsets.push(at);
        }
        conn.extend(c.into_iter().map(|v| v.saturating_add(base)));
        types.extend(piece.cells.types.iter().map(|&t| t as u64));
    }
    build(name, &points, &offsets, &conn, &types)
}

fn fmt_f64(v: f64) -> String {
    format!("{v:?}")
}

/// Writes a legacy VTK 4.2 unstructured grid of tetrahedra.
pub(crate) fn write_legacy(mesh: &TetMesh, binary: bool, _name: &str) -> Res<Vec<u8>> {
    let n = mesh.node_count();
    let t = mesh.tet_count();
    let mut out = Vec::new();
    out.extend_from_slice(b"# vtk DataFile Version 4.2\nbevy_soft_tissue tetrahedral mesh\n");
    out.extend_from_slice(if binary { b"BINARY\n" } else { b"ASCII\n" });
    out.extend_from_slice(format!("DATASET UNSTRUCTURED_GRID\nPOINTS {n} double\n").as_bytes());
    if binary {
        for v in mesh.positions().iter().flat_map(|p| p.iter()) {
            out.extend_from_slice(&v.to_be_bytes());
        }
        out.extend_from_slice(format!("\nCELLS {t} {}\n", 5 * t).as_bytes());
        for tet in mesh.tets() {
            out.extend_from_slice(&4i32.to_be_bytes());
            for &v in tet {
                out.extend_from_slice(&(v as i32).to_be_bytes());
            }
        }
        out.extend_from_slice(format!("\nCELL_TYPES {t}\n").as_bytes());
        for _ in 0..t {
            out.extend_from_slice(&10i32.to_be_bytes());
        }
        out.push(b'\n');
    } else {
        let mut s = String::new();
        for p in mesh.positions() {
            let _ = writeln!(s, "{} {} {}", fmt_f64(p.x), fmt_f64(p.y), fmt_f64(p.z));
        }
        let _ = writeln!(s, "CELLS {t} {}", 5 * t);
        for tet in mesh.tets() {
            let _ = writeln!(s, "4 {} {} {} {}", tet[0], tet[1], tet[2], tet[3]);
        }
        let _ = writeln!(s, "CELL_TYPES {t}");
        for _ in 0..t {
            s.push_str("10\n");
        }
        out.extend_from_slice(s.as_bytes());
    }
    Ok(out)
}

/// Writes a `.vtu`: base64 binary through `vtkio`, or plain ASCII.
pub(crate) fn write_xml(mesh: &TetMesh, binary: bool, name: &str) -> Res<Vec<u8>> {
    let n = mesh.node_count();
    let t = mesh.tet_count();
    if binary {
        use vtkio::model::{
            Attributes, ByteOrder, CellType, Cells, DataSet, IOBuffer, UnstructuredGridPiece,
            Version, VertexNumbers,
        };
        let vtk = vtkio::Vtk {
            version: Version::XML { major: 1, minor: 0 },
            title: String::new(),
            byte_order: ByteOrder::LittleEndian,
            file_path: None,
            data: DataSet::inline(UnstructuredGridPiece {
                points: IOBuffer::F64(
                    mesh.positions()
                        .iter()
                        .flat_map(|p| p.iter().copied())
                        .collect(),
                ),
                cells: Cells {
                    cell_verts: VertexNumbers::XML {
                        connectivity: mesh
                            .tets()
                            .iter()
                            .flatten()
                            .map(|&v| u64::from(v))
                            .collect(),
                        offsets: (1..=t as u64).map(|i| 4 * i).collect(),
                    },
                    types: vec![CellType::Tetra; t],
                },
                data: Attributes::new(),
            }),
        };
        let mut out = Vec::new();
        vtk.write_xml(&mut out)
            .map_err(|e| FormatError::unsupported(name, format!("VTK XML writer failed: {e}")))?;
        return Ok(out);
    }
    let mut s = String::new();
    s.push_str("<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n  <UnstructuredGrid>\n");
    let _ = writeln!(
        s,
        "    <Piece NumberOfPoints=\"{n}\" NumberOfCells=\"{t}\">"
    );
    s.push_str("      <Points>\n        <DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n");
    for p in mesh.positions() {
        let _ = writeln!(
            s,
            "          {} {} {}",
            fmt_f64(p.x),
            fmt_f64(p.y),
            fmt_f64(p.z)
        );
    }
    s.push_str("        </DataArray>\n      </Points>\n      <Cells>\n        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n");
    for tet in mesh.tets() {
        let _ = writeln!(s, "          {} {} {} {}", tet[0], tet[1], tet[2], tet[3]);
    }
    s.push_str("        </DataArray>\n        <DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    for i in 1..=t {
        let _ = writeln!(s, "          {}", 4 * i);
    }
    s.push_str("        </DataArray>\n        <DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for _ in 0..t {
        s.push_str("          10\n");
    }
    s.push_str(
        "        </DataArray>\n      </Cells>\n    </Piece>\n  </UnstructuredGrid>\n</VTKFile>\n",
    );
    Ok(s.into_bytes())
}
