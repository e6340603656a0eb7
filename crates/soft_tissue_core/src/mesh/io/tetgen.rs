//! TetGen `.node` / `.ele` files (read and write). Comments start with `#`; point numbers may
//! start at 0 or 1 (elements refer to them by number); 10-node tetrahedra are reduced to their
//! corners.

use super::text::{Cursor, LineFields, Res};
use super::{LoadedMesh, RawMesh};
use crate::Vec3;
use crate::mesh::TetMesh;
use std::collections::HashMap;
use std::fmt::Write as _;

/// Every attribute takes at least two bytes of a line: a declared count the file cannot
/// hold is an error (so the per-line field sums cannot overflow).
fn fits(c: &Cursor<'_>, at: usize, attrs: usize, bytes: usize) -> Res<()> {
    if attrs > bytes {
        return Err(c.err_at(
            at,
            format!("attribute count {attrs} cannot fit in a {bytes} byte file"),
        ));
    }
    Ok(())
}

/// Next non-empty line with any `#` comment removed.
fn content_line<'a>(c: &mut Cursor<'a>) -> Option<(usize, &'a [u8])> {
    loop {
        let (at, line) = c.next_line()?;
        let line = match line.iter().position(|&b| b == b'#') {
            Some(i) => line[..i].trim_ascii(),
            None => line,
        };
        if !line.is_empty() {
            return Some((at, line));
        }
    }
}

fn expect<'a>(
    c: &mut Cursor<'a>,
    what: &str,
    declared: usize,
    found: usize,
) -> Res<(usize, &'a [u8])> {
    let at = c.pos;
    content_line(c).ok_or_else(|| {
        c.err_at(
            at,
            format!("file ends after {found} of the {declared} declared {what}"),
        )
    })
}

pub(crate) fn parse(node: &[u8], node_name: &str, ele: &[u8], ele_name: &str) -> Res<LoadedMesh> {
    let mut c = Cursor::new(node, node_name);
    let (at, line) = expect(&mut c, "header", 1, 0)?;
    let f = LineFields::new(&c, at, line);
    f.need(1, "node header (count dimension attributes markers)")?;
    let n = f.usize(0, "point count")?;
    let dim = if f.len() > 1 {
        f.usize(1, "dimension")?
    } else {
        3
    };
    if dim != 3 {
        return Err(c.err_at(at, format!("dimension must be 3, found {dim}")));
    }
    let attrs = if f.len() > 2 {
        f.usize(2, "attribute count")?
    } else {
        0
    };
    let markers = if f.len() > 3 {
        f.usize(3, "boundary marker flag")?
    } else {
        0
    };
    fits(&c, at, attrs, node.len())?;
    let per_line = 4 + attrs + usize::from(markers != 0);
    let mut raw = RawMesh {
        origin_label: "tetrahedron",
        ..Default::default()
    };
    raw.positions.reserve(n.min(node.len() / 8 + 1));
    let mut index: HashMap<i64, usize> = HashMap::new();
    for i in 0..n {
        let (at, line) = expect(&mut c, "points", n, i)?;
        let f = LineFields::new(&c, at, line);
        if f.len() != per_line {
            return Err(c.err_at(
                at,
                format!(
                    "a point line needs {per_line} fields (number x y z{}{}), found {}",
                    if attrs > 0 { " attributes" } else { "" },
                    if markers != 0 { " marker" } else { "" },
                    f.len()
                ),
            ));
        }
        let num = f.i64(0, "point number")?;
        if index.insert(num, i).is_some() {
            return Err(c.err_at(at, format!("point number {num} appears twice")));
        }
        raw.positions
            .push(Vec3::new(f.f64(1, "x")?, f.f64(2, "y")?, f.f64(3, "z")?));
    }
    if let Some((at, _)) = content_line(&mut c) {
        return Err(c.err_at(at, format!("more point lines than the {n} declared")));
    }

    let mut c = Cursor::new(ele, ele_name);
    let (at, line) = expect(&mut c, "header", 1, 0)?;
    let f = LineFields::new(&c, at, line);
    f.need(1, "element header (count nodes-per-tet attributes)")?;
    let m = f.usize(0, "tetrahedron count")?;
    let per = if f.len() > 1 {
        f.usize(1, "nodes per tetrahedron")?
    } else {
        4
    };
    if per != 4 && per != 10 {
        return Err(c.err_at(
            at,
            format!("nodes per tetrahedron must be 4 or 10, found {per}"),
        ));
    }
    let eattrs = if f.len() > 2 {
        f.usize(2, "attribute count")?
    } else {
        0
    };
    fits(&c, at, eattrs, ele.len())?;
    raw.tets.reserve(m.min(ele.len() / 8 + 1));
    for i in 0..m {
        let (at, line) = expect(&mut c, "tetrahedra", m, i)?;
        let f = LineFields::new(&c, at, line);
        if f.len() != 1 + per + eattrs {
            return Err(c.err_at(
                at,
                format!(
                    "a tetrahedron line needs {} fields, found {}",
                    1 + per + eattrs,
                    f.len()
                ),
            ));
        }
        let num = f.i64(0, "tetrahedron number")?;
        let mut t = [0usize; 4];
        for (k, slot) in t.iter_mut().enumerate() {
            let p = f.i64(1 + k, "node number")?;
            *slot = *index.get(&p).ok_or_else(|| {
                c.err_at(
                    at,
                    format!("tetrahedron {num} refers to point {p}, which is not in {node_name}"),
                )
            })?;
        }
        raw.tets.push(t);
        raw.origin.push(num as u64);
        raw.reduced_order += usize::from(per == 10);
    }
    if let Some((at, _)) = content_line(&mut c) {
        return Err(c.err_at(at, format!("more tetrahedron lines than the {m} declared")));
    }
    raw.finish(ele_name)
}

/// Writes the `.node` and `.ele` contents (1-based numbering, TetGen's default).
pub(crate) fn write(mesh: &TetMesh) -> (Vec<u8>, Vec<u8>) {
    let mut node = String::new();
    let _ = writeln!(
        node,
        "# written by bevy_soft_tissue\n{} 3 0 0",
        mesh.node_count()
    );
    for (i, p) in mesh.positions().iter().enumerate() {
        let _ = writeln!(node, "{} {:?} {:?} {:?}", i + 1, p.x, p.y, p.z);
    }
    let mut ele = String::new();
    let _ = writeln!(
        ele,
        "# written by bevy_soft_tissue\n{} 4 0",
        mesh.tet_count()
    );
    for (i, t) in mesh.tets().iter().enumerate() {
        let _ = writeln!(
            ele,
            "{} {} {} {} {}",
            i + 1,
            t[0] + 1,
            t[1] + 1,
            t[2] + 1,
            t[3] + 1
        );
    }
    (node.into_bytes(), ele.into_bytes())
}
