//! STL and PLY files as real exporters write them, beyond the tidy ones: binary STL headers
//! whose triangle count is wrong (0 from streaming exporters, too many, too few, trailing
//! padding, or a truncated file), ASCII STL in upper case, with a byte-order mark or with
//! several solids, PLY headers with a comment naming `end_header` or with CR line ends, and
//! PLY faces naming a vertex that does not exist, PLY after a byte-order mark, and PLY
//! faces given as triangle strips. Every input is built here as bytes: a tetrahedron, read
//! back triangle by triangle and vertex by vertex.

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::io::{
    SurfaceMesh, parse_ply, parse_stl, parse_stl_with_notes, read_surface_with_notes,
};

/// The tetrahedron's corners (exact in `f32`, so binary files read back exactly).
fn corners() -> [Vec3; 4] {
    [
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(2.5, 0.0, 0.0),
        Vec3::new(0.0, 1.5, 0.0),
        Vec3::new(0.25, -0.5, 3.0),
    ]
}

/// Its faces, turning outwards.
const FACES: [[usize; 3]; 4] = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];

fn tetrahedron() -> Vec<[Vec3; 3]> {
    let c = corners();
    FACES.iter().map(|f| f.map(|v| c[v])).collect()
}

/// The surface's triangles as corner positions.
fn triangles_of(s: &SurfaceMesh) -> Vec<[Vec3; 3]> {
    s.triangles
        .iter()
        .map(|t| t.map(|v| s.positions[v as usize]))
        .collect()
}

/// A binary STL: `header` padded with spaces to 80 bytes, the stated `count`, the
/// triangles (zero normals), then `trailing` bytes.
fn binary_stl(header: &str, count: u32, triangles: &[[Vec3; 3]], trailing: &[u8]) -> Vec<u8> {
    let mut out = header.as_bytes().to_vec();
    out.resize(80, b' ');
    out.extend(count.to_le_bytes());
    for t in triangles {
        out.extend([0u8; 12]);
        for x in t.iter().flat_map(|p| p.iter()) {
            out.extend((*x as f32).to_le_bytes());
        }
        out.extend([0u8; 2]);
    }
    out.extend(trailing);
    out
}

/// An ASCII STL solid holding the triangles (lower case, LF line ends).
fn ascii_solid(name: &str, triangles: &[[Vec3; 3]]) -> String {
    let mut s = format!("solid {name}\n");
    for t in triangles {
        s += "  facet normal 0 0 0\n    outer loop\n";
        for p in t {
            s += &format!("      vertex {} {} {}\n", p.x, p.y, p.z);
        }
        s += "    endloop\n  endfacet\n";
    }
    s + &format!("endsolid {name}\n")
}

fn stl_error(data: &[u8]) -> String {
    match parse_stl(data, "t.stl") {
        Ok(s) => panic!("read {} triangles, expected an error", s.triangles.len()),
        Err(e) => e.to_string(),
    }
}

/// A binary STL whose header says 0 triangles, as streaming exporters write it, is read
/// with every triangle its bytes hold, with a `solid` header or without.
#[test]
fn binary_stl_with_a_zero_count_reads_every_triangle() {
    for header in ["streamed", "solid streamed"] {
        let data = binary_stl(header, 0, &tetrahedron(), &[]);
        let s = parse_stl(&data, "t.stl").unwrap();
        assert_eq!(triangles_of(&s), tetrahedron(), "{header}");
    }
}

/// A header promising more triangles than a whole number of records holds, or fewer, is
/// overruled by the data: every triangle is read, whatever the header starts with.
#[test]
fn binary_stl_with_a_wrong_count_reads_what_the_data_holds() {
    for header in [
        "exported",
        "solid exported",
        "solid sphere\nfacet normal 0 0 0\n",
    ] {
        for count in [1, 3, 5, 1000] {
            let data = binary_stl(header, count, &tetrahedron(), &[]);
            let s = parse_stl(&data, "t.stl")
                .unwrap_or_else(|e| panic!("{header:?}, count {count}: {e}"));
            assert_eq!(triangles_of(&s), tetrahedron(), "{header:?}, count {count}");
        }
    }
}

