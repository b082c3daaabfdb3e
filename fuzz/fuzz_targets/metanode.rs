//! The meta-node file: validated open, then every block parsed both ways navigation reads it.
//! The header checksum is stamped on the input first (see `common::with_header_checksum`).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let (_dir, path) = common::input_file("in.rmn", &common::with_header_checksum(data));
    if let Ok(f) = relief_core::format::metanode::MetaNodeFile::open(&path) {
        let _ = (f.base_triangles().len(), f.tree_bytes());
        let read = relief_core::format::metanode::MetaNodeFile::open_with(&path, relief_core::pager::Access::Read).ok();
        for m in 0..f.mnt().len().min(1 << 12) as u32 {
            let _ = f.block_pages(m);
            // Both ways navigation reads a block: pread (Ext, pool) and the map (Virt).
            if let Some(Ok(block)) = read.as_ref().map(|r| r.block(m)) {
                walk(relief_core::format::metanode::parse_block(&f, m, &block));
            }
            if let Ok(block) = f.block(m) {
                walk(relief_core::format::metanode::parse_block(&f, m, &block));
            }
        }
    }
});

fn walk(view: relief_core::Result<relief_core::format::metanode::BlockView<'_>>) {
    if let Ok(v) = view {
        for node in v.nodes {
            let _ = (v.position(node), v.triangles_of(node).len());
        }
    }
}
