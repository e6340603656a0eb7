#![no_main]
//! Fuzz target: the glTF/GLB reader (container, JSON, buffers, accessors, node transforms)
//! must never panic, and a surface it reads must repair (or be refused) without a panic too.
//! A buffer kept in another file is answered with the input's own bytes.
use libfuzzer_sys::fuzz_target;
use soft_tissue_core::mesh::io::parse_gltf;
use soft_tissue_core::mesh::tetrahedralize::repair;

fuzz_target!(|data: &[u8]| {
    if let Ok(s) = parse_gltf(data, "fuzz.glb", &mut |_| Ok(data.to_vec())) {
        let _ = repair(&s);
    }
});