/// Fewer than 50 bytes after the stated triangles are padding: the header's count is read.
#[test]
fn binary_stl_with_trailing_padding_reads_the_header_count() {
    for header in ["padded", "solid padded"] {
        for pad in [1, 2, 7, 49] {
            let data = binary_stl(header, 4, &tetrahedron(), &vec![0u8; pad]);
            let s = parse_stl(&data, "t.stl").unwrap();
            assert_eq!(triangles_of(&s), tetrahedron(), "{header}, {pad} bytes");
        }
    }
}

/// A file cut inside a triangle, with a header promising more, is a truncated file: the
/// error names the header's count and the whole triangles the bytes hold.
#[test]
fn truncated_binary_stl_names_the_stated_and_the_real_count() {
    for header in ["cut", "solid cut"] {
        let mut data = binary_stl(header, 4, &tetrahedron(), &[]);
        data.truncate(84 + 2 * 50 + 17);
        let e = stl_error(&data);
        assert!(e.contains("t.stl"), "{e}");
        assert!(e.contains("says 4 triangles"), "{e}");
        assert!(e.contains("hold 2 whole triangles"), "{e}");
    }
    // A header alone, promising triangles it does not have.
    let e = stl_error(&binary_stl("empty", 1280, &[], &[]));
    assert!(e.contains("1280") && e.contains("hold 0"), "{e}");
}

/// A non-finite vertex in a file whose header count is wrong names both counts.
#[test]
fn binary_stl_errors_name_both_counts_where_they_disagree() {
    let mut t = tetrahedron();
    t[2][1].y = f64::NAN;
    let e = stl_error(&binary_stl("nan", 0, &t, &[]));
    assert!(e.contains("triangle 2: vertex 1 is not finite"), "{e}");
    assert!(e.contains("header says 0") && e.contains("holds 4"), "{e}");
}

