//! The page file: validated open, every page read both ways (pread and the map) and decoded,
//! then a few frames of the per-frame fetch (k-d query, box and normal-cone culling, reads).
//! Both checksums are stamped on the input first (see `stamp`), so the fields behind them are
//! fuzzed rather than the comparison.
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

use relief_core::diskpages::fetch::{FetchOptions, PageSource};
use relief_core::flight::frame::FrameSource;
use relief_core::format::pagefile::PageFile;

fuzz_target!(|data: &[u8]| {
    let (_dir, path) = common::input_file("in.rpg", &stamp(data));
    let Ok(f) = PageFile::open(&path) else { return };
    let read = PageFile::open_with(&path, relief_core::pager::Access::Read).ok();
    for p in 0..f.header().pages.min(1 << 12) as u32 {
        if let Some(Ok(page)) = read.as_ref().map(|r| r.page(p)) {
            walk(f.decode(p, &page));
        }
        if let Ok(page) = f.page(p) {
            walk(f.decode(p, &page));
        }
    }
    let b = f.header().bounds;
    let centre = b.centre();
    let d = b.diagonal().max(1e-3);
    let mut source = PageSource::new(f, FetchOptions::default());
    for eye in [centre + glam::DVec3::new(d, 0.3 * d, 0.5 * d), centre, centre - glam::DVec3::new(0.0, d, 0.0)] {
        let look = centre + glam::DVec3::new(0.1 * d, 0.0, 0.0);
        if let Ok(camera) = relief_core::camera::Camera::new(eye, look, glam::DVec3::Y, 60.0, 64, 64) {
            let _ = source.update(&camera, 1.0).map(|_| source.triangles().len());
        }
    }
});

fn walk(view: relief_core::Result<relief_core::format::pagefile::PageView<'_>>) {
    if let Ok(v) = view {
        let mut out = Vec::new();
        v.append_triangles(&mut out);
        for i in 0..v.vertices() {
            let _ = (v.normal(i), v.colour(i));
        }
    }
}

/// The tables checksum (header bytes 152..160: XXH3-64 of bytes 256 .. refs offset + refs × 4,
/// when those fields name a range inside the input), then the header checksum over 0..248.
fn stamp(data: &[u8]) -> Vec<u8> {
    let mut bytes = data.to_vec();
    if bytes.len() >= 256 {
        let u64_at = |b: &[u8], at: usize| u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"));
        let end = u64_at(&bytes, 80).checked_mul(4).and_then(|r| r.checked_add(u64_at(&bytes, 88)));
        if let Some(end) = end.filter(|&e| e >= 256 && e <= bytes.len() as u64) {
            let sum = xxhash_rust::xxh3::xxh3_64(&bytes[256..end as usize]);
            bytes[152..160].copy_from_slice(&sum.to_le_bytes());
        }
    }
    common::with_header_checksum(&bytes)
}
