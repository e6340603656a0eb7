#![no_main]
//! Fuzz target: a haptic recording (RON) is parsed and validated; a valid one is replayed
//! (every position read back finite) and converted to a world script, which must validate.
use libfuzzer_sys::fuzz_target;
use soft_tissue_core::contact::ToolShape;
use soft_tissue_core::haptics::{Recording, ReplayDevice};

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(recording) = Recording::from_ron(text, "fuzz.ron") else {
        return;
    };
    let (first, last) = (
        recording.samples[0].t,
        recording.samples[recording.samples.len() - 1].t,
    );
    let script = recording.to_script(
        "replayed",
        ToolShape::Sphere { radius: 0.5 },
        [0.0, 1.0, 0.0],
        30.0,
        7,
    );
    script
        .validate()
        .expect("a valid recording converts to a valid script");
    let mut device = ReplayDevice::new(recording, 10.0).expect("validated");
    for k in 0..=16 {
        let t = first + (last - first) * f64::from(k) / 16.0;
        let state = device.state_at(t);
        assert!(
            state.position.iter().all(|c| c.is_finite()),
            "replay at {t}"
        );
    }
});