/// Where the data overrules the header's count (0, too large, too small) or bytes follow the
/// last whole triangle, the reader says so in a note naming both counts; a header that
/// agrees with its data, and an ASCII file, give none. `read_surface_with_notes` passes the
/// note on.
#[test]
fn binary_stl_whose_header_count_is_overruled_says_so_in_a_note() {
    // The tetrahedron's 4 triangles, with each stated count and trailing bytes.
    let held = |stated: u32| {
        format!("binary STL header says {stated} triangles; the data holds 4 (read those)")
    };
    for (count, trailing, want) in [
        (0, 0, held(0)),
        (1000, 0, held(1000)),
        (5, 0, held(5)),
        (3, 0, held(3)),
        (1, 0, held(1)),
        (
            3,
            7,
            held(3) + ", and 7 bytes after them, less than a triangle (ignored)",
        ),
        (
            4,
            7,
            "binary STL: 7 bytes after the header's 4 triangles, less than a triangle \
             (ignored)"
                .to_string(),
        ),
    ] {
        for header in ["x", "solid x"] {
            let data = binary_stl(header, count, &tetrahedron(), &vec![0u8; trailing]);
            let read = parse_stl_with_notes(&data, "t.stl")
                .unwrap_or_else(|e| panic!("count {count}, {trailing} bytes: {e}"));
            assert_eq!(triangles_of(&read.surface), tetrahedron());
            assert_eq!(read.notes, vec![want.clone()], "{header:?}");
            // The plain reader gives the same surface.
            assert_eq!(parse_stl(&data, "t.stl").unwrap(), read.surface);
        }
    }
    for data in [
        binary_stl("agrees", 4, &tetrahedron(), &[]),
        ascii_solid("a", &tetrahedron()).into_bytes(),
    ] {
        let read = parse_stl_with_notes(&data, "t.stl").unwrap();
        assert_eq!(triangles_of(&read.surface), tetrahedron());
        assert!(read.notes.is_empty(), "{:?}", read.notes);
    }
    let dir = std::env::temp_dir().join(format!("st-stl-notes-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("zero.stl");
    std::fs::write(&path, binary_stl("x", 0, &tetrahedron(), &[])).unwrap();
    let read = read_surface_with_notes(&path);
    std::fs::remove_dir_all(&dir).unwrap();
    let read = read.unwrap();
    assert_eq!(triangles_of(&read.surface), tetrahedron());
    assert_eq!(read.notes, vec![held(0)]);
}

/// No binary length or stated count makes the reader panic.
#[test]
fn binary_stl_of_any_length_and_count_never_panics() {
    for count in [0, 1, 3, 4, 5, 50, u32::MAX] {
        for header in ["x", "solid x"] {
            let data = binary_stl(header, count, &tetrahedron(), &[0u8; 60]);
            for len in 0..=data.len() {
                let _ = parse_stl(&data[..len], "t.stl");
            }
        }
    }
}

/// ASCII STL keywords are read in any case: upper case, as some CAD exporters write, and
/// mixed.
#[test]
fn ascii_stl_keywords_are_read_in_any_case() {
    let text = ascii_solid("part", &tetrahedron());
    let mixed = text
        .replace("solid", "Solid")
        .replace("facet normal", "Facet Normal")
        .replace("vertex", "Vertex")
        .replace("endfacet", "EndFacet");
    for t in [text.to_uppercase(), mixed] {
        let s = parse_stl(t.as_bytes(), "t.stl").unwrap_or_else(|e| panic!("{e}\n{t}"));
        assert_eq!(triangles_of(&s), tetrahedron());
    }
}

/// A UTF-8 byte-order mark before `solid` is skipped, with LF or CRLF line ends.
#[test]
fn ascii_stl_after_a_byte_order_mark_is_read() {
    let text = ascii_solid("bom", &tetrahedron());
    for t in [
        text.clone(),
        text.replace('\n', "\r\n"),
        text.to_uppercase(),
    ] {
        let mut data = b"\xEF\xBB\xBF".to_vec();
        data.extend(t.as_bytes());
        let s = parse_stl(&data, "t.stl").unwrap();
        assert_eq!(triangles_of(&s), tetrahedron());
    }
}

/// Every `solid` ... `endsolid` block of one ASCII file is read, in order.
#[test]
fn ascii_stl_with_several_solids_reads_them_all() {
    let t = tetrahedron();
    let text = ascii_solid("a", &t[..1]) + &ascii_solid("b", &t[1..3]) + &ascii_solid("", &t[3..]);
    let s = parse_stl(text.as_bytes(), "t.stl").unwrap();
    assert_eq!(triangles_of(&s), t);
}

/// A file starting with `solid` that is shorter than a binary header (84 bytes) is ASCII,
/// with a byte-order mark or without, and its error is about facets.
#[test]
fn short_ascii_stl_is_read_as_ascii() {
    let e = stl_error(b"solid x\nendsolid x\n");
    assert!(e.contains("no facets"), "{e}");
    let e = stl_error(b"\xEF\xBB\xBFSOLID\n");
    assert!(e.contains("no facets"), "{e}");
}

/// A PLY header (from `ply` to `end_header`) with the given line end, the tetrahedron's
/// four vertices and four faces, and the extra header lines after `format`.
fn ply_header(format: &str, extra: &[&str], eol: &str) -> String {
    let mut lines = vec!["ply".to_string(), format!("format {format} 1.0")];
    lines.extend(extra.iter().map(|l| l.to_string()));
    lines.extend(
        [
            "element vertex 4",
            "property float x",
            "property float y",
            "property float z",
            "element face 4",
            "property list uchar int vertex_indices",
            "end_header",
        ]
        .map(String::from),
    );
    lines.join(eol) + eol
}

/// An ASCII PLY of the tetrahedron, with the faces' indices as given.
fn ascii_ply(extra: &[&str], eol: &str, faces: &[[i64; 3]]) -> Vec<u8> {
    let mut s = ply_header("ascii", extra, eol);
    for p in corners() {
        s += &format!("{} {} {}\n", p.x, p.y, p.z);
    }
    for f in faces {
        s += &format!("3 {} {} {}\n", f[0], f[1], f[2]);
    }
    s.into_bytes()
}

/// A binary little-endian PLY of the tetrahedron with the given corners.
fn binary_ply(extra: &[&str], eol: &str, corners: &[Vec3; 4]) -> Vec<u8> {
    let mut out = ply_header("binary_little_endian", extra, eol).into_bytes();
    for x in corners.iter().flat_map(|p| p.iter()) {
        out.extend((*x as f32).to_le_bytes());
    }
    for f in FACES {
        out.push(3);
        for v in f {
            out.extend((v as i32).to_le_bytes());
        }
    }
    out
}

fn tetra_faces() -> Vec<[i64; 3]> {
    FACES.iter().map(|f| f.map(|v| v as i64)).collect()
}

/// The surface has the tetrahedron's corners and faces, in the file's order.
fn assert_tetrahedron(s: &SurfaceMesh, corners: &[Vec3; 4]) {
    assert_eq!(s.positions, corners.to_vec());
    let faces: Vec<[u32; 3]> = FACES.iter().map(|f| f.map(|v| v as u32)).collect();
    assert_eq!(s.triangles, faces);
}

/// A comment or `obj_info` line that names `end_header` does not end the header: only a
/// line that is exactly `end_header` does.
#[test]
fn ply_comment_naming_end_header_does_not_end_the_header() {
    let extra = [
        "comment the header ends at end_header below",
        "obj_info end_header",
        "comment end_header",
    ];
    let s = parse_ply(&ascii_ply(&extra, "\n", &tetra_faces()), "t.ply").unwrap();
    assert_tetrahedron(&s, &corners());
    let s = parse_ply(&binary_ply(&extra, "\n", &corners()), "t.ply").unwrap();
    assert_tetrahedron(&s, &corners());
}

/// Header lines ending in CRLF or in a lone CR are read, ASCII and binary; after a
/// CR-only header the binary body starts right after the CR, even where its first byte is
/// a newline.
#[test]
fn ply_headers_with_crlf_or_cr_line_ends_are_read() {
    let comment = ["comment made on a Mac"];
    for eol in ["\r\n", "\r"] {
        let s = parse_ply(&ascii_ply(&comment, eol, &tetra_faces()), "t.ply")
            .unwrap_or_else(|e| panic!("{eol:?}: {e}"));
        assert_tetrahedron(&s, &corners());
        // The first corner's x is 1 + 10 ulps: its first little-endian byte is `\n`.
        let mut c = corners();
        c[0].x = f32::from_bits(0x3F80_000A) as f64;
        let data = binary_ply(&comment, eol, &c);
        let s = parse_ply(&data, "t.ply").unwrap_or_else(|e| panic!("{eol:?}: {e}"));
        assert_tetrahedron(&s, &c);
    }
}

/// A negative or out-of-range face index names the face (0-based in the face element),
/// the index and the vertex count, whether faces come after the vertices or not.
#[test]
fn ply_bad_face_index_names_the_face_the_index_and_the_vertex_count() {
    for (face, index) in [(2, -1), (3, 4), (0, 70000)] {
        let mut faces = tetra_faces();
        faces[face][1] = index;
        let e = parse_ply(&ascii_ply(&[], "\n", &faces), "t.ply")
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.ply"), "{e}");
        assert!(
            e.contains(&format!("face {face}: vertex index {index} ")),
            "{e}"
        );
        assert!(e.contains("4 vertices"), "{e}");
    }
    // Faces before the vertices: the vertex count is the header's.
    let text = "ply\nformat ascii 1.0\nelement face 2\nproperty list uchar int vertex_index\n\
                element vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                end_header\n3 0 1 2\n3 2 1 -3\n0 0 0\n1 0 0\n0 1 0\n";
    let e = parse_ply(text.as_bytes(), "t.ply").unwrap_err().to_string();
    assert!(e.contains("face 1: vertex index -3 "), "{e}");
    assert!(e.contains("3 vertices"), "{e}");
}

/// A UTF-8 byte-order mark before `ply` is skipped, ASCII and binary, with LF or CRLF
/// header lines.
#[test]
fn ply_after_a_byte_order_mark_is_read() {
    for eol in ["\n", "\r\n"] {
        for data in [
            ascii_ply(&[], eol, &tetra_faces()),
            binary_ply(&[], eol, &corners()),
        ] {
            let mut bom = b"\xEF\xBB\xBF".to_vec();
            bom.extend(&data);
            let s = parse_ply(&bom, "t.ply").unwrap_or_else(|e| panic!("{eol:?}: {e}"));
            assert_tetrahedron(&s, &corners());
        }
    }
}

/// The volume the triangles enclose, by the divergence theorem: positive where they turn
/// outward.
fn enclosed_volume(s: &SurfaceMesh) -> f64 {
    triangles_of(s)
        .iter()
        .map(|[a, b, c]| a.dot(&b.cross(c)) / 6.0)
        .sum()
}

/// The tetrahedron's volume from its corners (outward faces): a sixth of the triple product.
fn tetrahedron_volume() -> f64 {
    let c = corners();
    (c[1] - c[0])
        .dot(&(c[2] - c[0]).cross(&(c[3] - c[0])))
        .abs()
        / 6.0
}

/// Each triangle as its smallest corner first (the same triangle, the same winding).
fn rotated(t: [u32; 3]) -> [u32; 3] {
    let k = (0..3).min_by_key(|&k| t[k]).unwrap_or(0);
    [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
}

/// The tetrahedron's faces, each with its smallest corner first, sorted.
fn sorted_faces(triangles: &[[u32; 3]]) -> Vec<[u32; 3]> {
    let mut f: Vec<[u32; 3]> = triangles.iter().map(|&t| rotated(t)).collect();
    f.sort();
    f
}

/// A PLY with the tetrahedron's corners, `faces` in a `face` element (none: no element) and
/// `strips` as the rows of a `tristrips` element (a list property `vertex_indices`), ASCII or
/// binary little-endian.
fn strips_ply(binary: bool, faces: &[[i64; 3]], strips: &[Vec<i64>]) -> Vec<u8> {
    let format = if binary {
        "binary_little_endian"
    } else {
        "ascii"
    };
    let mut h = format!(
        "ply\nformat {format} 1.0\ncomment Cyberware/Stanford style\nelement vertex 4\n\
         property float x\nproperty float y\nproperty float z\n"
    );
    if !faces.is_empty() {
        h += &format!(
            "element face {}\nproperty list uchar int vertex_indices\n",
            faces.len()
        );
    }
    h += &format!(
        "element tristrips {}\nproperty list int int vertex_indices\nend_header\n",
        strips.len()
    );
    let mut out = h.into_bytes();
    let mut text = String::new();
    for p in corners() {
        if binary {
            for x in p.iter() {
                out.extend((*x as f32).to_le_bytes());
            }
        } else {
            text += &format!("{} {} {}\n", p.x, p.y, p.z);
        }
    }
    for f in faces {
        if binary {
            out.push(3);
            for v in f {
                out.extend((*v as i32).to_le_bytes());
            }
        } else {
            text += &format!("3 {} {} {}\n", f[0], f[1], f[2]);
        }
    }
    for strip in strips {
        if binary {
            out.extend((strip.len() as i32).to_le_bytes());
            for v in strip {
                out.extend((*v as i32).to_le_bytes());
            }
        } else {
            let items: Vec<String> = strip.iter().map(|v| v.to_string()).collect();
            text += &format!("{} {}\n", strip.len(), items.join(" "));
        }
    }
    out.extend(text.into_bytes());
    out
}

/// Faces given only as triangle strips (old Stanford and Cyberware scans) are read: each
/// strip's triangles alternate so that all keep the strip's winding, -1 starts a new strip,
/// and the degenerate triangles that join strips are skipped. Each file below is the
/// tetrahedron, its four faces turned outward: the reader gives those four triangles and
/// the tetrahedron's volume.
#[test]
fn ply_triangle_strips_are_read() {
    // Strip (0 2 1 3 0 2) gives (0 2 1), (1 2 3), (1 3 0), (0 3 2): the four faces.
    let one = vec![0, 2, 1, 3, 0, 2];
    // Two strips after a restart: (0 2 1), (1 2 3), then (1 3 0), (0 3 2).
    let restarted = vec![0, 2, 1, 3, -1, 1, 3, 0, 2];
    // The same two joined by repeating 3 and 1: four degenerate triangles between them.
    let joined = vec![0, 2, 1, 3, 3, 1, 1, 3, 0, 2];
    // Strips over two rows, with -1 at the end of one and at the start of the other.
    let rows = [vec![0, 2, 1, 3, -1], vec![-1, 1, 3, 0, 2]];
    let want = sorted_faces(&FACES.map(|f| f.map(|v| v as u32)));
    for binary in [false, true] {
        for (what, strips) in [
            ("one strip", vec![one.clone()]),
            ("a restart", vec![restarted.clone()]),
            ("degenerate joins", vec![joined.clone()]),
            ("two rows", rows.to_vec()),
        ] {
            let s = parse_ply(&strips_ply(binary, &[], &strips), "t.ply")
                .unwrap_or_else(|e| panic!("{what}, binary {binary}: {e}"));
            assert_eq!(s.positions, corners().to_vec(), "{what}");
            assert_eq!(s.triangles.len(), 4, "{what}: {:?}", s.triangles);
            assert_eq!(sorted_faces(&s.triangles), want, "{what}");
            let v = enclosed_volume(&s);
            assert!((v - tetrahedron_volume()).abs() < 1e-12, "{what}: {v}");
            // Cut anywhere, after a byte order mark or not: an error or a surface, no panic.
            let mut bom = b"\xEF\xBB\xBF".to_vec();
            bom.extend(strips_ply(binary, &[], &strips));
            for len in 0..=bom.len() {
                let _ = parse_ply(&bom[..len], "t.ply");
                let _ = parse_ply(&bom[3.min(len)..len], "t.ply");
            }
        }
        // A file with both: two faces in `face`, the other two in a strip; both are read.
        let faces = [[0, 2, 1], [0, 1, 3]];
        let s = parse_ply(&strips_ply(binary, &faces, &[vec![0, 3, 2, 1]]), "t.ply")
            .unwrap_or_else(|e| panic!("face and tristrips, binary {binary}: {e}"));
        assert_eq!(
            s.triangles,
            vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [2, 3, 1]]
        );
        assert!((enclosed_volume(&s) - tetrahedron_volume()).abs() < 1e-12);
    }
    // An unsigned index list writes the restart as -1's 32-bit pattern.
    let mut text = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\n\
                    property float y\nproperty float z\nelement tristrips 1\n\
                    property list int uint vertex_indices\nend_header\n"
        .to_owned();
    for p in corners() {
        text += &format!("{} {} {}\n", p.x, p.y, p.z);
    }
    text += "9 0 2 1 3 4294967295 1 3 0 2\n";
    let s = parse_ply(text.as_bytes(), "t.ply").unwrap();
    assert_eq!(
        sorted_faces(&s.triangles),
        sorted_faces(&FACES.map(|f| f.map(|v| v as u32)))
    );
}

/// A strip index that is not a vertex (and not the -1 that restarts a strip) names the
/// `tristrips` row, the index and the vertex count.
#[test]
fn ply_bad_strip_index_names_the_row_the_index_and_the_vertex_count() {
    for binary in [false, true] {
        for (strips, row, index) in [
            (vec![vec![0, 2, 1, 4]], 0, 4),
            (vec![vec![0, 2, 1, 3], vec![1, 3, -2, 0]], 1, -2),
            (vec![vec![0, 1], vec![2, 3], vec![70000, 0, 1]], 2, 70000),
        ] {
            let e = parse_ply(&strips_ply(binary, &[], &strips), "t.ply")
                .unwrap_err()
                .to_string();
            assert!(e.contains("t.ply"), "{e}");
            assert!(
                e.contains(&format!("tristrips {row}: vertex index {index} ")),
                "{e}"
            );
            assert!(e.contains("4 vertices"), "{e}");
        }
    }
}

/// A glTF of one triangle, (0,0,0) (1,0,0) (0,1,0) in a data URI, under the given nodes and
/// scene roots.
fn gltf_with_nodes(nodes: &str, roots: &str) -> Vec<u8> {
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":{roots}}}],
        "nodes":{nodes},"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",
        "min":[0,0,0],"max":[1,1,0]}}],"bufferViews":[{{"buffer":0,"byteLength":36}}],
        "buffers":[{{"byteLength":36,
        "uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA"}}]}}"#
    )
    .into_bytes()
}

