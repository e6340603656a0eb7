//! The paper's organs scene (Fig. 4): liver, spleen, stomach and pancreas resting against
//! each other, gravity off, each at its cage level until the tool touches it. The liver has a
//! temperature field: the electrocautery heats it and thermal damage shows on its surface.
//!
//! Run: `cargo run --profile test --example organs [-- --screenshot FILE --frames N]` (the build
//! `cargo test` made; `--release` for the fastest frames after a long build); add
//! `--large` for the organs at segmentation sizes (`assets/scenes/organs-large.scene.ron`,
//! 27k tetrahedra, the prefactored corotational model), or `--scene FILE` for any scene;
//! `--surface FILE` adds your own organ, a closed surface (.obj, .stl, .ply, .gltf, .glb, relative to the
//! assets folder) meshed on load, beside the scene.
//!
//! Controls: right mouse drag orbits, shift + wheel zooms; the tool follows the mouse in the
//! screen plane and the wheel moves it nearer or farther, poking what it meets; hold the left
//! button to pick and drag; C toggles the cautery (10 W); P pauses, N steps, R resets.
//! The inspector panel lists every body's level, method (switchable) and step time.

mod common;

use bevy::prelude::*;

fn main() -> AppExit {
    common::run(
        common::ExampleScene {
            title: "bevy_soft_tissue: organs (levels of precision)",
            scene: "scenes/organs.scene.ron",
            colours: vec![
                Color::srgb(0.62, 0.22, 0.20),
                Color::srgb(0.45, 0.18, 0.32),
                Color::srgb(0.85, 0.62, 0.55),
                Color::srgb(0.90, 0.78, 0.52),
            ],
            script: "cauterize-liver",
            cautery_watts: 10.0,
            extra_controls: vec![],
        },
        |_| {},
    )
}
