//! Mesh file formats: reading reference files written by an independent implementation
//! (meshio, see tests/fixtures/make_fixtures.py), round trips through our writers, every
//! malformed case with its location, the real-world files in ../shared/meshes when present,
//! and a no-panic sweep over truncated and corrupted inputs (the larger sweep over every
//! real-world file is `mutation.rs`).

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::TetMesh;
use soft_tissue_core::mesh::generate::Organ;
use soft_tissue_core::mesh::io::{
    self, FormatError, Location, MeshFormat, SurfaceMesh, WriteOptions, parse_obj, parse_tet_mesh,
    parse_tetgen, write_obj,
};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

mod support;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures")
}

struct Reference {
    positions: Vec<Vec3>,
    tets: BTreeSet<[usize; 4]>,
}

fn reference() -> Reference {
    let text = std::fs::read_to_string(fixtures().join("reference.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let positions = v["positions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let p: Vec<f64> = p
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect();
            Vec3::new(p[0], p[1], p[2])
        })
        .collect();
    let tets = v["tets"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| {
            let mut t: Vec<usize> = t
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_u64().unwrap() as usize)
                .collect();
            t.sort_unstable();
            [t[0], t[1], t[2], t[3]]
        })
        .collect();
    Reference { positions, tets }
}

fn tet_set(m: &TetMesh) -> BTreeSet<[usize; 4]> {
    m.tets()
        .iter()
        .map(|t| {
            let mut t = t.map(|v| v as usize);
            t.sort_unstable();
            t
        })
        .collect()
}

/// Same nodes (same order) and the same tets as vertex sets.
fn assert_same(m: &TetMesh, r: &Reference, tol: f64, what: &str) {
    assert_eq!(m.node_count(), r.positions.len(), "{what}: node count");
    for (i, (a, b)) in m.positions().iter().zip(&r.positions).enumerate() {
        assert!(
            (a - b).amax() <= tol,
            "{what}: node {i} differs: {a:?} vs {b:?}"
        );
    }
    assert_eq!(tet_set(m), r.tets, "{what}: tetrahedra differ");
}

