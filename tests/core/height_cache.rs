//! The height cache's CPU side on a real DEM, without a GPU: what it hands the renderer is the
//! file's heights at the right slots, it never holds more tiles than its slots, keeps what the
//! newest strip wants first, settles with every blend finished, and reads through every access.

use std::sync::Arc;

use glam::DVec3;
use relief_core::camera::Camera;
use relief_core::format::terrain::TerrainFile;
use relief_core::heightcache::{CacheBudget, HeightCache, WantView, TABLE_HEADER};
use relief_core::layout::LayoutKind;
use relief_core::pager::Access;
use relief_core::preprocess::convert::{convert, ConvertOptions};
use relief_core::refine::{RefineOptions, Refiner, Strip};

use crate::common;

/// Steps the cache as a render thread would, checking each upload against the file, until it has
/// settled; returns the number of frames.
fn settle(cache: &mut HeightCache, t: &TerrainFile) -> usize {
    let side = cache.grid().slot_posts();
    let grid = cache.grid().clone();
    let slots = cache.slots();
    for frame in 0..10_000 {
        let (uploads, table) = cache.frame().unwrap();
        let uploads: Vec<(u32, Vec<f32>)> = uploads.iter().map(|u| (u.slot, u.texels.to_vec())).collect();
        if let Some(table) = table {
            // The header is the grid's; resident entries point at distinct slots.
            assert_eq!(&table[..TABLE_HEADER as usize], &grid.header()[..]);
            let mut used = vec![false; slots as usize];
            for &e in &table[TABLE_HEADER as usize..] {
                if e != 0 {
                    let slot = (e & 0xff_ffff) as usize - 1;
                    assert!(!std::mem::replace(&mut used[slot], true), "slot {slot} named twice");
                }
            }
        }
        // Each uploaded slot holds the file's heights of the tile placed in it, every texel.
        for (slot, heights) in &uploads {
            assert!(*slot < slots);
            let key = cache.slot_keys()[*slot as usize].expect("an uploaded slot holds a tile");
            for j in 0..side {
                for i in 0..side {
                    let (x, y) = grid.texel_post(key, i, j);
                    assert_eq!(heights[(j * side + i) as usize], t.height_at(x, y).unwrap());
                }
            }
        }
        cache.uploaded();
        if cache.converged() {
            return frame;
        }
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    panic!("the cache did not settle");
}

#[test]
fn the_cache_pages_the_file_heights_within_its_slots() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("z.relief");
    convert(&common::dem("zurich_25m_i16.tif"), &out, &ConvertOptions::new(LayoutKind::Hz)).unwrap();
    for access in [Access::Map, Access::Read] {
        let t = Arc::new(TerrainFile::open_with(&out, access).unwrap());
        let cam = Camera::new(
            DVec3::new(2000.0, -1500.0, 1500.0),
            DVec3::new(5000.0, 4500.0, 500.0),
            DVec3::Z,
            60.0,
            640,
            400,
        )
        .unwrap();
        let options = RefineOptions { tolerance_px: 1.0, ..Default::default() };
        let mut strip = Strip::new();
        Refiner::new(1).unwrap().refine_file(&t, &cam, &options, &mut strip).unwrap();
        let mut heights = Vec::new();
        relief_core::heightcache::exact_heights(&t, &strip.vertices, &mut heights).unwrap();
        for (v, m) in strip.vertices.iter().zip(&heights) {
            assert_eq!(m.z_m, t.record_at(v.x, v.y).unwrap().z);
        }
        // 12 slots of 32-cell tiles: fewer than the view wants.
        let grid = relief_core::heightcache::TileGrid::new(t.header().n, 32).unwrap();
        let budget = CacheBudget {
            gpu_bytes: 12 * grid.slot_bytes() + grid.table_bytes(),
            upload_bytes_per_frame: 3 * grid.slot_bytes() + grid.table_bytes(),
            max_slots: 2048,
        };
        let mut cache = HeightCache::new(t.clone(), 32, budget).unwrap();
        assert_eq!(cache.slots(), 12);
        assert!(cache.pool_bytes() <= budget.gpu_bytes);
        cache.want(&strip.vertices, &heights, WantView::new(&cam, t.header().spacing_m));
        let frames = settle(&mut cache, &t);
        // 12 tiles at 3 a frame: at least 4 frames, then the blends.
        assert!(frames >= 4, "settled after {frames} frames");
        let stats = cache.stats();
        assert_eq!(stats.tiles_resident, 12);
        assert!(stats.in_use_bytes <= budget.gpu_bytes);
        assert!(stats.wanted > 12 && stats.fallbacks == stats.wanted - 12, "{stats:?}");
        // Every resident tile has finished blending in.
        for (slot, key) in cache.slot_keys().iter().enumerate() {
            let e = cache.table()[(TABLE_HEADER + key.unwrap()) as usize];
            assert_eq!((e & 0xff_ffff, e >> 24), (slot as u32 + 1, 255));
        }
        // A new view elsewhere: its tiles replace the old ones (least recently wanted first),
        // the coarsest stays.
        let far = Camera::new(
            DVec3::new(9000.0, 9000.0, 1200.0),
            DVec3::new(12000.0, 12000.0, 400.0),
            DVec3::Z,
            60.0,
            640,
            400,
        )
        .unwrap();
        Refiner::new(1).unwrap().refine_file(&t, &far, &options, &mut strip).unwrap();
        relief_core::heightcache::exact_heights(&t, &strip.vertices, &mut heights).unwrap();
        let before: Vec<_> = cache.slot_keys().to_vec();
        cache.want(&strip.vertices, &heights, WantView::new(&far, t.header().spacing_m));
        settle(&mut cache, &t);
        let after = cache.slot_keys();
        let top = grid.key(grid.coarsest_level(), 0, 0);
        assert_eq!(after[0], Some(top));
        assert!(after.iter().zip(&before).filter(|(a, b)| a != b).count() > 0, "nothing was replaced");
    }
}
