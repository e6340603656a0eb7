//! Wavefront OBJ triangle surfaces (visual meshes, cages): `v` and `f` records are read
//! (faces may use `v/vt/vn` forms and negative indices; polygons are fan-triangulated), every
//! other record is ignored.

use super::FormatError;
use super::text::{Cursor, LineFields, parse_i64, show};
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
    let mut faces: Vec<(usize, Vec<i64>)> = Vec::new();
    while let Some((at, line)) = c.next_line() {
        let f = LineFields::new(&c, at, line);
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
                faces.push((at, idx));
            }
            _ => {}
        }
    }
    let n = out.positions.len() as i64;
    for (at, idx) in faces {
        let mut resolved = Vec::with_capacity(idx.len());
        for v in idx {
            let i = if v > 0 { v - 1 } else { n + v };
            if !(0..n).contains(&i) || i > u32::MAX as i64 {
                return Err(c.err_at(
                    at,
                    format!("face refers to vertex {v}, but there are {n} vertices"),
                ));
            }
            resolved.push(i as u32);
        }
        for k in 1..resolved.len() - 1 {
            let t = [resolved[0], resolved[k], resolved[k + 1]];
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                return Err(c.err_at(at, format!("face uses vertex {} twice", t[0] as i64 + 1)));
            }
            out.triangles.push(t);
        }
    }
    if out.triangles.is_empty() {
        return Err(FormatError::unsupported(name, "the OBJ file has no faces"));
    }
    Ok(out)
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