/// The variants the tests above (and `tetrahedralize/readers.rs` for glTF) read, as files:
/// (fuzz target, name, bytes). Each is a seed of its fuzz target's corpus
/// (`fuzz/corpus/TARGET/variant-NAME`), so that fuzzing starts from the files real
/// exporters write, not only from tidy ones.
fn reader_variants() -> Vec<(&'static str, &'static str, Vec<u8>)> {
    let t = tetrahedron();
    let mut nan = tetrahedron();
    nan[2][1].y = f64::NAN;
    let mut cut = binary_stl("solid cut", 4, &t, &[]);
    cut.truncate(84 + 2 * 50 + 17);
    let bom = |data: &[u8]| [b"\xEF\xBB\xBF".as_slice(), data].concat();
    let text = ascii_solid("part", &t);
    let mut bad_face = tetra_faces();
    bad_face[2][1] = -1;
    let mut newline_x = corners();
    newline_x[0].x = f32::from_bits(0x3F80_000A) as f64;
    let comment = [
        "comment the header ends at end_header below",
        "obj_info end_header",
    ];
    let glb = std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/sphere.glb"),
    )
    .unwrap();
    vec![
        (
            "stl",
            "binary-zero-count",
            binary_stl("streamed", 0, &t, &[]),
        ),
        (
            "stl",
            "binary-solid-zero-count",
            binary_stl("solid streamed", 0, &t, &[]),
        ),
        (
            "stl",
            "binary-count-too-large",
            binary_stl("solid exported", 1000, &t, &[]),
        ),
        (
            "stl",
            "binary-count-too-small",
            binary_stl("exported", 1, &t, &[]),
        ),
        (
            "stl",
            "binary-padded",
            binary_stl("solid padded", 4, &t, &[0; 7]),
        ),
        ("stl", "binary-truncated", cut),
        ("stl", "binary-nan", binary_stl("nan", 0, &nan, &[])),
        ("stl", "ascii-upper-case", text.to_uppercase().into_bytes()),
        (
            "stl",
            "ascii-bom-crlf",
            bom(text.replace('\n', "\r\n").as_bytes()),
        ),
        (
            "stl",
            "ascii-several-solids",
            (ascii_solid("a", &t[..1]) + &ascii_solid("b", &t[1..3]) + &ascii_solid("", &t[3..]))
                .into_bytes(),
        ),
        ("stl", "ascii-short", b"solid x\nendsolid x\n".to_vec()),
        (
            "ply",
            "ascii-comment-end-header",
            ascii_ply(&comment, "\n", &tetra_faces()),
        ),
        (
            "ply",
            "binary-comment-end-header",
            binary_ply(&comment, "\n", &corners()),
        ),
        ("ply", "ascii-crlf", ascii_ply(&[], "\r\n", &tetra_faces())),
        ("ply", "ascii-cr", ascii_ply(&[], "\r", &tetra_faces())),
        (
            "ply",
            "binary-cr-newline-byte",
            binary_ply(&[], "\r", &newline_x),
        ),
        (
            "ply",
            "ascii-bad-face-index",
            ascii_ply(&[], "\n", &bad_face),
        ),
        (
            "ply",
            "ascii-faces-before-vertices",
            b"ply\nformat ascii 1.0\nelement face 2\nproperty list uchar int vertex_index\n\
              element vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
              end_header\n3 0 1 2\n3 2 1 -3\n0 0 0\n1 0 0\n0 1 0\n"
                .to_vec(),
        ),
        (
            "ply",
            "binary-bom",
            bom(&binary_ply(&[], "\r\n", &corners())),
        ),
        (
            "ply",
            "ascii-strips-restarted",
            strips_ply(false, &[], &[vec![0, 2, 1, 3, -1, 1, 3, 0, 2]]),
        ),
        (
            "ply",
            "binary-strips-joined",
            strips_ply(true, &[], &[vec![0, 2, 1, 3, 3, 1, 1, 3, 0, 2]]),
        ),
        (
            "ply",
            "binary-faces-and-strips",
            strips_ply(true, &[[0, 2, 1], [0, 1, 3]], &[vec![0, 3, 2, 1]]),
        ),
        (
            "ply",
            "ascii-bad-strip-index",
            strips_ply(false, &[], &[vec![0, 2, 1, 3], vec![1, 3, -2, 0]]),
        ),
        (
            "gltf",
            "node-under-two-parents",
            gltf_with_nodes(r#"[{"children":[1,2]},{"children":[2]},{"mesh":0}]"#, "[0]"),
        ),
        (
            "gltf",
            "shared-mesh-placed-twice",
            gltf_with_nodes(
                r#"[{"children":[1,2]},{"mesh":0},{"mesh":0,"translation":[0,0,5]}]"#,
                "[0]",
            ),
        ),
        (
            "gltf",
            "no-triangles",
            br#"{"asset":{"version":"2.0"}}"#.to_vec(),
        ),
        ("gltf", "glb-cut-short", glb[..glb.len() - 9].to_vec()),
    ]
}

/// The fuzz corpora of the surface readers (`fuzz/corpus/stl`, `ply`, `gltf`) hold every
/// reader variant above, byte for byte. After changing a variant, write them again with
/// `SOFT_TISSUE_WRITE_FUZZ_VARIANTS=1 cargo test -p soft_tissue_core --test
/// stl_ply_variants fuzz_corpora` and commit the files.
#[test]
fn the_fuzz_corpora_hold_every_reader_variant() {
    let corpus = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus");
    let write = std::env::var_os("SOFT_TISSUE_WRITE_FUZZ_VARIANTS").is_some();
    let mut missing = Vec::new();
    for (target, name, bytes) in reader_variants() {
        let path = corpus.join(target).join(format!("variant-{name}"));
        if write {
            std::fs::write(&path, &bytes).unwrap();
        } else if std::fs::read(&path).ok().as_deref() != Some(bytes.as_slice()) {
            missing.push(path.display().to_string());
        }
    }
    assert!(
        missing.is_empty(),
        "missing or out of date (see this test's docs to write them): {missing:#?}"
    );
}
