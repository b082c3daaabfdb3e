//! The meta-node file: validated open, then every block parsed both ways navigation reads it.
//! The header checksum is stamped on the input first (see `common::with_header_checksum`).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let (_dir, path) = common::input_file("in.rmn", &common::with_header_checksum(data));
    if let Ok(f) = relief::metanode::blocking::MetaNodeFile::open(&path) {
        let _ = (f.base_triangles().len(), f.tree_bytes());
        let mut buf = Vec::new();
        for m in 0..f.mnt().len().min(1 << 12) as u32 {
            let _ = f.block_pages(m);
            // Both ways navigation reads a block: pread (Ext) and the map (Virt).
            if f.read_block(m, &mut buf).is_ok() {
                let bytes: &[u8] = words_as_bytes(&buf);
                walk(relief::metanode::navigate::parse_block(&f, m, bytes));
            }
            walk(relief::metanode::navigate::parse_block(&f, m, f.mapped_block(m)));
        }
    }
});

fn walk(view: relief::Result<relief::metanode::blocking::BlockView<'_>>) {
    if let Ok(v) = view {
        for node in v.nodes {
            let _ = (v.position(node), v.triangles_of(node).len());
        }
    }
}

fn words_as_bytes(words: &[u32]) -> &[u8] {
    // SAFETY: u32 has no padding and u8 has alignment 1; the length is in bytes.
    unsafe { std::slice::from_raw_parts(words.as_ptr().cast(), words.len() * 4) }
}
