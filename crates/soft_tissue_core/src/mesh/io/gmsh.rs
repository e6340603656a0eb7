//! Gmsh MSH reader (versions 1, 2.0-2.2 ASCII/binary, 4.1 ASCII/binary) and 2.2 writer.
//!
//! Our own reader rather than `mshio`: mshio 0.4 reads 4.1 only, so versions 1 and 2 need a
//! reader anyway, and it computes `num_nodes - 1` on unsigned values (overflow on an empty
//! section) and drops node tags when they look dense, which misnumbers nodes when blocks are
//! not in tag order. This reader keeps every tag, and reports the line or byte of each error.

use super::elements::{VolumeKind, split};
use super::text::{Cursor, LineFields, Res, show};
use super::{LoadedMesh, RawMesh};
use crate::Vec3;
use crate::mesh::TetMesh;
use std::collections::HashMap;
use std::fmt::Write as _;

#[derive(Debug, Clone, Copy, PartialEq)]
enum Version {
    V1,
    V2,
    V41,
}

#[derive(Debug, Clone, Copy)]
struct Header {
    version: Version,
    binary: bool,
    little_endian: bool,
    size_t: usize,
}

/// Number of nodes of the Gmsh element types we may meet, from Gmsh's element type table.
fn nodes_of_type(ty: u32) -> Option<usize> {
    Some(match ty {
        1 => 2,
        2 => 3,
        3 => 4,
        4 => 4,
        5 => 8,
        6 => 6,
        7 => 5,
        8 => 3,
        9 => 6,
        10 => 9,
        11 => 10,
        12 => 27,
        13 => 18,
        14 => 14,
        15 => 1,
        16 => 8,
        17 => 20,
        18 => 15,
        19 => 13,
        20 => 9,
        21 => 10,
        22 => 12,
        23 => 15,
        24 => 15,
        25 => 21,
        26 => 4,
        27 => 5,
        28 => 6,
        29 => 20,
        30 => 35,
        31 => 56,
        92 => 64,
        93 => 125,
        _ => return None,
    })
}

fn type_name(ty: u32) -> String {
    match ty {
        1 | 8 | 26 | 27 | 28 => "lines".into(),
        2 | 9 | 20..=25 => "triangles".into(),
        3 | 10 | 16 => "quadrangles".into(),
        15 => "points".into(),
        _ => format!("elements of type {ty}"),
    }
}

enum Use {
    Tet { reduced: bool },
    Split(VolumeKind),
    Skip,
}

fn use_of(ty: u32) -> Use {
    match ty {
        4 => Use::Tet { reduced: false },
        11 | 29 | 30 | 31 => Use::Tet { reduced: true },
        5 | 12 | 17 | 92 | 93 => Use::Split(VolumeKind::Hexahedron),
        6 | 13 | 18 => Use::Split(VolumeKind::Wedge),
        7 | 14 | 19 => Use::Split(VolumeKind::Pyramid),
        _ => Use::Skip,
    }
}

#[derive(Default)]
struct Nodes {
    tags: Vec<u64>,
    positions: Vec<Vec3>,
}

#[derive(Default)]
struct Elements {
    tag: Vec<u64>,
    ty: Vec<u32>,
    start: Vec<usize>,
    at: Vec<usize>,
    nodes: Vec<u64>,
}

impl Elements {
    fn push(&mut self, tag: u64, ty: u32, nodes: impl IntoIterator<Item = u64>, at: usize) {
        self.tag.push(tag);
        self.ty.push(ty);
        self.start.push(self.nodes.len());
        self.at.push(at);
        self.nodes.extend(nodes);
    }
}

/// Caps a declared count by what the remaining bytes could hold, so a corrupt count cannot
/// make us reserve absurd memory.
fn capacity(declared: usize, remaining: usize, min_bytes: usize) -> usize {
    declared.min(remaining / min_bytes.max(1) + 1)
}

struct Binary<'a, 'c> {
    c: &'c mut Cursor<'a>,
    h: Header,
}

impl Binary<'_, '_> {
    fn i32(&mut self, what: &str) -> Res<i32> {
        let b = self.c.bytes(4, what)?;
        let a = [b[0], b[1], b[2], b[3]];
        Ok(if self.h.little_endian {
            i32::from_le_bytes(a)
        } else {
            i32::from_be_bytes(a)
        })
    }

