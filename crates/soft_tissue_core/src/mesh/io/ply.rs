//! PLY triangle surfaces: ASCII, binary little-endian and binary big-endian. The `vertex`
//! element's `x`, `y`, `z` and the `face` element's index list (`vertex_indices` or
//! `vertex_index`) are read; every other element and property is skipped by its declared
//! type. Polygons are fan-triangulated.

use super::FormatError;
use super::obj::SurfaceMesh;
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
    let bad = |msg: String| FormatError::unsupported(name, msg);
    let end = data
        .windows(10)
        .position(|w| w == b"end_header")
        .ok_or_else(|| bad("no `end_header`: not a PLY file".into()))?;
    let header =
        std::str::from_utf8(&data[..end]).map_err(|_| bad("the header is not text".into()))?;
    let mut lines = header.lines().map(str::trim);
    if lines.next() != Some("ply") {
        return Err(bad("the file does not start with `ply`".into()));
    }
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    for (k, line) in lines.enumerate() {
        let line_no = k + 2;
        let f: Vec<&str> = line.split_whitespace().collect();
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
                let p = match f.as_slice() {
                    ["property", "list", c, v, n] => match (Scalar::parse(c), Scalar::parse(v)) {
                        (Some(c), Some(v)) => Property::List(n.to_string(), c, v),
                        _ => {
                            return Err(bad(format!(
                                "header line {line_no}: unknown list types `{c}`, `{v}`"
                            )));
                        }
                    },
                    ["property", t, n] => match Scalar::parse(t) {
                        Some(t) => Property::Scalar(n.to_string(), t),
                        None => {
                            return Err(bad(format!("header line {line_no}: unknown type `{t}`")));
                        }
                    },
                    _ => {
                        return Err(bad(format!(
                            "header line {line_no}: `property TYPE NAME` expected"
                        )));
                    }
                };
                e.properties.push(p);
            }
            _ => {}
        }
    }
    let encoding = encoding.ok_or_else(|| bad("no `format` line".into()))?;
    // The body starts after the line holding `end_header`.
    let mut start = end + 10;
    while start < data.len() && data[start] != b'\n' {
        start += 1;
    }
    let mut body = Body {
        data,
        pos: (start + 1).min(data.len()),
        encoding,
        name,
    };
    let mut out = SurfaceMesh::default();
    // The count of vertices is known before the faces only if the vertex element comes
    // first, as PLY writers put it; indices are checked at the end either way.
    for e in &elements {
        // A count the data cannot hold is refused before anything is reserved.
        if e.count > data.len() {
            return Err(bad(format!(
                "element `{}` declares {} entries, more than the file's {} bytes",
                e.name,
                e.count,
                data.len()
            )));
        }
        for _ in 0..e.count {
            let mut xyz = [f64::NAN; 3];
            let mut face: Option<Vec<f64>> = None;
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
                        if !(0.0..=1e6).contains(&count) {
                            return Err(body.err(format!("a list of {count} entries")));
                        }
                        let mut items = Vec::with_capacity(count as usize);
                        for _ in 0..count as usize {
                            items.push(body.value(*v)?);
                        }
                        if e.name == "face" && (n == "vertex_indices" || n == "vertex_index") {
                            face = Some(items);
                        }
                    }
                }
            }
            if e.name == "vertex" {
                if !xyz.iter().all(|c| c.is_finite()) {
                    return Err(bad(format!(
                        "vertex {}: x, y and z must be present and finite",
                        out.positions.len()
                    )));
                }
                out.positions.push(Vec3::new(xyz[0], xyz[1], xyz[2]));
            }
            if let Some(items) = face {
                if items.len() < 3 {
                    return Err(bad(format!(
                        "face {}: {} vertices (at least 3)",
                        out.triangles.len(),
                        items.len()
                    )));
                }
                let idx: Vec<u32> = items
                    .iter()
                    .map(|&i| {
                        if i >= 0.0 && i < u32::MAX as f64 && i.fract() == 0.0 {
                            Ok(i as u32)
                        } else {
                            Err(bad(format!("face index {i} is not a vertex number")))
                        }
                    })
                    .collect::<Result<_, _>>()?;
                for k in 1..idx.len() - 1 {
                    out.triangles.push([idx[0], idx[k], idx[k + 1]]);
                }
            }
        }
    }
    let n = out.positions.len();
    if let Some((k, t)) = out
        .triangles
        .iter()
        .enumerate()
        .find(|(_, t)| t.iter().any(|&v| v as usize >= n))
    {
        return Err(bad(format!(
            "triangle {k} names vertex {}, but there are {n} vertices",
            t.iter().max().copied().unwrap_or_default()
        )));
    }
    if out.triangles.is_empty() {
        return Err(bad("the PLY file has no faces".into()));
    }
    Ok(out)
}
