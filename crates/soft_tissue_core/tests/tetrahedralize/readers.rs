//! The surface readers against files other writers made (meshio, trimesh, pygltflib).

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::tetrahedralize::{TetrahedralizeOptions, repair, tetrahedralize};

/// A point written as a JSON array of three numbers.
fn json_point(p: &serde_json::Value) -> Vec3 {
    let c: Vec<f64> = p
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    Vec3::new(c[0], c[1], c[2])
}

/// The surface readers against files meshio wrote (tests/fixtures/make_surface_fixtures.py):
/// ASCII and binary STL and PLY, and OBJ give, once welded, the reference's points and triangles
/// (binary STL to float precision), and the binary STL meshes.
#[test]
fn surface_files_written_by_meshio_read_back_as_the_reference() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures");
    let text = std::fs::read_to_string(dir.join("surface_reference.json")).unwrap();
    let reference: serde_json::Value = serde_json::from_str(&text).unwrap();
    let points: Vec<Vec3> = reference["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(json_point)
        .collect();
    let triangles: Vec<[usize; 3]> = reference["triangles"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| {
            let c: Vec<usize> = t
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_u64().unwrap() as usize)
                .collect();
            [c[0], c[1], c[2]]
        })
        .collect();
    for (file, tol) in [
        ("sphere_ascii.stl", 1e-12),
        ("sphere_binary.stl", 1e-6),
        ("sphere.obj", 1e-12),
        ("sphere_ascii.ply", 1e-12),
        ("sphere_binary.ply", 1e-12),
    ] {
        let s = soft_tissue_core::mesh::io::read_surface(dir.join(file)).unwrap();
        assert_eq!(s.triangles.len(), triangles.len(), "{file}");
        let fixed = repair(&s).unwrap();
        assert_eq!(
            fixed.positions.len(),
            points.len(),
            "{file}: welded vertices"
        );
        assert_eq!(fixed.defects.boundary_edges, 0, "{file}");
        assert_eq!(
            fixed.defects.flipped_triangles, 0,
            "{file}: meshio keeps the orientation"
        );
        // Every reference triangle is there, in the same turning order.
        for (k, t) in triangles.iter().enumerate() {
            let want = t.map(|v| points[v]);
            let found = fixed.triangles.iter().any(|f| {
                let got = f.map(|v| fixed.positions[v as usize]);
                (0..3).any(|r| (0..3).all(|i| (got[(i + r) % 3] - want[i]).norm() < tol))
            });
            assert!(found, "{file}: triangle {k} missing");
        }
    }
    let s = soft_tissue_core::mesh::io::read_surface(dir.join("sphere_binary.stl")).unwrap();
    let (_, r) = tetrahedralize(&s, &TetrahedralizeOptions::default()).unwrap();
    assert!(
        (r.volume - r.enclosed_volume).abs() <= 0.03 * r.enclosed_volume,
        "{r:?}"
    );
    // Not a surface file, and a truncated binary STL: errors naming the file.
    let e = soft_tissue_core::mesh::io::read_surface(dir.join("block.node")).unwrap_err();
    assert!(e.to_string().contains("block.node"), "{e}");
    let data = std::fs::read(dir.join("sphere_binary.stl")).unwrap();
    let e = soft_tissue_core::mesh::io::parse_stl(&data[..data.len() - 7], "cut.stl").unwrap_err();
    assert!(e.to_string().contains("cut.stl"), "{e}");
}