#[test]
fn reads_meshio_reference_files_of_every_format() {
    let r = reference();
    let cases = [
        // meshio writes ASCII coordinates with 17 significant digits (%.16e): last-bit
        // rounding differences are expected there; binary files must be exact.
        ("block_v22_ascii.msh", 1e-15),
        ("block_v22_binary.msh", 0.0),
        ("block_v41_ascii.msh", 1e-15),
        ("block_v41_binary.msh", 0.0),
        ("block_ascii.vtk", 1e-15),
        ("block_binary.vtk", 0.0),
        // meshio's ASCII VTU writer keeps 12 significant digits.
        ("block_ascii.vtu", 1e-11),
        ("block_base64.vtu", 0.0),
        ("block.node", 1e-15),
    ];
    for (file, tol) in cases {
        let loaded =
            io::read_tet_mesh(fixtures().join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert_same(&loaded.mesh, &r, tol, file);
        if !file.ends_with(".node") {
            let skipped = loaded
                .notes
                .iter()
                .find(|n| n.starts_with("skipped"))
                .unwrap_or_else(|| panic!("{file}: no skip note in {:?}", loaded.notes));
            assert!(skipped.contains("1 lines"), "{file}: {skipped}");
            assert!(skipped.contains("2 triangles"), "{file}: {skipped}");
        }
        // 3 x 2 x 2 cubes of edge 0.37 (jittered by at most 0.02): the volume is near 12 * 0.37^3.
        let v = loaded.mesh.volume();
        assert!(
            (v - 12.0 * 0.37f64.powi(3)).abs() < 0.05,
            "{file}: volume {v}"
        );
    }
}

#[test]
fn hexahedra_and_wedges_are_split_conformingly() {
    let loaded = io::read_tet_mesh(fixtures().join("hex_wedge.vtu")).unwrap();
    let m = &loaded.mesh;
    assert!((m.volume() - 1.5).abs() < 1e-12, "volume {}", m.volume());
    // The boundary of a conforming split is closed: every edge in exactly two triangles.
    assert_closed(m);
    // Outer boundary: hex has 5 free faces (10 triangles), wedge 2 triangles + 2 quads (6).
    assert_eq!(m.surface().triangles().len(), 16);
}

fn assert_closed(m: &TetMesh) {
    let mut edges = std::collections::BTreeMap::new();
    for t in m.surface().triangles() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    assert!(edges.values().all(|&c| c == 2), "surface is not closed");
}

fn sample_mesh() -> TetMesh {
    Organ::Cylinder.generate(0.7).unwrap()
}

#[test]
fn writers_round_trip_exactly() {
    let m = sample_mesh();
    let r = Reference {
        positions: m.positions().to_vec(),
        tets: tet_set(&m),
    };
    for format in [MeshFormat::Gmsh, MeshFormat::VtkLegacy, MeshFormat::Vtu] {
        for binary in [false, true] {
            let bytes = io::write_tet_mesh_bytes(&m, format, WriteOptions { binary }, "x").unwrap();
            let back = parse_tet_mesh(&bytes, format, "x")
                .unwrap_or_else(|e| panic!("{format:?} {binary}: {e}"));
            assert_same(&back.mesh, &r, 0.0, &format!("{format:?} binary={binary}"));
            assert!(back.notes.is_empty(), "{:?}", back.notes);
        }
    }
    let (node, ele) = io::write_tetgen_bytes(&m);
    let back = parse_tetgen(&node, "x.node", &ele, "x.ele").unwrap();
    assert_same(&back.mesh, &r, 0.0, "tetgen");
    // A file whose extension names the other VTK form (real libraries have XML grids saved
    // as `.vtk`): the content decides.
    for (written, named) in [
        (MeshFormat::Vtu, MeshFormat::VtkLegacy),
        (MeshFormat::VtkLegacy, MeshFormat::Vtu),
    ] {
        let bytes =
            io::write_tet_mesh_bytes(&m, written, WriteOptions { binary: false }, "x").unwrap();
        let back = parse_tet_mesh(&bytes, named, "x")
            .unwrap_or_else(|e| panic!("{written:?} named {named:?}: {e}"));
        assert_same(&back.mesh, &r, 0.0, &format!("{written:?} named {named:?}"));
    }

    // Through files, with the extension choosing the format.
    let dir = std::env::temp_dir().join(format!("st-formats-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for name in ["a.msh", "a.vtk", "a.vtu", "a.node"] {
        let p = dir.join(name);
        io::write_tet_mesh(&m, &p, WriteOptions::default()).unwrap();
        assert_same(&io::read_tet_mesh(&p).unwrap().mesh, &r, 0.0, name);
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn obj_round_trip_and_polygon_faces() {
    let m = sample_mesh();
    let s = SurfaceMesh::boundary_of(&m);
    let back = parse_obj(&write_obj(&s), "s.obj").unwrap();
    assert_eq!(back, s);
    // Quads are fan-triangulated, v/vt/vn forms and negative indices resolve.
    let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1 4/1/1\nf -4//1 -2//1 -1//1\n";
    let q = parse_obj(text.as_bytes(), "q.obj").unwrap();
    assert_eq!(q.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 2, 3]]);
}

/// Negative indices count back from the vertices read so far (the OBJ rule), not from the
/// file's last vertex: two objects, each a `v` block and its own relative faces, as
/// exporters write them. Counted from the end, the first object's face took the second's
/// vertices and a real file's volume came out 1.67 times too large.
#[test]
fn obj_negative_indices_count_back_from_the_vertices_read_so_far() {
    let text = "o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n\
                o b\nv 0 0 5\nv 1 0 5\nv 0 1 5\nf -3/1 -2/2 -1/3\n";
    let s = parse_obj(text.as_bytes(), "two.obj").unwrap();
    assert_eq!(s.triangles, vec![[0, 1, 2], [3, 4, 5]]);
    let e = parse_obj(b"v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n", "c.obj").unwrap_err();
    assert!(
        e.to_string()
            .contains("line 3: face refers to vertex -3, but 2 vertices come before the face"),
        "{e}"
    );
}

/// What real exporters put around the records: a UTF-8 byte order mark (it hid the first
/// vertex and shifted every index by one), a `#` comment after a face, a line continued
/// with `\\`, and CR line ends (classic Mac OS), whose lines are numbered in messages.
#[test]
fn obj_reads_a_byte_order_mark_trailing_comments_continuations_and_cr_line_ends() {
    let want = SurfaceMesh {
        positions: vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ],
        triangles: vec![[0, 1, 2]],
    };
    let bom = b"\xEF\xBB\xBFv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    assert_eq!(parse_obj(bom, "bom.obj").unwrap(), want);
    let commented = "v 0 0 0 # origin\nv 1 \\\n 0 0\nv 0 1 0\nf 1 2 3 # the face\n";
    assert_eq!(parse_obj(commented.as_bytes(), "c.obj").unwrap(), want);
    let cr = "v 0 0 0\rv 1 0 0\rv 0 1 0\rf 1 2 3\r";
    assert_eq!(parse_obj(cr.as_bytes(), "cr.obj").unwrap(), want);
    let crlf = cr.replace('\r', "\r\n");
    assert_eq!(parse_obj(crlf.as_bytes(), "crlf.obj").unwrap(), want);
    for (text, name) in [(cr, "cr.obj"), (crlf.as_str(), "crlf.obj")] {
        let e = parse_obj(text.replace("f 1 2 3", "f 1 2 9").as_bytes(), name).unwrap_err();
        assert!(
            e.to_string()
                .contains(&format!("{name}: line 4: face refers to vertex 9")),
            "{e}"
        );
    }
}

/// A corner repeated in a row is a smaller polygon (`f 1 2 3 3`, a triangle written in a
/// quad's place, is the triangle); a face with fewer than three distinct corners stays,
/// degenerate, for the mesher's repair to count and drop, as the other readers leave it.
#[test]
fn obj_faces_with_repeated_corners_are_read_not_refused() {
    let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3 3\nf 4 4 1\nf 1 2 1 4\n";
    let s = parse_obj(text.as_bytes(), "r.obj").unwrap();
    assert_eq!(
        s.triangles,
        vec![[0, 1, 2], [3, 3, 0], [0, 1, 0], [0, 0, 3]]
    );
}

#[test]
fn gmsh_version_1_and_2_0() {
    let v1 = "$NOD\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$ENDNOD\n$ELM\n2\n1 4 1 1 4 1 2 3 4\n2 1 1 1 2 1 2\n$ENDELM\n";
    let m = parse_tet_mesh(v1.as_bytes(), MeshFormat::Gmsh, "v1.msh").unwrap();
    assert_eq!(m.mesh.tet_count(), 1);
    assert!((m.mesh.volume() - 1.0 / 6.0).abs() < 1e-15);
    assert!(m.notes.iter().any(|n| n.contains("1 lines")));
    // Version "2" (2.0) with sparse node tags.
    let v2 = "$MeshFormat\n2 0 8\n$EndMeshFormat\n$Nodes\n4\n10 0 0 0\n20 1 0 0\n30 0 1 0\n40 0 0 1\n$EndNodes\n$Elements\n1\n7 4 2 0 1 10 20 30 40\n$EndElements\n";
    let m = parse_tet_mesh(v2.as_bytes(), MeshFormat::Gmsh, "v2.msh").unwrap();
    assert_eq!(m.mesh.tet_count(), 1);
}

fn parse_err(text: &str, format: MeshFormat) -> FormatError {
    match parse_tet_mesh(text.as_bytes(), format, "bad") {
        Ok(_) => panic!("accepted malformed input:\n{text}"),
        Err(e) => e,
    }
}

fn assert_line(e: &FormatError, line: usize, needle: &str) {
    match e {
        FormatError::Parse {
            location, message, ..
        } => {
            assert_eq!(*location, Location::Line(line), "{e}");
            assert!(message.contains(needle), "'{e}' lacks '{needle}'");
        }
        other => panic!("expected a parse error at line {line}, got: {other}"),
    }
    assert!(e.to_string().starts_with("bad: "), "{e}");
}

const V22: &str = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n$Elements\n1\n1 4 2 0 1 1 2 3 4\n$EndElements\n";

#[test]
fn gmsh_malformed_inputs_name_the_line() {
    assert!(parse_tet_mesh(V22.as_bytes(), MeshFormat::Gmsh, "ok").is_ok());
    // Truncated inside the node list.
    let e = parse_err(&V22[..60], MeshFormat::Gmsh);
    assert!(e.to_string().contains("end"), "{e}");
    // Count that disagrees with the data.
    assert_line(
        &parse_err(&V22.replace("$Nodes\n4", "$Nodes\n5"), MeshFormat::Gmsh),
        10,
        "declares 5 nodes but ends after 4",
    );
    assert_line(
        &parse_err(&V22.replace("$Nodes\n4", "$Nodes\n3"), MeshFormat::Gmsh),
        9,
        "expected $EndNodes",
    );
    // Bad number.
    assert_line(
        &parse_err(&V22.replace("3 0 1 0", "3 0 x1 0"), MeshFormat::Gmsh),
        8,
        "'x1' is not a number",
    );
    // Wrong element arity.
    assert_line(
        &parse_err(
            &V22.replace("1 4 2 0 1 1 2 3 4", "1 4 2 0 1 1 2 3"),
            MeshFormat::Gmsh,
        ),
        13,
        "needs 4 nodes",
    );
    // Unknown node tag.
    assert_line(
        &parse_err(
            &V22.replace("1 2 3 4\n$End", "1 2 3 9\n$End"),
            MeshFormat::Gmsh,
        ),
        13,
        "node tag 9",
    );
    // Unsupported version.
    assert_line(
        &parse_err(&V22.replace("2.2 0 8", "4 0 8"), MeshFormat::Gmsh),
        2,
        "4.0 is not supported",
    );
    // Not a Gmsh file at all.
    assert_line(
        &parse_err("hello\n", MeshFormat::Gmsh),
        1,
        "expected a section",
    );
    // No tetrahedra: a clear error.
    let surface_only = V22.replace("1 4 2 0 1 1 2 3 4", "1 2 2 0 1 1 2 3");
    let e = parse_err(&surface_only, MeshFormat::Gmsh);
    assert!(
        matches!(e, FormatError::Unsupported { .. }) && e.to_string().contains("no tetrahedra"),
        "{e}"
    );
    // A degenerate element is named by its tag in the file.
    let flat = V22
        .replace("4 0 0 1\n", "4 0.3 0.3 0\n")
        .replace("1 4 2 0 1 1 2 3 4", "77 4 2 0 1 1 2 3 4");
    let e = parse_err(&flat, MeshFormat::Gmsh);
    assert!(
        e.to_string().starts_with("bad: element 77: tetrahedron 0"),
        "{e}"
    );
}

#[test]
fn gmsh_binary_truncation_names_the_byte() {
    let bytes = std::fs::read(fixtures().join("block_v22_binary.msh")).unwrap();
    let e = parse_tet_mesh(&bytes[..200], MeshFormat::Gmsh, "bad").unwrap_err();
    assert!(
        matches!(
            e,
            FormatError::Parse {
                location: Location::Byte(_),
                ..
            }
        ),
        "{e}"
    );
    let bytes = std::fs::read(fixtures().join("block_v41_binary.msh")).unwrap();
    let e = parse_tet_mesh(&bytes[..bytes.len() - 300], MeshFormat::Gmsh, "bad").unwrap_err();
    assert!(e.to_string().contains("bad: "), "{e}");
}

const VTK: &str = "# vtk DataFile Version 3.0\nt\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 4 float\n0 0 0 1 0 0\n0 1 0 0 0 1\nCELLS 1 5\n4 0 1 2 3\nCELL_TYPES 1\n10\n";

#[test]
fn vtk_malformed_inputs_name_the_problem() {
    assert!(parse_tet_mesh(VTK.as_bytes(), MeshFormat::VtkLegacy, "ok").is_ok());
    assert_line(
        &parse_err(&VTK.replace("0 0 1\n", "0 0 q\n"), MeshFormat::VtkLegacy),
        7,
        "'q' is not a number",
    );
    assert_line(
        &parse_err(&VTK.replace("POINTS 4", "POINTS 5"), MeshFormat::VtkLegacy),
        8,
        "'CELLS' is not a number",
    );
    // (replace this, with this, the message must contain)
    let cases = [
        ("CELLS 1 5", "CELLS 1 6", "CELLS"),
        (
            "4 0 1 2 3",
            "4 0 1 2 9",
            "cell 0 refers to point 9, but there are 4 points",
        ),
        ("4 0 1 2 3", "3 0 1 2 3", "CELLS"),
        (
            "CELLS 1 5\n4 0 1 2 3",
            "CELLS 1 4\n3 0 1 2",
            "cell 0 of type 10 (tetra) has 3 points, needs 4",
        ),
    ];
    for (from, to, needle) in cases {
        let e = parse_err(&VTK.replace(from, to), MeshFormat::VtkLegacy);
        assert!(e.to_string().contains(needle), "{e}");
    }
    let e = parse_err(&VTK[..VTK.len() - 3], MeshFormat::VtkLegacy);
    assert!(
        e.to_string()
            .contains("file ends after 0 of the 1 values of CELL_TYPES"),
        "{e}"
    );
    let e = parse_err(
        &VTK.replace("UNSTRUCTURED_GRID", "POLYDATA"),
        MeshFormat::VtkLegacy,
    );
    assert!(
        e.to_string().contains("no tetrahedra") && e.to_string().contains("POLYDATA"),
        "{e}"
    );
    assert_line(
        &parse_err("# not vtk\n", MeshFormat::VtkLegacy),
        1,
        "not a legacy VTK file",
    );
    // Binary data cut short.
    let bytes = std::fs::read(fixtures().join("block_binary.vtk")).unwrap();
    let e = parse_tet_mesh(&bytes[..300], MeshFormat::VtkLegacy, "bad").unwrap_err();
    assert!(
        matches!(
            e,
            FormatError::Parse {
                location: Location::Byte(_),
                ..
            }
        ),
        "{e}"
    );
}

#[test]
fn vtu_malformed_inputs_are_errors() {
    let text = std::fs::read_to_string(fixtures().join("block_ascii.vtu")).unwrap();
    let e = parse_tet_mesh(
        &text.as_bytes()[..text.len() / 2],
        MeshFormat::Vtu,
        "bad.vtu",
    )
    .unwrap_err();
    assert!(e.to_string().starts_with("bad.vtu: "), "{e}");
    let poly = "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"0.1\" byte_order=\"LittleEndian\"><PolyData><Piece NumberOfPoints=\"3\" NumberOfVerts=\"0\" NumberOfLines=\"0\" NumberOfStrips=\"0\" NumberOfPolys=\"1\"><Points><DataArray type=\"Float32\" NumberOfComponents=\"3\" format=\"ascii\">0 0 0 1 0 0 0 1 0</DataArray></Points><Polys><DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">0 1 2</DataArray><DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">3</DataArray></Polys></Piece></PolyData></VTKFile>";
    let e = parse_tet_mesh(poly.as_bytes(), MeshFormat::Vtu, "surf.vtu").unwrap_err();
    assert!(e.to_string().contains("no tetrahedra"), "{e}");
}

/// Regression: a VTU Piece without <Points> made vtkio panic (found by the `vtu` fuzz target).
#[test]
fn vtu_piece_without_points_is_an_error_not_a_panic() {
    let bytes = std::fs::read(fixtures().join("regressions/vtu_piece_without_points.vtu")).unwrap();
    let e = parse_tet_mesh(&bytes, MeshFormat::Vtu, "crash.vtu").unwrap_err();
    assert!(e.to_string().starts_with("crash.vtu: "), "{e}");
}

#[test]
fn tetgen_and_obj_malformed_inputs_name_the_line() {
    let node = "# c\n4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n";
    let ele = "1 4 0\n1 1 2 3 4\n";
    assert!(parse_tetgen(node.as_bytes(), "a.node", ele.as_bytes(), "a.ele").is_ok());
    let e = parse_tetgen(
        node.replace("4 3 0 0", "5 3 0 0").as_bytes(),
        "a.node",
        ele.as_bytes(),
        "a.ele",
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains("a.node: line 7: file ends after 4 of the 5 declared points"),
        "{e}"
    );
    let e = parse_tetgen(
        node.as_bytes(),
        "a.node",
        "1 4 0\n1 1 2 3 8\n".as_bytes(),
        "a.ele",
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains("a.ele: line 2: tetrahedron 1 refers to point 8"),
        "{e}"
    );
    let e = parse_tetgen(
        node.as_bytes(),
        "a.node",
        "1 4 0\n1 1 2 3\n".as_bytes(),
        "a.ele",
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains("line 2: a tetrahedron line needs 5 fields, found 4"),
        "{e}"
    );
    let e = parse_tetgen(
        node.replace("2 1 0 0", "2 1 0 z").as_bytes(),
        "a.node",
        ele.as_bytes(),
        "a.ele",
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains("a.node: line 4: z: 'z' is not a number"),
        "{e}"
    );

    let e = parse_obj(b"v 0 0 0\nv 1 0 0\nf 1 2 3\n", "c.obj").unwrap_err();
    assert!(
        e.to_string()
            .contains("c.obj: line 3: face refers to vertex 3, but there are 2 vertices"),
        "{e}"
    );
    let e = parse_obj(b"v 0 0\n", "c.obj").unwrap_err();
    assert!(e.to_string().contains("c.obj: line 1"), "{e}");
}

#[test]
fn real_world_meshes_from_shared_folder() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/meshes");
    let Some(dir) = support::shared_folder(
        &dir,
        "real_world_meshes_from_shared_folder",
        support::shared_meshes_required(),
    ) else {
        return;
    };
    let entries = std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    let mut seen = 0;
    for entry in entries {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        let loaded = io::read_tet_mesh(&path);
        if name.contains("bad") {
            // Meant to be bad: either a clear error or loaded with warnings.
            match loaded {
                Ok(l) => assert!(!l.notes.is_empty(), "{name} loaded without a warning"),
                Err(e) => assert!(e.to_string().contains(&name), "{e}"),
            }
        } else {
            let l = loaded.unwrap_or_else(|e| panic!("{e}"));
            assert!(l.mesh.tet_count() > 0 && l.mesh.volume() > 0.0, "{name}");
            assert_closed(&l.mesh);
        }
        seen += 1;
    }
    assert!(seen > 0);
}