    fn u32(&mut self, what: &str) -> Res<u32> {
        let at = self.c.pos;
        let v = self.i32(what)?;
        u32::try_from(v).map_err(|_| self.c.err_byte(at, format!("{what}: negative value {v}")))
    }

    fn size_t(&mut self, what: &str) -> Res<u64> {
        if self.h.size_t == 4 {
            let b = self.c.bytes(4, what)?;
            let a = [b[0], b[1], b[2], b[3]];
            Ok(u64::from(if self.h.little_endian {
                u32::from_le_bytes(a)
            } else {
                u32::from_be_bytes(a)
            }))
        } else {
            let b = self.c.bytes(8, what)?;
            let mut a = [0u8; 8];
            a.copy_from_slice(b);
            Ok(if self.h.little_endian {
                u64::from_le_bytes(a)
            } else {
                u64::from_be_bytes(a)
            })
        }
    }

    fn count(&mut self, what: &str) -> Res<usize> {
        let at = self.c.pos;
        let v = self.size_t(what)?;
        usize::try_from(v).map_err(|_| self.c.err_byte(at, format!("{what}: {v} is too large")))
    }

    fn f64(&mut self, what: &str) -> Res<f64> {
        let b = self.c.bytes(8, what)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(if self.h.little_endian {
            f64::from_le_bytes(a)
        } else {
            f64::from_be_bytes(a)
        })
    }
}

/// Parses a Gmsh file.
pub(crate) fn parse(data: &[u8], name: &str) -> Res<LoadedMesh> {
    let mut c = Cursor::new(data, name);
    let mut header: Option<Header> = None;
    let mut nodes: Option<(Nodes, usize)> = None;
    let mut elements: Option<(Elements, usize)> = None;
    while let Some((start, line)) = c.next_line() {
        match line {
            b"$MeshFormat" => {
                if header.is_some() {
                    return Err(c.err_at(start, "a second $MeshFormat section"));
                }
                header = Some(parse_header(&mut c)?);
            }
            b"$NOD" | b"$Nodes" | b"$ParametricNodes" => {
                let h = match (line, header) {
                    (b"$NOD", None) => Header {
                        version: Version::V1,
                        binary: false,
                        little_endian: true,
                        size_t: 8,
                    },
                    (b"$NOD", Some(_)) => {
                        return Err(c.err_at(start, "$NOD (version 1) after a $MeshFormat header"));
                    }
                    (b"$ParametricNodes", _) => {
                        return Err(c.err_at(
                            start,
                            "$ParametricNodes (MSH 2.1 parametric nodes) is not supported",
                        ));
                    }
                    (_, Some(h)) => h,
                    (_, None) => {
                        return Err(c.err_at(start, "$Nodes before the $MeshFormat header"));
                    }
                };
                header = Some(h);
                if nodes.is_some() {
                    return Err(c.err_at(start, "a second node section"));
                }
                let n = match (h.version, h.binary) {
                    (Version::V41, true) => nodes_v41_binary(&mut c, h)?,
                    (Version::V41, false) => nodes_v41_ascii(&mut c)?,
                    (_, true) => nodes_v2_binary(&mut c, h)?,
                    (_, false) => nodes_v12_ascii(&mut c, h.version)?,
                };
                nodes = Some((n, start));
            }
            b"$ELM" | b"$Elements" => {
                let Some(h) = header else {
                    return Err(c.err_at(start, "elements before any node section"));
                };
                if (line == b"$ELM") != (h.version == Version::V1) {
                    return Err(c.err_at(
                        start,
                        "element section name does not match the file version",
                    ));
                }
                if elements.is_some() {
                    return Err(c.err_at(start, "a second element section"));
                }
                let e = match (h.version, h.binary) {
                    (Version::V41, true) => elements_v41_binary(&mut c, h)?,
                    (Version::V41, false) => elements_v41_ascii(&mut c)?,
                    (_, true) => elements_v2_binary(&mut c, h)?,
                    (_, false) => elements_v12_ascii(&mut c, h.version)?,
                };
                elements = Some((e, start));
            }
            _ if line.starts_with(b"$") && !line.starts_with(b"$End") => {
                // Any other section ($PhysicalNames, $Entities, $NodeData, ...): skip it.
                let section = std::str::from_utf8(&line[1..]).unwrap_or("?");
                let end = format!("$End{section}");
                c.skip_past_tag(&end, start)?;
            }
            _ => {
                return Err(c.err_at(
                    start,
                    format!(
                        "expected a section such as $Nodes or $Elements, found '{}'",
                        show(line)
                    ),
                ));
            }
        }
    }
    if header.is_none() && nodes.is_none() {
        return Err(c.err_at(0, "not a Gmsh file: no $MeshFormat or $NOD section"));
    }
    let Some((nodes, _)) = nodes else {
        return Err(c.err_at(c.data.len(), "the file has no node section"));
    };
    let Some((elements, _)) = elements else {
        return Err(c.err_at(c.data.len(), "the file has no element section"));
    };
    build(&c, nodes, elements)
}

