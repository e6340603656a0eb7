//! Same surface, same options, same mesh, byte for byte: a hash of the Gmsh file of five
//! meshed surfaces (uniform, graded, crease fit, a cavity, overlapping parts) against the
//! hashes checked in below.
//!
//! A change to the mesher that changes any of these meshes must be deliberate: raise
//! `tetrahedralize::REVISION` (caches of meshed surfaces key on it), then update the hashes
//! here from the test's failure message, which prints every hash found, and say in the
//! commit why the meshes changed. Set `SOFT_TISSUE_GOLDEN_OBJ=DIR` to also write the five
//! input surfaces as OBJ files: `soft-tissue mesh tetrahedralize DIR/NAME.obj --out X.msh
//! --target-tets 1500` writes the same bytes (the CLI's path, checked against a build of
//! another commit with `cmp`).

use soft_tissue_core::Vec3;
use soft_tissue_core::mesh::io::write_tet_mesh_bytes;
use soft_tissue_core::mesh::io::{MeshFormat, SurfaceMesh, WriteOptions, write_obj};
use soft_tissue_core::mesh::tetrahedralize::{REVISION, TetrahedralizeOptions, tetrahedralize};

use super::shapes::{ellipsoid, joined, l_prism, sphere};

/// 64-bit FNV-1a (Fowler, Noll and Vo): a fixed, documented hash, the same on every
/// platform and toolchain (unlike the standard library's `DefaultHasher`).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// The surfaces, by name.
fn surfaces() -> Vec<(&'static str, SurfaceMesh)> {
    let moved = |mut s: SurfaceMesh, d: Vec3| {
        for p in &mut s.positions {
            *p += d;
        }
        s
    };
    vec![
        ("sphere", sphere(0.5)),
        ("knife_lens", ellipsoid(1.0, 0.6, 0.1)),
        ("l_prism", l_prism(0.6)),
        (
            "hollow",
            joined(&[(sphere(1.0), false), (sphere(0.5), true)]),
        ),
        (
            "overlap",
            joined(&[
                (sphere(1.0), false),
                (moved(sphere(1.0), Vec3::new(1.0, 0.0, 0.0)), false),
            ]),
        ),
    ]
}

/// The hashes of the meshes at `REVISION` 5 (see the module docs to update them); the
/// CLI of the commit before the mesher was split into files wrote the same bytes.
const GOLDEN: [(&str, u64); 5] = [
    ("sphere", 0x8dbe_9201_6fed_700e),
    ("knife_lens", 0x5c57_b02e_d41b_67d2),
    ("l_prism", 0x7a68_ebb7_2128_2792),
    ("hollow", 0x4947_a0c1_3c03_23d1),
    ("overlap", 0x0f2c_4f2c_4bdc_643b),
];

#[test]
fn meshed_surfaces_are_the_same_bytes_as_checked_in() {
    let obj_dir = std::env::var_os("SOFT_TISSUE_GOLDEN_OBJ").map(std::path::PathBuf::from);
    let mut found = Vec::new();
    for (name, surface) in surfaces() {
        if let Some(dir) = &obj_dir {
            std::fs::write(dir.join(format!("{name}.obj")), write_obj(&surface)).unwrap();
        }
        let (mesh, _) = tetrahedralize(&surface, &TetrahedralizeOptions::default()).unwrap();
        let bytes = write_tet_mesh_bytes(
            &mesh,
            MeshFormat::Gmsh,
            WriteOptions::default(),
            &format!("{name}.msh"),
        )
        .unwrap();
        found.push((name, fnv1a(&bytes)));
    }
    let listed: String = found
        .iter()
        .map(|(n, h)| format!("    (\"{n}\", 0x{h:016x}),\n"))
        .collect();
    assert_eq!(
        REVISION, 5,
        "the mesher's revision changed: check the hashes below and update GOLDEN:\n{listed}"
    );
    assert_eq!(
        found,
        GOLDEN.to_vec(),
        "a mesh changed without a new REVISION; if deliberate, raise REVISION and update \
         GOLDEN to:\n{listed}"
    );
}

/// The hash itself, against the published FNV-1a 64 test values.
#[test]
fn fnv1a_matches_its_published_values() {
    assert_eq!(fnv1a(b""), 0xcbf2_9ce4_8422_2325);
    assert_eq!(fnv1a(b"a"), 0xaf63_dc4c_8601_ec8c);
    assert_eq!(fnv1a(b"foobar"), 0x8594_4171_f739_67e8);
}