/// A missing shared folder fails the test where the flag asks for it, and is skipped (with
/// SKIPPED printed) where it does not; a folder that is there is read.
#[test]
fn a_missing_shared_folder_fails_when_required() {
    let missing = Path::new(env!("CARGO_MANIFEST_DIR")).join("no-such-folder/meshes");
    let failed = std::panic::catch_unwind(|| support::shared_folder(&missing, "probe", true));
    let message = failed.expect_err("a missing folder passed under the flag");
    let text = message
        .downcast_ref::<String>()
        .cloned()
        .unwrap_or_default();
    assert!(
        text.contains("no-such-folder/meshes") && text.contains("SOFT_TISSUE_REQUIRE_SHARED"),
        "{text}"
    );
    assert_eq!(
        support::shared_folder(
            &missing,
            "the probe of a missing folder (an expected skip)",
            false
        ),
        None
    );
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    assert_eq!(support::shared_folder(here, "probe", true), Some(here));
}

/// Every parser must return (never panic) on truncated and corrupted copies of valid files
/// (TetGen's pair of files included), and on declared counts far beyond the data.
#[test]
fn no_panic_on_truncated_or_corrupted_input() {
    let mut inputs: Vec<(Vec<u8>, MeshFormat)> = Vec::new();
    for entry in std::fs::read_dir(fixtures()).unwrap() {
        let p = entry.unwrap().path();
        if let Some(f) = MeshFormat::from_path(&p)
            && f != MeshFormat::TetGen
        {
            inputs.push((std::fs::read(&p).unwrap(), f));
        }
    }
    inputs.push((V22.as_bytes().to_vec(), MeshFormat::Gmsh));
    inputs.push((VTK.as_bytes().to_vec(), MeshFormat::VtkLegacy));
    // A copy of `bytes` with one to four bytes replaced (digits, line breaks, signs, noise).
    let mut rng = support::Rng::new(0x9E37_79B9_7F4A_7C15);
    let mut corrupt =
        move |bytes: &[u8]| support::replace_bytes(&mut rng, bytes.len()).apply(bytes);
    for (bytes, format) in &inputs {
        for cut in (0..bytes.len()).step_by((bytes.len() / 97).max(1)) {
            let _ = parse_tet_mesh(&bytes[..cut], *format, "t");
        }
        for _ in 0..300 {
            let _ = parse_tet_mesh(&corrupt(bytes), *format, "t");
        }
    }
    let obj = write_obj(&SurfaceMesh::boundary_of(&sample_mesh()));
    for cut in (0..obj.len()).step_by(97) {
        let _ = parse_obj(&obj[..cut], "t");
    }
    // TetGen (two files): truncate and corrupt each side, and declare huge counts.
    let (node, ele) = io::write_tetgen_bytes(&sample_mesh());
    for (k, whole) in [&node, &ele].into_iter().enumerate() {
        for cut in (0..whole.len()).step_by((whole.len() / 97).max(1)) {
            let part = &whole[..cut];
            let _ = match k {
                0 => parse_tetgen(part, "n", &ele, "e"),
                _ => parse_tetgen(&node, "n", part, "e"),
            };
        }
        for _ in 0..300 {
            let b = corrupt(whole);
            let _ = match k {
                0 => parse_tetgen(&b, "n", &ele, "e"),
                _ => parse_tetgen(&node, "n", &b, "e"),
            };
        }
    }
    let huge = usize::MAX.to_string();
    for header in [
        format!("3 3 {huge} 0\n"),
        format!("3 3 0 {huge}\n"),
        format!("{huge} 3 0 0\n"),
    ] {
        assert!(
            parse_tetgen(header.as_bytes(), "n", &ele, "e").is_err(),
            "{header}"
        );
    }
    for header in [format!("1 4 {huge}\n"), format!("{huge} 4 0\n")] {
        assert!(
            parse_tetgen(&node, "n", header.as_bytes(), "e").is_err(),
            "{header}"
        );
    }
    // Gmsh: a tag count beyond the line (2.2), a node count beyond the line (1.0).
    let tags = V22.replace("1 4 2 0 1 1 2 3 4", &format!("1 4 {huge} 0 1 1 2 3 4"));
    assert!(parse_tet_mesh(tags.as_bytes(), MeshFormat::Gmsh, "t").is_err());
    let v1 = format!(
        "$NOD\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$ENDNOD\n$ELM\n1\n1 4 1 1 {huge} 1 2 3 4\n$ENDELM\n"
    );
    assert!(parse_tet_mesh(v1.as_bytes(), MeshFormat::Gmsh, "t").is_err());
}

