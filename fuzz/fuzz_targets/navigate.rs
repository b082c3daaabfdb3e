//! Navigation over a meta-node file: what `relief mesh fly` does with the body of the file once
//! the header and table are validated. Opens it, starts a navigator over the map (Virt) and over
//! the buffer pool (Ext), both through the file's pager, and adapts each to three views of the header's bounding box (far,
//! close, inside): splits and collapses follow the blocks' cross-block links. The header
//! checksum is stamped on the input first (see `common::with_header_checksum`).
#![no_main]
use glam::DVec3;
use libfuzzer_sys::fuzz_target;
use relief_core::format::metanode::MetaNodeFile;
use relief_core::metanode::navigate::{MetaStore, NavOptions, Navigator, PagedStore};
use relief_core::pager::Access;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let (_dir, path) = common::input_file("in.rmn", &common::with_header_checksum(data));
    let Ok(f) = MetaNodeFile::open(&path) else { return };
    let cameras = cameras(&f);
    let options = NavOptions { check_foldover: true, ..NavOptions::default() };
    if let Ok(nav) = Navigator::new(&f, PagedStore::new(&f), options) {
        fly(nav, &cameras);
    }
    let bytes = (f.mnt().len().min(64) as u64 + 5) * f.header().holder_bytes;
    if let Ok(pooled) = MetaNodeFile::open_with(&path, Access::Pool { bytes }) {
        if let Ok(nav) = Navigator::new(&pooled, PagedStore::new(&pooled), options) {
            fly(nav, &cameras);
        }
    }
});

fn cameras(f: &MetaNodeFile) -> Vec<relief_core::camera::Camera> {
    let b = f.header().bounds;
    let (lo, hi) = (DVec3::from(b.min), DVec3::from(b.max));
    let centre = (lo + hi) / 2.0;
    let size = (hi - lo).length().max(1e-6);
    let eyes = [centre + DVec3::new(0.3, -1.0, 0.6) * 2.0 * size, centre + DVec3::new(0.1, -0.2, 0.1) * size, centre];
    let looks = [centre, centre, centre + DVec3::new(0.0, 1.0, 0.0) * size];
    eyes.iter()
        .zip(looks)
        .filter_map(|(&eye, look)| relief_core::camera::Camera::new(eye, look, DVec3::Z, 60.0, 320, 200).ok())
        .collect()
}

fn fly<S: MetaStore>(mut nav: Navigator<S>, cameras: &[relief_core::camera::Camera]) {
    for camera in cameras.iter().chain(cameras.iter().rev()) {
        if nav.update(camera, 1.0).is_err() {
            return;
        }
        let _ = (nav.triangle_count(), nav.active_nodes(), nav.coexistence_violations());
    }
    let _ = nav.check();
}
