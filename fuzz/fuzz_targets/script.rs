#![no_main]
//! Fuzz target: a tool script (RON) is parsed and validated; a valid one is sampled along
//! its path and turned into a recording (a script ending too far away is a typed error).
use libfuzzer_sys::fuzz_target;
use soft_tissue_core::haptics::Recording;
use soft_tissue_core::world::Script;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(script) = Script::from_ron(text, "fuzz.ron") else {
        return;
    };
    let end = script.end_time();
    for k in 0..=8 {
        let (position, axis) = script.pose_at(end * f64::from(k) / 8.0);
        assert!(position.iter().chain(axis.iter()).all(|c| c.is_finite()));
    }
    let _ = script.events_in(0.0, end).count();
    // A low rate keeps the samples few enough for the fuzzer's memory limit.
    if let Ok(r) = Recording::from_script(&script, 10.0, 0.5) {
        assert!(r.samples.len() as f64 <= end * 10.0 + 6.0);
    }
});
