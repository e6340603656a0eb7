#![no_main]
//! Fuzz target: the parser must return Ok or Err, never panic, on any bytes.
use libfuzzer_sys::fuzz_target;
use soft_tissue_core::mesh::io::{MeshFormat, parse_tet_mesh};

fuzz_target!(|data: &[u8]| {
    let _ = parse_tet_mesh(data, MeshFormat::Gmsh, "fuzz");
});
