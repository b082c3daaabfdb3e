//! Flight-path JSON (one frame per line).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let (_dir, path) = common::input_file("path.json", data);
    if let Ok(p) = relief_core::flight::FlightPath::load(&path) {
        for k in 0..p.frames.len().min(64) {
            let _ = p.camera(k, 60.0, 320, 200);
        }
    }
});
