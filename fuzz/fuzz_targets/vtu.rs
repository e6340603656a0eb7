#![no_main]
//! Fuzz target: the parser must return Ok or Err, never panic, on any bytes.
//!
//! The `.vtu` reader goes through `vtkio`, which (with its XML deserializer, `quick-xml`)
//! panics on some malformed files; the reader catches those panics and returns an error
//! (`mesh/io/vtk.rs`). libFuzzer's panic hook aborts on every panic before it can be caught,
//! so this target's hook lets panics raised inside those two crates unwind to the reader's
//! guard and keeps aborting on every other panic (ours).
use libfuzzer_sys::fuzz_target;
use soft_tissue_core::mesh::io::{MeshFormat, parse_tet_mesh};

fuzz_target!(
    init: {
        let abort = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let inside_vtkio = info.location().is_some_and(|l| {
                let file = l.file();
                file.contains("/vtkio-") || file.contains("/quick-xml-")
            });
            if !inside_vtkio {
                abort(info);
            }
        }));
    },
    |data: &[u8]| {
        let _ = parse_tet_mesh(data, MeshFormat::Vtu, "fuzz");
    }
);