fn parse_header(c: &mut Cursor<'_>) -> Res<Header> {
    let (start, line) = c.expect_line("the MSH version line")?;
    let f = LineFields::new(c, start, line);
    f.need(3, "$MeshFormat")?;
    let version_tok = String::from_utf8_lossy(f.toks[0]).into_owned();
    let version = match version_tok.as_str() {
        "2" | "2.0" | "2.1" | "2.2" => Version::V2,
        "4.1" => Version::V41,
        "4" | "4.0" => {
            return Err(c.err_at(start, "MSH 4.0 is not supported: save as MSH 4.1 or 2.2"));
        }
        v => {
            return Err(c.err_at(
                start,
                format!("unsupported MSH version '{}'", show(v.as_bytes())),
            ));
        }
    };
    let file_type = f.usize(1, "file type")?;
    let size_t = f.usize(2, "data size")?;
    let binary = match file_type {
        0 => false,
        1 => true,
        t => {
            return Err(c.err_at(
                start,
                format!("file type must be 0 (ASCII) or 1 (binary), found {t}"),
            ));
        }
    };
    if binary && size_t != 4 && size_t != 8 {
        return Err(c.err_at(start, format!("data size must be 4 or 8, found {size_t}")));
    }
    let mut little_endian = true;
    if binary {
        let at = c.pos;
        let b = c.bytes(4, "endianness marker")?;
        let a = [b[0], b[1], b[2], b[3]];
        little_endian = if i32::from_le_bytes(a) == 1 {
            true
        } else if i32::from_be_bytes(a) == 1 {
            false
        } else {
            return Err(c.err_byte(at, "binary endianness marker is not the integer 1"));
        };
    }
    let (at, end) = c.expect_line("$EndMeshFormat")?;
    if end != b"$EndMeshFormat" {
        return Err(c.err_at(
            at,
            format!("expected $EndMeshFormat, found '{}'", show(end)),
        ));
    }
    Ok(Header {
        version,
        binary,
        little_endian,
        size_t,
    })
}

fn end_tag(version: Version, nodes: bool) -> &'static str {
    match (version, nodes) {
        (Version::V1, true) => "$ENDNOD",
        (Version::V1, false) => "$ENDELM",
        (_, true) => "$EndNodes",
        (_, false) => "$EndElements",
    }
}

fn expect_end(c: &mut Cursor<'_>, tag: &str, declared: usize, what: &str) -> Res<()> {
    let (at, line) = c.expect_line(tag)?;
    if line != tag.as_bytes() {
        return Err(c.err_at(
            at,
            format!(
                "expected {tag} after the {declared} declared {what}, found '{}'",
                show(line)
            ),
        ));
    }
    Ok(())
}

/// Reads the next data line of a section; a `$` line means the section ended too early.
fn data_line<'a>(
    c: &mut Cursor<'a>,
    declared: usize,
    found: usize,
    what: &str,
) -> Res<(usize, &'a [u8])> {
    let (at, line) = c.expect_line(what)?;
    if line.starts_with(b"$") {
        return Err(c.err_at(
            at,
            format!("the section declares {declared} {what} but ends after {found}"),
        ));
    }
    Ok((at, line))
}

