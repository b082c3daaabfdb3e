//! Every backend reads only through its file's pager: each is flown along one path over every
//! access it supports (the map, positioned reads, the buffer pool) through the one frame
//! protocol, and the frames are identical (the same strip, the same triangles). The pager's
//! observer sees what each access reads.

use crate::common;

use std::sync::Arc;

use relief_core::camera::{Camera, UpAxis};
use relief_core::diskpages::build::{build_page_file, PageBuildOptions};
use relief_core::diskpages::fetch::{FetchOptions, PageSource};
use relief_core::flight::frame::{Frame, FrameSource};
use relief_core::flight::terrain::TerrainSource;
use relief_core::flight::{flyover, orbit_box, FlyoverOptions, OrbitOptions};
use relief_core::format::metanode::MetaNodeFile;
use relief_core::format::pagefile::{PageFile, PageLayout};
use relief_core::format::terrain::TerrainFile;
use relief_core::layout::LayoutKind;
use relief_core::mesh::read_mesh;
use relief_core::metanode::blocking::BlockingOptions;
use relief_core::metanode::build::BuildOptions;
use relief_core::metanode::navigate::{NavOptions, Navigator, PagedStore, Prefetch};
use relief_core::metanode::source::NavSource;
use relief_core::metanode::VdtMetric;
use relief_core::pager::{Access, LruCache, LruTrace, PageGeometry};
use relief_core::preprocess::convert::{convert, ConvertOptions};
use relief_core::refine::RefineOptions;

/// What a frame drew, comparable across accesses: a strip's vertices, or a mesh's triangles as
/// their corners' bits.
#[derive(Debug, PartialEq)]
enum Drawn {
    Strip(Vec<(u32, u32)>),
    Triangles(Vec<[[u32; 3]; 3]>),
}

fn drawn(frame: Frame<'_>, sort: bool) -> Drawn {
    match frame {
        Frame::Strip(s) => Drawn::Strip(s.vertices.iter().map(|v| (v.x, v.y)).collect()),
        Frame::Triangles(t) => {
            let mut tris: Vec<[[u32; 3]; 3]> =
                t.chunks_exact(3).map(|c| [c[0], c[1], c[2]].map(|p| p.map(f32::to_bits))).collect();
            if sort {
                tris.sort_unstable();
            }
            Drawn::Triangles(tris)
        }
    }
}

const ACCESSES: [Access; 3] = [Access::Map, Access::Read, Access::Pool { bytes: 1 << 20 }];

/// An observer on the pager that must see reads (misses of a small model) whatever the access.
fn observe(pager: &relief_core::pager::Pager) -> Arc<LruTrace> {
    let g = PageGeometry::new(4096).unwrap();
    let trace = Arc::new(LruTrace::new(LruCache::with_pages(16), g));
    pager.observe(trace.clone()).unwrap();
    trace
}

#[test]
fn the_terrain_refines_the_same_strips_through_every_access() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("zurich.relief");
    convert(&common::dem("zurich_25m_i16.tif"), &out, &ConvertOptions::new(LayoutKind::Interleaved)).unwrap();
    let path = flyover(&TerrainFile::open(&out).unwrap(), &FlyoverOptions::new(24)).unwrap();
    let cameras: Vec<Camera> = (0..24).map(|k| path.camera(k, 60.0, 640, 360).unwrap()).collect();
    let options = RefineOptions { tolerance_px: 1.0, ..Default::default() };
    let mut flights = Vec::new();
    for access in ACCESSES {
        let terrain = Arc::new(TerrainFile::open_with(&out, access).unwrap());
        let trace = observe(terrain.pager());
        let mut source = TerrainSource::new(terrain.clone(), options, 1, false).unwrap();
        let frames: Vec<Drawn> = cameras
            .iter()
            .map(|c| {
                let s = source.update(c, 1.0).unwrap();
                assert!(s.changed && s.triangles > 100, "{access:?}: {s:?}");
                drawn(source.frame(), false)
            })
            .collect();
        let reads = terrain.pager().reads();
        match access {
            // The map reads nothing itself; reads and the pool read blocks of 1,024 records.
            Access::Map => assert_eq!(reads.blocks, 0),
            _ => assert!(reads.blocks > 0 && reads.bytes == reads.blocks * 12_288, "{access:?}: {reads:?}"),
        }
        assert!(trace.stats().misses > 0, "{access:?}: the observer saw no reads");
        flights.push((access, frames));
    }
    for (access, frames) in &flights[1..] {
        assert_eq!(frames, &flights[0].1, "{access:?} refined other strips than the map");
    }
}

