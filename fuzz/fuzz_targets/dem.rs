//! Every DEM reader, through the detection users hit (`dem::open` with no forced format): the
//! first byte picks the file name (extension), the rest is the file. Then streams the samples;
//! the sink stops a stream after 2^20 samples (a small file claiming a huge grid is refused or
//! fails when its data runs out: streaming on is slow, not a bug).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;
#[path = "dem_stream.rs"]
mod dem_stream;

const NAMES: [&str; 6] = ["in.tif", "in.png", "in.exr", "N47E008.hgt", "in.asc", "in.dem"];

fuzz_target!(|data: &[u8]| {
    let Some((&pick, bytes)) = data.split_first() else { return };
    let (_dir, path) = common::input_file(NAMES[pick as usize % NAMES.len()], bytes);
    if let Ok(source) = relief_core::dem::open(&path, None) {
        dem_stream::stream(source);
    }
});