/// The glTF reader against files two other writers made (tests/fixtures/make_surface_fixtures.py):
/// a GLB from trimesh (one node, rotated and moved) and a `.gltf` from pygltflib (a scaled
/// parent with two children sharing the mesh, one mirrored), with its buffer in a `.bin` file
/// or in a base64 data URI. Every placed triangle is found at its world place, facing out.
#[test]
fn gltf_files_written_by_trimesh_and_pygltflib_read_back_placed() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures");
    let text = std::fs::read_to_string(dir.join("surface_reference.json")).unwrap();
    let reference: serde_json::Value = serde_json::from_str(&text).unwrap();
    let triangles_of = |key: &str| -> Vec<[Vec3; 3]> {
        reference["gltf"][key]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| {
                let p: Vec<Vec3> = t.as_array().unwrap().iter().map(json_point).collect();
                [p[0], p[1], p[2]]
            })
            .collect()
    };
    for (file, key) in [
        ("sphere.glb", "sphere.glb"),
        ("spheres.gltf", "spheres.gltf"),
        ("spheres_embedded.gltf", "spheres.gltf"),
    ] {
        let want = triangles_of(key);
        let s = soft_tissue_core::mesh::io::read_surface(dir.join(file)).unwrap();
        assert_eq!(s.triangles.len(), want.len(), "{file}");
        let got: Vec<[Vec3; 3]> = s
            .triangles
            .iter()
            .map(|t| t.map(|v| s.positions[v as usize]))
            .collect();
        // Positions are 32-bit floats in the file.
        let tol = 1e-5;
        for (k, w) in want.iter().enumerate() {
            let found = got
                .iter()
                .any(|g| (0..3).any(|r| (0..3).all(|i| (g[(i + r) % 3] - w[i]).norm() < tol)));
            assert!(
                found,
                "{file}: placed triangle {k} missing or turned the wrong way"
            );
        }
        let fixed = repair(&s).unwrap();
        assert_eq!(
            fixed.defects.flipped_triangles, 0,
            "{file}: every piece faces out"
        );
        assert_eq!(fixed.defects.boundary_edges, 0, "{file}");
    }
    // A mirrored child keeps its volume: the two spheres (scale 2) enclose 8x the one's.
    let one = repair(&soft_tissue_core::mesh::io::read_surface(dir.join("sphere.glb")).unwrap())
        .unwrap()
        .enclosed_volume;
    let two = repair(&soft_tissue_core::mesh::io::read_surface(dir.join("spheres.gltf")).unwrap())
        .unwrap()
        .enclosed_volume;
    assert!((two / one - 16.0).abs() < 1e-4, "{two} against {one}");
    // Broken files: a GLB cut short, a .gltf whose buffer file is missing, a buffer too
    // short and an index out of range each name the file and what is wrong.
    use soft_tissue_core::mesh::io::parse_gltf;
    let glb = std::fs::read(dir.join("sphere.glb")).unwrap();
    let e = parse_gltf(&glb[..glb.len() - 9], "cut.glb", &mut |_| unreachable!()).unwrap_err();
    assert!(e.to_string().contains("cut.glb"), "{e}");
    let gltf = std::fs::read(dir.join("spheres.gltf")).unwrap();
    let bin = std::fs::read(dir.join("spheres.bin")).unwrap();
    // A buffer file that is not there: the error names the glTF, the buffer and its file.
    let e = soft_tissue_core::mesh::io::read_surface(dir.join("missing_buffer.gltf"));
    assert!(e.is_err());
    let e = parse_gltf(&gltf, "missing.gltf", &mut |uri| {
        Err(soft_tissue_core::mesh::io::FormatError::Io {
            file: uri.to_owned(),
            source: std::io::ErrorKind::NotFound.into(),
        })
    })
    .unwrap_err()
    .to_string();
    assert!(
        e.starts_with("missing.gltf: buffer 0: spheres.bin: "),
        "{e}"
    );
    let e = parse_gltf(&gltf, "short.gltf", &mut |_| Ok(bin[..100].to_vec())).unwrap_err();
    assert!(
        e.to_string().contains("short.gltf") && e.to_string().contains("buffer 0"),
        "{e}"
    );
    let mut bad = bin.clone();
    bad[0] = 0xff; // the first 16-bit index: 255 + 256 * its high byte, past the 66 points
    bad[1] = 0x7f;
    let e = parse_gltf(&gltf, "index.gltf", &mut |_| Ok(bad.clone())).unwrap_err();
    assert!(e.to_string().contains("index 0 is 32767"), "{e}");
    let e = parse_gltf(
        b"{\"asset\":{\"version\":\"2.0\"}}",
        "empty.gltf",
        &mut |_| unreachable!(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("no triangles"), "{e}");
}

/// A glTF node hierarchy is a set of trees: a node under two parents is refused with both
/// named (walked as given, a chain of 40 such nodes placed its mesh 2^40 times and never
/// finished), while a mesh shared by two nodes, the format's instancing, is placed twice.
#[test]
fn a_gltf_node_under_two_parents_is_refused_and_a_shared_mesh_is_placed_twice() {
    use soft_tissue_core::mesh::io::parse_gltf;
    // One triangle, (0,0,0) (1,0,0) (0,1,0), in a data URI.
    let with_nodes = |nodes: &str, roots: &str| {
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":{roots}}}],
            "nodes":{nodes},"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",
            "min":[0,0,0],"max":[1,1,0]}}],"bufferViews":[{{"buffer":0,"byteLength":36}}],
            "buffers":[{{"byteLength":36,
            "uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA"}}]}}"#
        )
    };
    let diamond = with_nodes(r#"[{"children":[1,2]},{"children":[2]},{"mesh":0}]"#, "[0]");
    let e = parse_gltf(diamond.as_bytes(), "diamond.gltf", &mut |_| unreachable!()).unwrap_err();
    assert!(
        e.to_string()
            .contains("diamond.gltf: node 2 is a child of both node 0 and node 1"),
        "{e}"
    );
    let shared = with_nodes(
        r#"[{"children":[1,2]},{"mesh":0},{"mesh":0,"translation":[0,0,5]}]"#,
        "[0]",
    );
    let s = parse_gltf(shared.as_bytes(), "shared.gltf", &mut |_| unreachable!()).unwrap();
    assert_eq!(s.triangles.len(), 2);
    for z in [0.0, 5.0] {
        assert!(
            s.positions.contains(&Vec3::new(0.0, 1.0, z)),
            "{:?}",
            s.positions
        );
    }
}
