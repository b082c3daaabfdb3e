//! Mesh readers (OFF, PLY ASCII/binary, OBJ, optionally gzip'd): the first byte picks the name.
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

const NAMES: [&str; 5] = ["in.off", "in.ply", "in.obj", "in.ply.gz", "in.off.gz"];

fuzz_target!(|data: &[u8]| {
    let Some((&pick, bytes)) = data.split_first() else { return };
    let (_dir, path) = common::input_file(NAMES[pick as usize % NAMES.len()], bytes);
    if let Ok(mesh) = relief_core::mesh::read_mesh(&path) {
        let _ = mesh.bounds();
    }
});
