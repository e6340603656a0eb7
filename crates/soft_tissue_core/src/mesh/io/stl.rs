//! STL triangle surfaces, ASCII (`solid` ... `facet normal` ... `vertex x y z` ...) and
//! binary (an 80-byte header, a triangle count, 50 bytes per triangle). Every triangle has
//! its own three vertices, as the format stores them: the mesher's repair welds them.
//!
//! Which of the two a file is, in this order:
//! 1. binary when the size is exactly 84 bytes plus 50 per triangle of the header's count;
//! 2. ASCII when the text, after an optional UTF-8 byte-order mark and whitespace, starts
//!    with `solid` in any case and either the file is shorter than a binary header or its
//!    first kilobyte is text (no control bytes other than whitespace) naming `facet` or
//!    `endsolid` (a binary header may start with `solid` too, but its count field and its
//!    floats hold zero bytes);
//! 3. binary otherwise, when the file is at least 84 bytes long. The header's count is
//!    trusted only where the bytes agree: a count of 0 (streaming exporters write it) or any
//!    count below what the bytes hold reads every whole triangle the bytes hold; a count equal to
//!    what they hold reads it and ignores fewer than 50 bytes of trailing padding; a count
//!    above it reads what they hold when the data is a whole number of triangles, and is a
//!    truncated file, refused with both numbers, when it is not. Wherever the data overrules
//!    the count, or bytes after the last triangle are ignored, [`parse_stl_with_notes`]
//!    says so in a note naming both counts.
//!
//! ASCII keywords are matched in any case, and every `solid` ... `endsolid` block of a file
//! is read.

use super::obj::SurfaceMesh;
use super::text::{Cursor, LineFields, UTF8_BOM};
use super::{FormatError, LoadedSurface};
use crate::Vec3;

const HEADER: usize = 84;
const RECORD: usize = 50;

/// Parses an STL file, ASCII or binary. `name` is used in messages. The notes
/// [`parse_stl_with_notes`] gives are dropped.
pub fn parse_stl(data: &[u8], name: &str) -> Result<SurfaceMesh, FormatError> {
    parse_stl_with_notes(data, name).map(|read| read.surface)
}

/// Parses an STL file, ASCII or binary, with a note where a binary file's header count is
/// overruled by its data or bytes after its last triangle are ignored. `name` is used in
/// messages.
pub fn parse_stl_with_notes(data: &[u8], name: &str) -> Result<LoadedSurface, FormatError> {
    let stated = stated_count(data);
    if stated.is_some_and(|n| {
        n.checked_mul(RECORD).and_then(|b| b.checked_add(HEADER)) == Some(data.len())
    }) {
        return parse_binary(data, name);
    }
    let text = data.strip_prefix(UTF8_BOM).unwrap_or(data);
    if starts_with_solid(text) && (data.len() < HEADER || looks_like_ascii_stl(text)) {
        return parse_ascii(text, name).map(LoadedSurface::from);
    }
    if stated.is_some() {
        return parse_binary(data, name);
    }
    Err(FormatError::unsupported(
        name,
        format!(
            "not an STL file: it does not start with `solid` (ASCII), and its {} bytes are \
             fewer than a binary STL's {HEADER}-byte header",
            data.len()
        ),
    ))
}

/// The triangle count in a binary header, if the file is long enough to have one.
fn stated_count(data: &[u8]) -> Option<usize> {
    let b = data.get(80..HEADER)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
}

/// Whether the text, after leading whitespace, starts with `solid` in any case.
fn starts_with_solid(text: &[u8]) -> bool {
    let start = text.trim_ascii_start();
    start
        .get(..5)
        .is_some_and(|w| w.eq_ignore_ascii_case(b"solid"))
}

