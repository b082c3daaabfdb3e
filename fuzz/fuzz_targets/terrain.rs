//! The terrain file: validated open (magic, version, header checksum, sizes), then `verify`,
//! which reads every record, `info`, an orbit path over it and one refinement (culling and
//! geomorphing on) from that path's first camera: what `relief fly` reads. The header checksum
//! is stamped on the input first, so mutated header fields reach the checks behind it.
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let (_dir, path) = common::input_file("in.relief", &common::with_header_checksum(data));
    let Ok(file) = relief_core::format::terrain::TerrainFile::open(&path) else { return };
    let _ = relief_core::preprocess::inspect::verify(&file, relief_core::sys::progress::Progress::hidden());
    let _ = relief_core::preprocess::inspect::info(&file);
    let options = relief_core::flight::OrbitOptions { frames: 2, radius_m: None, altitude_m: None };
    let Ok(orbit) = relief_core::flight::orbit(&file, &options) else { return };
    let Ok(camera) = orbit.camera(0, 60.0, 320, 200) else { return };
    let mut refiner = relief_core::refine::Refiner::new(1).expect("a refiner");
    let mut strip = relief_core::refine::Strip::new();
    let refine = relief_core::refine::RefineOptions { morph_ratio: Some(2.0), ..Default::default() };
    let _ = refiner.refine_file(&file, &camera, &refine, &mut strip);
});
