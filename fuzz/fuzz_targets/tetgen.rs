#![no_main]
//! Fuzz target: the TetGen parser must never panic. The input is split at the first NUL byte
//! into the .node and the .ele file.
use libfuzzer_sys::fuzz_target;
use soft_tissue_core::mesh::io::parse_tetgen;

fuzz_target!(|data: &[u8]| {
    let split = data.iter().position(|&b| b == 0).unwrap_or(data.len());
    let (node, ele) = data.split_at(split);
    let ele = ele.get(1..).unwrap_or_default();
    let _ = parse_tetgen(node, "fuzz.node", ele, "fuzz.ele");
});
