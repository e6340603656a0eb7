#![no_main]
//! Fuzz target: the STL parser (ASCII and binary) must never panic, and a surface it reads
//! must repair (or be refused) without a panic too.
use libfuzzer_sys::fuzz_target;
use soft_tissue_core::mesh::io::parse_stl;
use soft_tissue_core::mesh::tetrahedralize::repair;

fuzz_target!(|data: &[u8]| {
    if let Ok(s) = parse_stl(data, "fuzz.stl") {
        let _ = repair(&s);
    }
});
