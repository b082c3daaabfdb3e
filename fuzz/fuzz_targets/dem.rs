//! Every DEM reader, through the detection users hit (`dem::open` with no forced format): the
//! first byte picks the file name (extension), the rest is the file. Streams every sample unless
//! the header claims more than 2^22 of them (streaming a huge claimed grid is slow, not a bug).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

const NAMES: [&str; 6] = ["in.tif", "in.png", "in.exr", "N47E008.hgt", "in.asc", "in.dem"];

fuzz_target!(|data: &[u8]| {
    let Some((&pick, bytes)) = data.split_first() else { return };
    let (_dir, path) = common::input_file(NAMES[pick as usize % NAMES.len()], bytes);
    if let Ok(mut source) = relief::dem::open(&path, None) {
        let info = source.info().clone();
        if (info.width as u64) * (info.height as u64) <= 1 << 22 {
            let _ = source.read(&mut |run| {
                assert!(run.x0 as u64 + run.values.len() as u64 <= info.width as u64 && run.row < info.height);
                Ok(())
            });
        }
    }
});