#[test]
fn meta_node_trees_navigate_to_the_same_triangles_through_every_access() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bunny.rmn");
    let mesh = read_mesh(&common::mesh("bunny.off")).unwrap();
    relief_core::metanode::build_tree(
        mesh,
        &out,
        None,
        &BuildOptions::new(1 << 32, VdtMetric::Length),
        BlockingOptions::default(),
    )
    .unwrap();
    let tree = MetaNodeFile::open(&out).unwrap();
    let b = tree.header().bounds;
    let cameras: Vec<Camera> = {
        let path = orbit_box(&b, UpAxis::Y, &OrbitOptions::new(12)).unwrap();
        (0..12).map(|k| path.camera_with_up(k, UpAxis::Y, 60.0, 640, 360).unwrap()).collect()
    };
    // Room for the whole tree in the pool: once its loads are in, nothing misses.
    let pool = Access::Pool { bytes: (tree.header().metanodes + 8) * tree.header().holder_bytes };
    let mut flights = Vec::new();
    for access in [Access::Map, Access::Read, pool] {
        let file = MetaNodeFile::open_with(&out, access).unwrap();
        let trace = observe(file.pager());
        let options = NavOptions { prefetch: Prefetch::Frontier, ..NavOptions::default() };
        let mut source = NavSource::new(Navigator::new(&file, PagedStore::new(&file), options).unwrap());
        let mut frames = Vec::new();
        for c in &cameras {
            // With the pool a frame may miss blocks still loading: adapt again once they are in
            // (the loads of a frame are what the I/O thread was asked for while it ran).
            let mut s = source.update(c, 2.0).unwrap();
            if let Some(p) = file.pager().pool() {
                for _ in 0..64 {
                    if s.misses == 0 {
                        break;
                    }
                    p.drain().unwrap();
                    s = source.update(c, 2.0).unwrap();
                }
            }
            assert_eq!(s.misses, 0, "{access:?}: misses left with the whole tree in memory");
            frames.push(drawn(source.frame(), true));
        }
        assert!(trace.stats().misses > 0, "{access:?}: the observer saw no reads");
        flights.push((access, frames));
    }
    for (access, frames) in &flights[1..] {
        assert_eq!(frames, &flights[0].1, "{access:?} drew other triangles than the map");
    }
}

#[test]
fn disk_pages_fetch_the_same_triangles_through_every_access() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bunny.rpg");
    let mesh = read_mesh(&common::mesh("bunny.off")).unwrap();
    build_page_file(&mesh, &out, &PageBuildOptions::new(4096, PageLayout::TwoFactor)).unwrap();
    let b = PageFile::open(&out).unwrap().header().bounds;
    let path = orbit_box(&b, UpAxis::Y, &OrbitOptions::new(12)).unwrap();
    let cameras: Vec<Camera> = (0..12).map(|k| path.camera_with_up(k, UpAxis::Y, 60.0, 640, 360).unwrap()).collect();
    let mut flights = Vec::new();
    // A pool smaller than the file: pages are evicted and read again, the frames stay the same.
    for access in [Access::Read, Access::Map, Access::Pool { bytes: 64 * 4096 }] {
        let file = PageFile::open_with(&out, access).unwrap();
        let trace = observe(file.pager());
        let mut source = PageSource::new(file, FetchOptions::default());
        let frames: Vec<Drawn> = cameras
            .iter()
            .map(|c| {
                let s = source.update(c, 1.0).unwrap();
                assert!(s.pages_requested > 0 && s.triangles > 0, "{access:?}: {s:?}");
                drawn(source.frame(), false)
            })
            .collect();
        assert!(trace.stats().misses > 0, "{access:?}: the observer saw no reads");
        flights.push((access, frames));
    }
    for (access, frames) in &flights[1..] {
        assert_eq!(frames, &flights[0].1, "{access:?} fetched other triangles than positioned reads");
    }
}
