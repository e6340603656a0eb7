#![no_main]
//! Fuzz target: the PLY parser (ASCII and both binary byte orders) must never panic, and a
//! surface it reads must repair (or be refused) without a panic too.
use libfuzzer_sys::fuzz_target;
use soft_tissue_core::mesh::io::parse_ply;
use soft_tissue_core::mesh::tetrahedralize::repair;

fuzz_target!(|data: &[u8]| {
    if let Ok(s) = parse_ply(data, "fuzz.ply") {
        let _ = repair(&s);
    }
});
