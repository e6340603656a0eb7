//! PLY triangle surfaces: ASCII, binary little-endian and binary big-endian. The `vertex`
//! element's `x`, `y`, `z`, the `face` element's index list (`vertex_indices` or
//! `vertex_index`) and the `tristrips` element's (old Stanford and Cyberware scans give
//! their faces so) are read; every other element and property is skipped by its declared
//! type. Polygons are fan-triangulated. A strip's triangles alternate, (i0 i1 i2),
//! (i2 i1 i3), (i2 i3 i4), ..., so that all keep its winding; -1 ends a strip and starts
//! another (so does each row of the element), and the degenerate triangles that join strips
//! (a repeated index) are skipped. A file with both elements gives both.
//!
//! A UTF-8 byte order mark before `ply` is skipped. The header ends at the first line that
//! is exactly `end_header` (trimmed), so a comment naming it does not cut the header short;
//! its lines may end in `\n`, `\r\n`, or a lone `\r` (where the `ply` line does, every `\r`
//! ends a line alone). A face or strip index that is not one of the file's vertices is
//! refused with the face's (or strip row's) number in its element, the index and the vertex
//! count.

use super::FormatError;
use super::obj::SurfaceMesh;
use super::text::UTF8_BOM;
use crate::Vec3;

#[derive(Clone, Copy, PartialEq)]
enum Encoding {
    Ascii,
    Little,
    Big,
}

#[derive(Clone, Copy)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(t: &str) -> Option<Scalar> {
        Some(match t {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
}

enum Property {
    Scalar(String, Scalar),
    List(String, Scalar, Scalar),
}

struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

/// Reads values one at a time from the body, in the file's encoding.
struct Body<'a> {
    data: &'a [u8],
    pos: usize,
    encoding: Encoding,
    name: &'a str,
}

impl Body<'_> {
    fn err(&self, msg: impl Into<String>) -> FormatError {
        FormatError::unsupported(self.name, format!("byte {}: {}", self.pos, msg.into()))
    }

    fn value(&mut self, s: Scalar) -> Result<f64, FormatError> {
        if self.encoding == Encoding::Ascii {
            while self.pos < self.data.len() && self.data[self.pos].is_ascii_whitespace() {
                self.pos += 1;
            }
            let start = self.pos;
            while self.pos < self.data.len() && !self.data[self.pos].is_ascii_whitespace() {
                self.pos += 1;
            }
            if start == self.pos {
                return Err(self.err("the data ends before the declared elements do"));
            }
            let tok = std::str::from_utf8(&self.data[start..self.pos]).unwrap_or("");
            return tok
                .parse::<f64>()
                .map_err(|_| self.err(format!("`{tok}` is not a number")));
        }
        let n = s.size();
        let Some(b) = self.data.get(self.pos..self.pos + n) else {
            return Err(self.err("the data ends before the declared elements do"));
        };
        self.pos += n;
        let mut a = [0u8; 8];
        a[..n].copy_from_slice(b);
        if self.encoding == Encoding::Big {
            a[..n].reverse();
        }
        Ok(match s {
            Scalar::I8 => a[0] as i8 as f64,
            Scalar::U8 => a[0] as f64,
            Scalar::I16 => i16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F64 => f64::from_le_bytes(a),
        })
    }
}

/// Parses a PLY file. `name` is used in messages.
pub fn parse_ply(data: &[u8], name: &str) -> Result<SurfaceMesh, FormatError> {
    let (lines, body_start) = split_header(data, name)?;
    let (encoding, elements) = parse_header(&lines, name)?;
    let mut body = Body {
        data,
        pos: body_start,
        encoding,
        name,
    };
    read_body(&mut body, &elements)
}

/// The header's lines, trimmed (`ply` first), and the byte where the body starts: after
/// the first line that is exactly `end_header` (a comment naming it does not end the
/// header). A UTF-8 byte order mark before `ply` is skipped. Lines end in `\n`, `\r\n` or
/// a lone `\r`; where the first line ends in a lone `\r`, every `\r` ends a line alone (a
/// binary body that starts with `\n` keeps it).
fn split_header<'a>(data: &'a [u8], name: &str) -> Result<(Vec<&'a [u8]>, usize), FormatError> {
    let bad = |msg: &str| FormatError::unsupported(name, msg);
    let mut pos = if data.starts_with(UTF8_BOM) {
        UTF8_BOM.len()
    } else {
        0
    };
    let first_end = data
        .iter()
        .skip(pos)
        .position(|&b| b == b'\n' || b == b'\r')
        .map(|i| pos + i);
    let cr_only = first_end
        .and_then(|i| data.get(i..))
        .is_some_and(|t| t.starts_with(b"\r") && !t.starts_with(b"\r\n"));
    let mut lines = Vec::new();
    while pos < data.len() {
        let (line, next) = header_line(data, pos, cr_only);
        if lines.is_empty() && line != b"ply" {
            return Err(bad("the file does not start with `ply`"));
        }
        lines.push(line);
        pos = next;
        if line == b"end_header" {
            return Ok((lines, pos));
        }
    }
    Err(bad(
        "no `end_header` line: not a PLY file, or its header is cut short",
    ))
}