fn count_line(c: &mut Cursor<'_>, what: &str) -> Res<usize> {
    let (at, line) = c.expect_line(what)?;
    let f = LineFields::new(c, at, line);
    f.need(1, what)?;
    f.usize(0, what)
}

fn nodes_v12_ascii(c: &mut Cursor<'_>, version: Version) -> Res<Nodes> {
    let n = count_line(c, "node count")?;
    let mut out = Nodes::default();
    let cap = capacity(n, c.data.len() - c.pos, 8);
    out.tags.reserve(cap);
    out.positions.reserve(cap);
    for i in 0..n {
        let (at, line) = data_line(c, n, i, "nodes")?;
        let f = LineFields::new(c, at, line);
        if f.len() != 4 {
            return Err(c.err_at(
                at,
                format!("a node line needs 4 fields (tag x y z), found {}", f.len()),
            ));
        }
        out.tags.push(f.usize(0, "node tag")? as u64);
        out.positions
            .push(Vec3::new(f.f64(1, "x")?, f.f64(2, "y")?, f.f64(3, "z")?));
    }
    expect_end(c, end_tag(version, true), n, "nodes")?;
    Ok(out)
}

fn nodes_v2_binary(c: &mut Cursor<'_>, h: Header) -> Res<Nodes> {
    let n = count_line(c, "node count")?;
    if h.size_t != 8 {
        return Err(c.err_at(c.pos, "binary MSH 2 needs 8-byte doubles (data size 8)"));
    }
    let mut out = Nodes::default();
    let cap = capacity(n, c.data.len() - c.pos, 28);
    out.tags.reserve(cap);
    out.positions.reserve(cap);
    let mut b = Binary { c, h };
    for _ in 0..n {
        let at = b.c.pos;
        let tag = b.i32("node tag")?;
        let tag =
            u64::try_from(tag).map_err(|_| b.c.err_byte(at, format!("negative node tag {tag}")))?;
        out.tags.push(tag);
        out.positions
            .push(Vec3::new(b.f64("x")?, b.f64("y")?, b.f64("z")?));
    }
    expect_end(c, "$EndNodes", n, "nodes")?;
    Ok(out)
}

fn nodes_v41_ascii(c: &mut Cursor<'_>) -> Res<Nodes> {
    let (at, line) = c.expect_line("node section header")?;
    let f = LineFields::new(c, at, line);
    f.need(
        4,
        "$Nodes header (numEntityBlocks numNodes minNodeTag maxNodeTag)",
    )?;
    let blocks = f.usize(0, "numEntityBlocks")?;
    let total = f.usize(1, "numNodes")?;
    let mut out = Nodes::default();
    let cap = capacity(total, c.data.len() - c.pos, 8);
    out.tags.reserve(cap);
    out.positions.reserve(cap);
    for _ in 0..blocks {
        let (at, line) = data_line(c, blocks, 0, "node blocks")?;
        let f = LineFields::new(c, at, line);
        f.need(
            4,
            "node block header (entityDim entityTag parametric numNodesInBlock)",
        )?;
        let dim = f.usize(0, "entityDim")?;
        let parametric = f.usize(2, "parametric")? != 0;
        let n = f.usize(3, "numNodesInBlock")?;
        let params = if parametric { dim } else { 0 };
        let first = out.tags.len();
        for i in 0..n {
            let (at, line) = data_line(c, n, i, "node tags in the block")?;
            let f = LineFields::new(c, at, line);
            out.tags.push(f.usize(0, "node tag")? as u64);
        }
        for i in 0..n {
            let (at, line) = data_line(c, n, i, "node coordinates in the block")?;
            let f = LineFields::new(c, at, line);
            if f.len() != 3 + params {
                return Err(c.err_at(
                    at,
                    format!("expected {} coordinates, found {}", 3 + params, f.len()),
                ));
            }
            out.positions
                .push(Vec3::new(f.f64(0, "x")?, f.f64(1, "y")?, f.f64(2, "z")?));
        }
        debug_assert_eq!(out.tags.len() - first, n);
    }
    let found = out.tags.len();
    if found != total {
        return Err(c.err_at(at, total_mismatch("nodes", total, found)));
    }
    expect_end(c, "$EndNodes", total, "nodes")?;
    Ok(out)
}

