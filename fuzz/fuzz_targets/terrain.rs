//! The terrain file: validated open (magic, version, header checksum, sizes), then `verify`,
//! which reads every record, and `info`.
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let (_dir, path) = common::input_file("in.relief", data);
    if let Ok(file) = relief::format::TerrainFile::open(&path) {
        let _ = relief::inspect::verify(&file, relief::progress::Progress::hidden());
        let _ = relief::inspect::info(&file);
    }
});
