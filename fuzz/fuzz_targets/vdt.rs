//! The VDT forest file: validated open, then every accessor navigation and blocking use. The
//! header checksum is stamped on the input first (see `common::with_header_checksum`).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let (_dir, path) = common::input_file("in.vdt", &common::with_header_checksum(data));
    if let Ok(f) = relief_core::metanode::VdtFile::open(&path) {
        let _ = (f.leaves(), f.bounds(), f.metric(), f.base_triangles().len(), f.triangles().len());
        for id in 0..f.nodes().len().min(1 << 16) as u32 {
            let _ = f.node_triangles(id);
        }
        let _ = f.roots().count();
    }
});