fn nodes_v41_binary(c: &mut Cursor<'_>, h: Header) -> Res<Nodes> {
    let header_at = c.pos;
    let mut b = Binary { c, h };
    let blocks = b.count("numEntityBlocks")?;
    let total = b.count("numNodes")?;
    b.size_t("minNodeTag")?;
    b.size_t("maxNodeTag")?;
    let mut out = Nodes::default();
    let cap = capacity(total, b.c.data.len() - b.c.pos, 8 + 24);
    out.tags.reserve(cap);
    out.positions.reserve(cap);
    for _ in 0..blocks {
        let at = b.c.pos;
        let dim = b.i32("entityDim")?;
        b.i32("entityTag")?;
        let parametric = b.i32("parametric")? != 0;
        let n = b.count("numNodesInBlock")?;
        if !(0..=3).contains(&dim) {
            return Err(b.c.err_byte(at, format!("entityDim {dim} is not 0-3")));
        }
        let params = if parametric { dim as usize } else { 0 };
        for _ in 0..n {
            out.tags.push(b.size_t("node tag")?);
        }
        for _ in 0..n {
            let p = Vec3::new(b.f64("x")?, b.f64("y")?, b.f64("z")?);
            for _ in 0..params {
                b.f64("parametric coordinate")?;
            }
            out.positions.push(p);
        }
    }
    let found = out.tags.len();
    if found != total {
        return Err(c.err_byte(header_at, total_mismatch("nodes", total, found)));
    }
    expect_end(c, "$EndNodes", total, "nodes")?;
    Ok(out)
}

/// Message for MSH 4.1 blocks that do not add up to the header's total.
fn total_mismatch(what: &str, total: usize, found: usize) -> String {
    format!("the header declares {total} {what}, the blocks hold {found}")
}

fn check_arity(c: &Cursor<'_>, at: usize, tag: u64, ty: u32, found: usize) -> Res<()> {
    if let Some(expected) = nodes_of_type(ty)
        && expected != found
    {
        return Err(c.err_at(
            at,
            format!("element {tag} of type {ty} needs {expected} nodes, the line lists {found}"),
        ));
    }
    Ok(())
}

fn elements_v12_ascii(c: &mut Cursor<'_>, version: Version) -> Res<Elements> {
    let n = count_line(c, "element count")?;
    let mut out = Elements::default();
    for i in 0..n {
        let (at, line) = data_line(c, n, i, "elements")?;
        let f = LineFields::new(c, at, line);
        let (tag, ty, first) = if version == Version::V1 {
            // number type reg-phys reg-elem number-of-nodes nodes...
            f.need(
                5,
                "element line (number type reg-phys reg-elem number-of-nodes nodes...)",
            )?;
            let nn = f.usize(4, "number-of-nodes")?;
            // (`need` above: at least 5 fields; compared without adding to a declared count.)
            if f.len() - 5 != nn {
                return Err(c.err_at(
                    at,
                    format!(
                        "element declares {nn} nodes but the line lists {}",
                        f.len() - 5
                    ),
                ));
            }
            (
                f.usize(0, "element number")?,
                f.usize(1, "element type")?,
                5,
            )
        } else {
            // number type number-of-tags tags... nodes...
            f.need(
                3,
                "element line (number type number-of-tags tags... nodes...)",
            )?;
            let nt = f.usize(2, "number-of-tags")?;
            if f.len() - 3 < nt {
                return Err(c.err_at(
                    at,
                    format!("element declares {nt} tags but the line is shorter"),
                ));
            }
            (
                f.usize(0, "element number")?,
                f.usize(1, "element type")?,
                3 + nt,
            )
        };
        let ty = u32::try_from(ty)
            .map_err(|_| c.err_at(at, format!("element type {ty} is out of range")))?;
        check_arity(c, at, tag as u64, ty, f.len() - first)?;
        let mut ids = Vec::with_capacity(f.len() - first);
        for k in first..f.len() {
            ids.push(f.usize(k, "node tag")? as u64);
        }
        out.push(tag as u64, ty, ids, at);
    }
    expect_end(c, end_tag(version, false), n, "elements")?;
    Ok(out)
}