/// The line starting at `pos`, trimmed, and where the next one starts.
fn header_line(data: &[u8], pos: usize, cr_only: bool) -> (&[u8], usize) {
    let rest = data.get(pos..).unwrap_or_default();
    let Some(end) = rest.iter().position(|&b| b == b'\n' || b == b'\r') else {
        return (rest.trim_ascii(), data.len());
    };
    let crlf = !cr_only && rest.get(end..end + 2) == Some(b"\r\n");
    (
        rest[..end].trim_ascii(),
        pos + end + if crlf { 2 } else { 1 },
    )
}

/// The encoding and the elements the header declares.
fn parse_header(lines: &[&[u8]], name: &str) -> Result<(Encoding, Vec<Element>), FormatError> {
    let bad = |msg: String| FormatError::unsupported(name, msg);
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    for (k, line) in lines.iter().enumerate().skip(1) {
        let line_no = k + 1;
        let text = String::from_utf8_lossy(line);
        let f: Vec<&str> = text.split_whitespace().collect();
        match f.first().copied() {
            Some("format") => {
                encoding = Some(match f.get(1).copied() {
                    Some("ascii") => Encoding::Ascii,
                    Some("binary_little_endian") => Encoding::Little,
                    Some("binary_big_endian") => Encoding::Big,
                    other => {
                        return Err(bad(format!(
                            "header line {line_no}: unknown format {other:?}"
                        )));
                    }
                });
            }
            Some("element") => {
                let (Some(n), Some(count)) = (f.get(1), f.get(2).and_then(|c| c.parse().ok()))
                else {
                    return Err(bad(format!(
                        "header line {line_no}: `element NAME COUNT` expected"
                    )));
                };
                elements.push(Element {
                    name: n.to_string(),
                    count,
                    properties: Vec::new(),
                });
            }
            Some("property") => {
                let Some(e) = elements.last_mut() else {
                    return Err(bad(format!(
                        "header line {line_no}: a property before any element"
                    )));
                };
                let p =
                    parse_property(&f).map_err(|m| bad(format!("header line {line_no}: {m}")))?;
                e.properties.push(p);
            }
            _ => {}
        }
    }
    let encoding = encoding.ok_or_else(|| bad("no `format` line".into()))?;
    Ok((encoding, elements))
}

/// A `property TYPE NAME` or `property list COUNT_TYPE ITEM_TYPE NAME` line's fields.
fn parse_property(f: &[&str]) -> Result<Property, String> {
    match f {
        ["property", "list", c, v, n] => match (Scalar::parse(c), Scalar::parse(v)) {
            (Some(c), Some(v)) => Ok(Property::List(n.to_string(), c, v)),
            _ => Err(format!("unknown list types `{c}`, `{v}`")),
        },
        ["property", t, n] => match Scalar::parse(t) {
            Some(t) => Ok(Property::Scalar(n.to_string(), t)),
            None => Err(format!("unknown type `{t}`")),
        },
        _ => Err("`property TYPE NAME` expected".into()),
    }
}

/// One entry of an element: its `x`, `y`, `z` (NaN where absent) and its vertex index
/// list, if it has one (`vertex_indices` or `vertex_index` of a `face` or a `tristrips`).
type Entry = ([f64; 3], Option<Vec<f64>>);

/// Reads every element's entries, keeping the vertices and the faces' triangles.
fn read_body(body: &mut Body, elements: &[Element]) -> Result<SurfaceMesh, FormatError> {
    let name = body.name;
    let bad = |msg: String| FormatError::unsupported(name, msg);
    // A count the data cannot hold is refused before anything is reserved.
    if let Some(e) = elements.iter().find(|e| e.count > body.data.len()) {
        return Err(bad(format!(
            "element `{}` declares {} entries, more than the file's {} bytes",
            e.name,
            e.count,
            body.data.len()
        )));
    }
    // Each vertex entry gives one vertex, so the count is known before any face or strip
    // is read, wherever they come.
    let vertices = elements
        .iter()
        .filter(|e| e.name == "vertex")
        .fold(0usize, |n, e| n.saturating_add(e.count));
    let mut out = SurfaceMesh::default();
    for e in elements {
        for j in 0..e.count {
            let (xyz, face) = read_entry(body, e)?;
            if e.name == "vertex" {
                if !xyz.iter().all(|c| c.is_finite()) {
                    return Err(bad(format!(
                        "vertex {}: x, y and z must be present and finite",
                        out.positions.len()
                    )));
                }
                out.positions.push(Vec3::new(xyz[0], xyz[1], xyz[2]));
            }
            match (e.name.as_str(), face) {
                ("tristrips", Some(items)) => {
                    add_strips(&mut out.triangles, &items, j, vertices, body)?;
                }
                (_, Some(items)) => add_face(&mut out.triangles, &items, j, vertices, body)?,
                (_, None) => {}
            }
        }
    }
    if out.triangles.is_empty() {
        return Err(bad(
            "the PLY file has no faces: neither a `face` nor a `tristrips` element gives a \
             triangle"
                .into(),
        ));
    }
    Ok(out)
}

