//! Wavefront OBJ triangle surfaces (visual meshes, cages): `v` and `f` records are read
//! (faces may use `v/vt/vn` forms and negative indices, which count back from the vertices
//! read so far; polygons are fan-triangulated), every other record is ignored. `#` starts a
//! comment anywhere on a line, a line ending in `\` goes on on the next, and lines may end in
//! LF, CR LF or CR.

use super::FormatError;
use super::text::{Cursor, LineFields, parse_i64, show, tokens};
use crate::Vec3;
use crate::mesh::TetMesh;
use std::fmt::Write as _;

/// A triangle surface.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SurfaceMesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Triangles as indices into `positions`.
    pub triangles: Vec<[u32; 3]>,
}

impl SurfaceMesh {
    /// The boundary surface of a tetrahedral mesh, with its own compact vertex numbering
    /// (vertex `i` is volume node `mesh.surface().vertices()[i]`).
    pub fn boundary_of(mesh: &TetMesh) -> Self {
        let s = mesh.surface();
        Self {
            positions: s
                .vertices()
                .iter()
                .map(|&n| mesh.positions()[n as usize])
                .collect(),
            triangles: s.local_triangles().to_vec(),
        }
    }
}

/// Parses an OBJ file. `name` is used in messages.
pub fn parse_obj(data: &[u8], name: &str) -> Result<SurfaceMesh, FormatError> {
    let mut c = Cursor::new(data, name);
    let mut out = SurfaceMesh::default();
    // Each face's line, its indices, and how many vertices came before it (a negative
    // index counts back from there).
    let mut faces: Vec<(usize, Vec<i64>, usize)> = Vec::new();
    while let Some((at, toks)) = next_record(&mut c) {
        let f = LineFields {
            cursor: &c,
            start: at,
            toks,
        };
        match f.toks[0] {
            b"v" => {
                f.need(4, "vertex (v x y z)")?;
                out.positions
                    .push(Vec3::new(f.f64(1, "x")?, f.f64(2, "y")?, f.f64(3, "z")?));
                if !out
                    .positions
                    .last()
                    .is_some_and(|p| p.iter().all(|v| v.is_finite()))
                {
                    return Err(c.err_at(at, "vertex coordinate is not finite"));
                }
            }
            b"f" => {
                f.need(4, "face (f a b c ...)")?;
                let mut idx = Vec::with_capacity(f.len() - 1);
                for tok in &f.toks[1..] {
                    let first = tok.split(|&b| b == b'/').next().unwrap_or_default();
                    let v = parse_i64(first).filter(|&v| v != 0).ok_or_else(|| {
                        c.err_at(
                            at,
                            format!("face index '{}' is not a non-zero integer", show(tok)),
                        )
                    })?;
                    idx.push(v);
                }
                faces.push((at, idx, out.positions.len()));
            }
            _ => {}
        }
    }
    let n = out.positions.len() as i64;
    for (at, idx, before) in faces {
        let mut corners = Vec::with_capacity(idx.len());
        for v in idx {
            let i = if v > 0 { v - 1 } else { before as i64 + v };
            if !(0..n).contains(&i) || i > u32::MAX as i64 {
                let known = if v > 0 {
                    format!("there are {n} vertices")
                } else {
                    format!("{before} vertices come before the face")
                };
                return Err(c.err_at(at, format!("face refers to vertex {v}, but {known}")));
            }
            corners.push(i as u32);
        }
        out.triangles.extend(fan(&corners));
    }
    if out.triangles.is_empty() {
        return Err(FormatError::unsupported(name, "the OBJ file has no faces"));
    }
    Ok(out)
}

/// The next record's start and fields: a `#` starts a comment that runs to the end of the
/// line, and a line that ends in `\` goes on on the next. `None` at the end.
fn next_record<'a>(c: &mut Cursor<'a>) -> Option<(usize, Vec<&'a [u8]>)> {
    loop {
        let (at, mut line) = c.next_line()?;
        let mut toks = Vec::new();
        loop {
            let body = line
                .split(|&b| b == b'#')
                .next()
                .unwrap_or_default()
                .trim_ascii_end();
            let Some(head) = body.strip_suffix(b"\\") else {
                toks.extend(tokens(body));
                break;
            };
            toks.extend(tokens(head));
            match c.raw_line() {
                Some(next) => line = next,
                None => break,
            }
        }
        if !toks.is_empty() {
            return Some((at, toks));
        }
    }
}

/// A polygon's triangles, fanned from its first corner. A corner repeated in a row (`f a b
/// c c`: a triangle written in a quad's place) is the polygon without the repeat. A face
/// with fewer than three corners left, or one that comes back to a corner later, keeps its
/// degenerate triangles: the mesher's repair counts and drops them, as it does for every
/// format.
fn fan(corners: &[u32]) -> Vec<[u32; 3]> {
    let mut ring = corners.to_vec();
    ring.dedup();
    while ring.len() > 1 && ring.first() == ring.last() {
        ring.pop();
    }
    if ring.len() < 3 {
        ring = corners.to_vec();
    }
    (1..ring.len() - 1)
        .map(|k| [ring[0], ring[k], ring[k + 1]])
        .collect()
}

/// Serialises a surface as OBJ text (1-based indices).
pub fn write_obj(s: &SurfaceMesh) -> Vec<u8> {
    let mut out = String::from("# written by bevy_soft_tissue\n");
    for p in &s.positions {
        let _ = writeln!(out, "v {:?} {:?} {:?}", p.x, p.y, p.z);
    }
    for t in &s.triangles {
        let _ = writeln!(out, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    out.into_bytes()
}