fn elements_v2_binary(c: &mut Cursor<'_>, h: Header) -> Res<Elements> {
    let n = count_line(c, "element count")?;
    let mut out = Elements::default();
    let mut b = Binary { c, h };
    while out.tag.len() < n {
        let at = b.c.pos;
        let ty = b.u32("element type")?;
        let follow = b.u32("number of elements in the block")? as usize;
        let ntags = b.u32("number of tags")? as usize;
        let Some(nn) = nodes_of_type(ty) else {
            return Err(b.c.err_byte(
                at,
                format!("unknown element type {ty}: cannot skip it in binary data"),
            ));
        };
        if follow == 0 || follow > n - out.tag.len() {
            return Err(b.c.err_byte(at, format!(
                "element block of {follow} elements does not fit the declared total {n} ({} read)",
                out.tag.len()
            )));
        }
        for _ in 0..follow {
            let at = b.c.pos;
            let tag = b.u32("element number")?;
            for _ in 0..ntags {
                b.i32("element tag")?;
            }
            let mut ids = [0u64; 125];
            for id in ids.iter_mut().take(nn) {
                *id = u64::from(b.u32("node tag")?);
            }
            out.push(u64::from(tag), ty, ids[..nn].iter().copied(), at);
        }
    }
    expect_end(c, "$EndElements", n, "elements")?;
    Ok(out)
}

fn elements_v41_ascii(c: &mut Cursor<'_>) -> Res<Elements> {
    let (at, line) = c.expect_line("element section header")?;
    let f = LineFields::new(c, at, line);
    f.need(
        4,
        "$Elements header (numEntityBlocks numElements minElementTag maxElementTag)",
    )?;
    let blocks = f.usize(0, "numEntityBlocks")?;
    let total = f.usize(1, "numElements")?;
    let mut out = Elements::default();
    for _ in 0..blocks {
        let (bat, line) = data_line(c, blocks, 0, "element blocks")?;
        let f = LineFields::new(c, bat, line);
        f.need(
            4,
            "element block header (entityDim entityTag elementType numElementsInBlock)",
        )?;
        let ty = f.usize(2, "elementType")?;
        let ty = u32::try_from(ty)
            .map_err(|_| c.err_at(bat, format!("element type {ty} is out of range")))?;
        let n = f.usize(3, "numElementsInBlock")?;
        for i in 0..n {
            let (at, line) = data_line(c, n, i, "elements in the block")?;
            let f = LineFields::new(c, at, line);
            f.need(2, "element line (tag nodes...)")?;
            let tag = f.usize(0, "element tag")? as u64;
            check_arity(c, at, tag, ty, f.len() - 1)?;
            let mut ids = Vec::with_capacity(f.len() - 1);
            for k in 1..f.len() {
                ids.push(f.usize(k, "node tag")? as u64);
            }
            out.push(tag, ty, ids, at);
        }
    }
    let found = out.tag.len();
    if found != total {
        return Err(c.err_at(at, total_mismatch("elements", total, found)));
    }
    expect_end(c, "$EndElements", total, "elements")?;
    Ok(out)
}

fn elements_v41_binary(c: &mut Cursor<'_>, h: Header) -> Res<Elements> {
    let header_at = c.pos;
    let mut b = Binary { c, h };
    let blocks = b.count("numEntityBlocks")?;
    let total = b.count("numElements")?;
    b.size_t("minElementTag")?;
    b.size_t("maxElementTag")?;
    let mut out = Elements::default();
    for _ in 0..blocks {
        let at = b.c.pos;
        b.i32("entityDim")?;
        b.i32("entityTag")?;
        let ty = b.u32("elementType")?;
        let n = b.count("numElementsInBlock")?;
        let Some(nn) = nodes_of_type(ty) else {
            return Err(b.c.err_byte(
                at,
                format!("unknown element type {ty}: cannot skip it in binary data"),
            ));
        };
        for _ in 0..n {
            let at = b.c.pos;
            let tag = b.size_t("element tag")?;
            let mut ids = [0u64; 125];
            for id in ids.iter_mut().take(nn) {
                *id = b.size_t("node tag")?;
            }
            out.push(tag, ty, ids[..nn].iter().copied(), at);
        }
    }
    let found = out.tag.len();
    if found != total {
        return Err(c.err_byte(header_at, total_mismatch("elements", total, found)));
    }
    expect_end(c, "$EndElements", total, "elements")?;
    Ok(out)
}

