//! Every DEM reader forced (`dem::open` with `--format`), so each sees content its detection
//! would have sent elsewhere (an .hgt that is not square, an ASCII grid without `ncols` first, a
//! grayscale PNG read as Terrain-RGB, …): the first byte picks the format, the rest is the file.
#![no_main]
use libfuzzer_sys::fuzz_target;
use relief_core::dem::DemFormat;

#[path = "common.rs"]
mod common;
#[path = "dem_stream.rs"]
mod dem_stream;

fuzz_target!(|data: &[u8]| {
    let Some((&pick, bytes)) = data.split_first() else { return };
    let format = DemFormat::ALL[pick as usize % DemFormat::ALL.len()];
    // A tile name, so the .hgt reader also derives its spacing.
    let (_dir, path) = common::input_file("S12W077.dem", bytes);
    if let Ok(source) = relief_core::dem::open(&path, Some(format)) {
        dem_stream::stream(source);
    }
});