/// A glTF file with one triangle, (0,0,0) (1,0,0) (0,1,0), in a data URI (the nine floats'
/// little-endian bytes in base64), the given nodes, scenes and default scene.
fn gltf_with(nodes: &str, scenes: &str, scene: usize) -> String {
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":{scene},"scenes":{scenes},"nodes":{nodes},
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",
        "min":[0,0,0],"max":[1,1,0]}}],"bufferViews":[{{"buffer":0,"byteLength":36}}],
        "buffers":[{{"byteLength":36,
        "uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA"}}]}}"#
    )
}

/// A scene's nodes must be root nodes (glTF 2.0, 3.5.1: listed in no node's `children`,
/// each once). A root that is also a child was walked twice, from the scene and from its
/// parent (a chain listed whole as roots is walked quadratically), and is refused naming
/// the node, the scene and the parent; a root listed twice is refused too. One node as the
/// root of two scenes is allowed, and two roots placing one mesh place it twice.
#[test]
fn a_gltf_scene_root_that_is_also_a_child_is_refused() {
    use soft_tissue_core::mesh::io::parse_gltf;
    let err = |text: &str| match parse_gltf(text.as_bytes(), "r.gltf", &mut |_| unreachable!()) {
        Ok(s) => panic!("read {} triangles, expected an error", s.triangles.len()),
        Err(e) => e.to_string(),
    };
    let chain = r#"[{"children":[1],"mesh":0},{"children":[2],"mesh":0},{"mesh":0}]"#;
    for (scenes, scene, node, parent) in [
        (r#"[{"nodes":[0,1]}]"#, 0, 1, 0),
        (r#"[{"nodes":[0,1,2]}]"#, 0, 1, 0),
        (r#"[{"nodes":[2,0]}]"#, 0, 2, 1),
        (r#"[{"nodes":[0]},{"nodes":[1]}]"#, 1, 1, 0),
    ] {
        let e = err(&gltf_with(chain, scenes, scene));
        assert!(
            e.contains(&format!(
                "r.gltf: node {node} is a root of scene {scene} and a child of node {parent}"
            )),
            "{scenes}: {e}"
        );
    }
    let twice = gltf_with(r#"[{"mesh":0}]"#, r#"[{"nodes":[0,0]}]"#, 0);
    let e = err(&twice);
    assert!(
        e.contains("r.gltf: node 0 is listed twice in scene 0's nodes"),
        "{e}"
    );
    // Allowed: node 0 is the root of both scenes; two roots share the mesh.
    let two_roots = gltf_with(
        r#"[{"mesh":0},{"mesh":0,"translation":[0,0,5]}]"#,
        r#"[{"nodes":[0]},{"nodes":[0,1]}]"#,
        1,
    );
    let s = parse_gltf(two_roots.as_bytes(), "r.gltf", &mut |_| unreachable!()).unwrap();
    assert_eq!(s.triangles.len(), 2);
    for z in [0.0, 5.0] {
        assert!(
            s.positions.contains(&Vec3::new(0.0, 1.0, z)),
            "{:?}",
            s.positions
        );
    }
    // The chain with only its top as the root: three triangles, one per node.
    let s = parse_gltf(
        gltf_with(chain, r#"[{"nodes":[0]}]"#, 0).as_bytes(),
        "r.gltf",
        &mut |_| unreachable!(),
    )
    .unwrap();
    assert_eq!(s.triangles.len(), 3);
}
