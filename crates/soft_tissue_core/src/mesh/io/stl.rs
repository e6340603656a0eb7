//! STL triangle surfaces, ASCII (`solid` ... `facet normal` ... `vertex x y z` ...) and
//! binary (an 80-byte header, a triangle count, 50 bytes per triangle). Every triangle has
//! its own three vertices, as the format stores them: the mesher's repair welds them.

use super::FormatError;
use super::obj::SurfaceMesh;
use super::text::{Cursor, LineFields};
use crate::Vec3;

/// Parses an STL file, ASCII or binary. `name` is used in messages.
pub fn parse_stl(data: &[u8], name: &str) -> Result<SurfaceMesh, FormatError> {
    // Binary when the size is exactly what its triangle count says (an ASCII file starts
    // with "solid", but so do some binary headers).
    if data.len() >= 84 {
        let n = u32::from_le_bytes([data[80], data[81], data[82], data[83]]) as usize;
        if n.checked_mul(50).and_then(|b| b.checked_add(84)) == Some(data.len()) {
            return parse_binary(data, n, name);
        }
    }
    let head = data
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .map_or(&data[..0], |i| &data[i..]);
    if head.starts_with(b"solid") {
        return parse_ascii(data, name);
    }
    Err(FormatError::unsupported(
        name,
        "not an STL file: neither `solid` (ASCII) nor a binary triangle count that matches \
         the file's size",
    ))
}

fn parse_binary(data: &[u8], n: usize, name: &str) -> Result<SurfaceMesh, FormatError> {
    if n == 0 {
        return Err(FormatError::unsupported(
            name,
            "the STL file has no triangles",
        ));
    }
    let mut out = SurfaceMesh {
        positions: Vec::with_capacity(3 * n),
        triangles: Vec::with_capacity(n),
    };
    for k in 0..n {
        let rec = &data[84 + 50 * k..84 + 50 * (k + 1)];
        let f = |i: usize| {
            let b = &rec[4 * i..4 * i + 4];
            f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64
        };
        // Floats 0-2 are the normal (recomputed from the vertices, not read).
        for v in 0..3 {
            let p = Vec3::new(f(3 + 3 * v), f(4 + 3 * v), f(5 + 3 * v));
            if !p.iter().all(|c| c.is_finite()) {
                return Err(FormatError::unsupported(
                    name,
                    format!("triangle {k}: vertex {v} is not finite"),
                ));
            }
            out.positions.push(p);
        }
        let b = 3 * k as u32;
        out.triangles.push([b, b + 1, b + 2]);
    }
    Ok(out)
}

fn parse_ascii(data: &[u8], name: &str) -> Result<SurfaceMesh, FormatError> {
    let mut c = Cursor::new(data, name);
    let mut out = SurfaceMesh::default();
    let mut facet: Option<(usize, Vec<Vec3>)> = None;
    while let Some((at, line)) = c.next_line() {
        let f = LineFields::new(&c, at, line);
        match f.toks[0] {
            b"facet" => {
                if facet.is_some() {
                    return Err(c.err_at(at, "`facet` before the last one's `endfacet`"));
                }
                facet = Some((at, Vec::with_capacity(3)));
            }
            b"vertex" => {
                f.need(4, "vertex (vertex x y z)")?;
                let p = Vec3::new(f.f64(1, "x")?, f.f64(2, "y")?, f.f64(3, "z")?);
                if !p.iter().all(|v| v.is_finite()) {
                    return Err(c.err_at(at, "vertex coordinate is not finite"));
                }
                match &mut facet {
                    Some((_, vs)) => vs.push(p),
                    None => return Err(c.err_at(at, "`vertex` outside a facet")),
                }
            }
            b"endfacet" => {
                let Some((start, vs)) = facet.take() else {
                    return Err(c.err_at(at, "`endfacet` without a `facet`"));
                };
                if vs.len() < 3 {
                    return Err(c.err_at(
                        start,
                        format!("facet with {} vertices (at least 3)", vs.len()),
                    ));
                }
                // A polygon facet is fan-triangulated.
                let b = out.positions.len() as u32;
                for k in 1..vs.len() as u32 - 1 {
                    out.triangles.push([b, b + k, b + k + 1]);
                }
                out.positions.extend(vs);
            }
            _ => {}
        }
    }
    if let Some((start, _)) = facet {
        return Err(c.err_at(start, "facet without `endfacet`"));
    }
    if out.triangles.is_empty() {
        return Err(FormatError::unsupported(name, "the STL file has no facets"));
    }
    Ok(out)
}

/// Writes a binary STL (normals from the triangles).
pub fn write_stl(s: &SurfaceMesh) -> Vec<u8> {
    let mut out = vec![0u8; 80];
    out[..20].copy_from_slice(b"bevy_soft_tissue STL");
    out.extend((s.triangles.len() as u32).to_le_bytes());
    for t in &s.triangles {
        let [a, b, c] = t.map(|v| s.positions[v as usize]);
        let n = (b - a).cross(&(c - a));
        let n = if n.norm() > 0.0 { n.normalize() } else { n };
        for v in [n, a, b, c] {
            for x in v.iter() {
                out.extend((*x as f32).to_le_bytes());
            }
        }
        out.extend([0u8, 0u8]);
    }
    out
}