/// Whether the first kilobyte is text naming `facet` or `endsolid` (in any case).
fn looks_like_ascii_stl(text: &[u8]) -> bool {
    let head = &text[..text.len().min(1024)];
    let is_text = head
        .iter()
        .all(|&b| b.is_ascii_whitespace() || !(b.is_ascii_control()));
    let lower = head.to_ascii_lowercase();
    let names = |w: &[u8]| lower.windows(w.len()).any(|x| x == w);
    is_text && (names(b"facet") || names(b"endsolid"))
}

/// How many triangles to read from a binary file, by the rule in the module's doc.
fn binary_count(data: &[u8], name: &str) -> Result<usize, FormatError> {
    let stated = stated_count(data).unwrap_or(0);
    let body = data.len().saturating_sub(HEADER);
    let (held, rest) = (body / RECORD, body % RECORD);
    if stated > held && rest != 0 {
        return Err(FormatError::unsupported(
            name,
            format!(
                "truncated binary STL: the header says {stated} triangles, but the {body} \
                 bytes after it hold {held} whole triangles and {rest} bytes of another"
            ),
        ));
    }
    let n = if stated == held { stated } else { held };
    if n == 0 {
        return Err(FormatError::unsupported(
            name,
            format!(
                "the binary STL file has no triangles: the header says {stated}, and the \
                 {body} bytes after it hold {held}"
            ),
        ));
    }
    Ok(n)
}

fn parse_binary(data: &[u8], name: &str) -> Result<LoadedSurface, FormatError> {
    let n = binary_count(data, name)?;
    let stated = stated_count(data).unwrap_or(0);
    // Where the header disagrees, every message names both counts, and so does the note.
    let counts = if stated == n {
        String::new()
    } else {
        format!(" (the header says {stated} triangles; the file holds {n})")
    };
    let ignored = data.len().saturating_sub(HEADER + n * RECORD);
    let note = match (stated == n, ignored) {
        (true, 0) => None,
        (true, _) => Some(format!(
            "binary STL: {ignored} bytes after the header's {n} triangles, less than a \
             triangle (ignored)"
        )),
        (false, 0) => Some(format!(
            "binary STL header says {stated} triangles; the data holds {n} (read those)"
        )),
        (false, _) => Some(format!(
            "binary STL header says {stated} triangles; the data holds {n} (read those), \
             and {ignored} bytes after them, less than a triangle (ignored)"
        )),
    };
    let mut out = SurfaceMesh {
        positions: Vec::with_capacity(3 * n),
        triangles: Vec::with_capacity(n),
    };
    let records = data.get(HEADER..).unwrap_or_default().chunks_exact(RECORD);
    for (k, rec) in records.take(n).enumerate() {
        // Floats 0-2 are the normal (recomputed from the vertices, not read).
        for v in 0..3 {
            let p = Vec3::from_fn(|i, _| f32_at(rec, 3 + 3 * v + i));
            if !p.iter().all(|c| c.is_finite()) {
                return Err(FormatError::unsupported(
                    name,
                    format!("triangle {k}: vertex {v} is not finite{counts}"),
                ));
            }
            out.positions.push(p);
        }
        let b = 3 * k as u32;
        out.triangles.push([b, b + 1, b + 2]);
    }
    Ok(LoadedSurface {
        surface: out,
        notes: note.into_iter().collect(),
    })
}

/// The `i`-th little-endian float of a record (NaN past its end, which cannot happen for a
/// whole record).
fn f32_at(rec: &[u8], i: usize) -> f64 {
    match rec.get(4 * i..4 * i + 4) {
        Some(&[a, b, c, d]) => f32::from_le_bytes([a, b, c, d]) as f64,
        _ => f64::NAN,
    }
}

fn parse_ascii(data: &[u8], name: &str) -> Result<SurfaceMesh, FormatError> {
    let mut c = Cursor::new(data, name);
    let mut out = SurfaceMesh::default();
    let mut facet: Option<(usize, Vec<Vec3>)> = None;
    while let Some((at, line)) = c.next_line() {
        let f = LineFields::new(&c, at, line);
        let keyword = f.toks.first().map(|t| t.to_ascii_lowercase());
        match keyword.as_deref().unwrap_or_default() {
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
