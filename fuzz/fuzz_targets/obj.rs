#![no_main]
//! Fuzz target: the OBJ parser must never panic.
use libfuzzer_sys::fuzz_target;
use soft_tissue_core::mesh::io::parse_obj;

fuzz_target!(|data: &[u8]| {
    let _ = parse_obj(data, "fuzz.obj");
});
