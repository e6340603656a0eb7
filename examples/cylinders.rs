//! The paper's cylinders scene (Tables II and III): two cylinders side by side, fixed at their
//! base, with the paper's parameters; each rises from its Green-coordinate cage to its precise
//! method when touched and returns when it rests. Keys choose the method combination.
//!
//! Run: `cargo run --profile test --example cylinders [-- --screenshot FILE --frames N]` (the
//! build `cargo test` made; `--release` for the fastest frames after a long build)
//!
//! Controls: right mouse drag orbits, shift + wheel zooms; the tool follows the mouse in the
//! screen plane and the wheel moves it nearer or farther, poking what it meets; hold the left
//! button to pick and drag; C toggles the cautery; P pauses, N steps, R resets.
//! 1: FEM / FEM, 2: MSD / MSD, 3: FEM / MSD, 4: MSD / FEM (model A / model B, linear FEM and
//! RK4 MSD as in the paper), 5: corotational FEM / implicit MSD.

mod common;

use bevy::prelude::*;
use bevy_soft_tissue::core::precision::PreciseMethod;
use bevy_soft_tissue::prelude::*;

fn choose_methods(keys: Res<ButtonInput<KeyCode>>, mut bodies: Query<(&Name, &mut SoftBody)>) {
    use PreciseMethod as M;
    let pair = if keys.just_pressed(KeyCode::Digit1) {
        (M::LinearFem, M::LinearFem)
    } else if keys.just_pressed(KeyCode::Digit2) {
        (M::MsdRk4, M::MsdRk4)
    } else if keys.just_pressed(KeyCode::Digit3) {
        (M::LinearFem, M::MsdRk4)
    } else if keys.just_pressed(KeyCode::Digit4) {
        (M::MsdRk4, M::LinearFem)
    } else if keys.just_pressed(KeyCode::Digit5) {
        (M::CorotationalFem, M::MsdImplicit)
    } else {
        return;
    };
    for (name, mut body) in &mut bodies {
        body.method = if name.as_str().ends_with('A') {
            pair.0
        } else {
            pair.1
        };
    }
}

fn main() -> AppExit {
    common::run(
        common::ExampleScene {
            title: "bevy_soft_tissue: cylinders (levels of precision)",
            scene: "scenes/cylinders.scene.ron",
            colours: vec![Color::srgb(0.80, 0.45, 0.40), Color::srgb(0.40, 0.55, 0.80)],
            script: "push-a-into-b",
            cautery_watts: 10.0,
            extra_controls: vec![
                "1: FEM/FEM, 2: MSD/MSD, 3: FEM/MSD, 4: MSD/FEM",
                "5: corotational FEM / implicit MSD",
            ],
        },
        |app| {
            app.add_systems(Update, choose_methods);
        },
    )
}