fn build(c: &Cursor<'_>, nodes: Nodes, e: Elements) -> Res<LoadedMesh> {
    let mut index: HashMap<u64, usize> = HashMap::with_capacity(nodes.tags.len());
    for (i, &t) in nodes.tags.iter().enumerate() {
        if index.insert(t, i).is_some() {
            return Err(super::FormatError::unsupported(
                c.name,
                format!("node tag {t} is used by more than one node"),
            ));
        }
    }
    let mut raw = RawMesh {
        positions: nodes.positions,
        origin_label: "element",
        ..Default::default()
    };
    for k in 0..e.tag.len() {
        let ty = e.ty[k];
        let end = e.start.get(k + 1).copied().unwrap_or(e.nodes.len());
        let list = &e.nodes[e.start[k]..end];
        let lookup = |want: usize| -> Res<Vec<usize>> {
            if list.len() < want {
                return Err(c.err_at(
                    e.at[k],
                    format!(
                        "element {} lists {} nodes, needs at least {want}",
                        e.tag[k],
                        list.len()
                    ),
                ));
            }
            list[..want]
                .iter()
                .map(|t| {
                    index.get(t).copied().ok_or_else(|| {
                        c.err_at(e.at[k], format!("element {} refers to node tag {t}, which is not in the node section", e.tag[k]))
                    })
                })
                .collect()
        };
        match use_of(ty) {
            Use::Tet { reduced } => {
                let v = lookup(4)?;
                raw.tets.push([v[0], v[1], v[2], v[3]]);
                raw.origin.push(e.tag[k]);
                if reduced {
                    raw.reduced_order += 1;
                }
            }
            Use::Split(kind) => {
                let v = lookup(kind.corners())?;
                split(&mut raw, kind, &v, e.tag[k]);
            }
            Use::Skip => raw.skip(type_name(ty)),
        }
    }
    raw.finish(c.name)
}

/// Writes MSH 2.2 (ASCII or binary). Node and element numbers start at 1; all tets get
/// physical and elementary tag 1.
pub(crate) fn write_v22(mesh: &TetMesh, binary: bool) -> Vec<u8> {
    let mut out: Vec<u8> = Vec::new();
    let n = mesh.node_count();
    let t = mesh.tet_count();
    if binary {
        out.extend_from_slice(b"$MeshFormat\n2.2 1 8\n");
        out.extend_from_slice(&1i32.to_le_bytes());
        out.extend_from_slice(format!("\n$EndMeshFormat\n$Nodes\n{n}\n").as_bytes());
        for (i, p) in mesh.positions().iter().enumerate() {
            out.extend_from_slice(&(i as i32 + 1).to_le_bytes());
            for v in p.iter() {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out.extend_from_slice(format!("\n$EndNodes\n$Elements\n{t}\n").as_bytes());
        for v in [4i32, t as i32, 2] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for (i, tet) in mesh.tets().iter().enumerate() {
            for v in [i as i32 + 1, 1, 1] {
                out.extend_from_slice(&v.to_le_bytes());
            }
            for &v in tet {
                out.extend_from_slice(&(v as i32 + 1).to_le_bytes());
            }
        }
        out.extend_from_slice(b"\n$EndElements\n");
    } else {
        let mut s = String::new();
        let _ = write!(s, "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n{n}\n");
        for (i, p) in mesh.positions().iter().enumerate() {
            let _ = writeln!(s, "{} {:?} {:?} {:?}", i + 1, p.x, p.y, p.z);
        }
        let _ = write!(s, "$EndNodes\n$Elements\n{t}\n");
        for (i, tet) in mesh.tets().iter().enumerate() {
            let _ = writeln!(
                s,
                "{} 4 2 1 1 {} {} {} {}",
                i + 1,
                tet[0] + 1,
                tet[1] + 1,
                tet[2] + 1,
                tet[3] + 1
            );
        }
        s.push_str("$EndElements\n");
        out = s.into_bytes();
    }
    out
}