/// Reads one entry of element `e`.
fn read_entry(body: &mut Body, e: &Element) -> Result<Entry, FormatError> {
    let mut xyz = [f64::NAN; 3];
    let mut face = None;
    for p in &e.properties {
        match p {
            Property::Scalar(n, t) => {
                let v = body.value(*t)?;
                if e.name == "vertex" {
                    match n.as_str() {
                        "x" => xyz[0] = v,
                        "y" => xyz[1] = v,
                        "z" => xyz[2] = v,
                        _ => {}
                    }
                }
            }
            Property::List(n, c, v) => {
                let count = body.value(*c)?;
                // Each entry takes at least a byte, in either encoding: a longer list is
                // refused before anything is reserved, and what is reserved up front is
                // bounded (a strip row of a large scan holds millions of entries).
                let left = body.data.len().saturating_sub(body.pos);
                if !(count >= 0.0 && count <= left as f64) {
                    return Err(body.err(format!(
                        "a list of {count} entries, more than the {left} bytes left"
                    )));
                }
                let mut items = Vec::with_capacity((count as usize).min(1 << 16));
                for _ in 0..count as usize {
                    items.push(body.value(*v)?);
                }
                if (e.name == "face" || e.name == "tristrips")
                    && (n == "vertex_indices" || n == "vertex_index")
                {
                    face = Some(items);
                }
            }
        }
    }
    Ok((xyz, face))
}

/// Fan-triangulates face number `face` (0-based in its element), whose vertex indices must
/// name one of the file's `vertices` vertices.
fn add_face(
    triangles: &mut Vec<[u32; 3]>,
    items: &[f64],
    face: usize,
    vertices: usize,
    body: &Body,
) -> Result<(), FormatError> {
    if items.len() < 3 {
        return Err(body.err(format!(
            "face {face}: {} vertices (at least 3)",
            items.len()
        )));
    }
    let idx = items
        .iter()
        .map(|&i| vertex_number(i, || format!("face {face}"), vertices, body))
        .collect::<Result<Vec<u32>, _>>()?;
    if let Some((&first, rest)) = idx.split_first() {
        triangles.extend(rest.windows(2).map(|w| [first, w[0], w[1]]));
    }
    Ok(())
}

/// Adds the triangles of row `row` (0-based in its element) of a `tristrips` element: -1
/// (4294967295 in an unsigned list) ends a strip and starts another; in each strip triangle `k` is (i_k, i_k+1, i_k+2) for
/// even `k` and (i_k+1, i_k, i_k+2) for odd `k`, so that all keep the strip's winding.
/// Triangles with a repeated index (strip joins) are skipped. Every other index must name
/// one of the file's `vertices` vertices.
fn add_strips(
    triangles: &mut Vec<[u32; 3]>,
    items: &[f64],
    row: usize,
    vertices: usize,
    body: &Body,
) -> Result<(), FormatError> {
    let at = || format!("tristrips {row}");
    // -1 as a signed index; as an unsigned one (`list uchar uint`), its 32-bit pattern.
    for strip in items.split(|&i| i == -1.0 || i == u32::MAX as f64) {
        let idx = strip
            .iter()
            .map(|&i| vertex_number(i, at, vertices, body))
            .collect::<Result<Vec<u32>, _>>()?;
        for (k, w) in idx.windows(3).enumerate() {
            let t = if k % 2 == 0 {
                [w[0], w[1], w[2]]
            } else {
                [w[1], w[0], w[2]]
            };
            if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
                triangles.push(t);
            }
        }
    }
    Ok(())
}

/// Index `i` of the face or strip `at` names as a vertex number, or an error naming it, the
/// index and the vertex count (the name is written only for the error).
fn vertex_number(
    i: f64,
    at: impl Fn() -> String,
    vertices: usize,
    body: &Body,
) -> Result<u32, FormatError> {
    if i.fract() == 0.0 && i >= 0.0 && i < vertices as f64 && i < u32::MAX as f64 {
        Ok(i as u32)
    } else {
        Err(body.err(format!(
            "{}: vertex index {i} is not a vertex number: the file has {vertices} \
             vertices, numbered from 0",
            at()
        )))
    }
}
