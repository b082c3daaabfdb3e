//! Imagery tile files on a real image (the Fuji Terrain-RGB tile, decoded as the colour image it
//! is, cut to an odd size): every stored texel is its level's texel at the clamped position, each
//! level the rounded mean of the one below (recomputed here), identical through every access;
//! damaged files are one-line errors; and the tile cache pages such a file within its slots,
//! following a strip over a real terrain.

use std::sync::Arc;

use glam::DVec3;
use relief_core::camera::Camera;
use relief_core::format::imagery::{write, ImageGrid, ImageryFile};
use relief_core::format::terrain::TerrainFile;
use relief_core::heightcache::{CacheBudget, ImageryTiles, TileCache, TileSet, WantView, TABLE_HEADER};
use relief_core::layout::LayoutKind;
use relief_core::pager::Access;
use relief_core::preprocess::convert::{convert, ConvertOptions};
use relief_core::refine::{RefineOptions, Refiner, Strip};
use relief_core::sys::progress::Progress;

use crate::common;

/// The real image, RGBA, cropped to `w × h` from its upper-left corner.
fn real_image(w: usize, h: usize) -> Vec<[u8; 4]> {
    let decoder =
        png::Decoder::new(std::io::BufReader::new(std::fs::File::open(common::dem("fuji_terrain_rgb.png")).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.color_type, info.bit_depth), (png::ColorType::Rgba, png::BitDepth::Eight));
    let width = info.width as usize;
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let i = 4 * (y * width + x);
            [buf[i], buf[i + 1], buf[i + 2], buf[i + 3]]
        })
        .collect()
}

/// Level `k + 1` of a level, the way the format says (rounded mean of 2 × 2, clamped).
fn halve(level: &[[u8; 4]], w: usize, h: usize) -> (Vec<[u8; 4]>, usize, usize) {
    let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
    let at = |x: usize, y: usize| level[y.min(h - 1) * w + x.min(w - 1)];
    let mut out = Vec::with_capacity(nw * nh);
    for y in 0..nh {
        for x in 0..nw {
            let q = [at(2 * x, 2 * y), at(2 * x + 1, 2 * y), at(2 * x, 2 * y + 1), at(2 * x + 1, 2 * y + 1)];
            out.push([0, 1, 2, 3].map(|c| ((q.iter().map(|p| p[c] as u32).sum::<u32>() + 2) / 4) as u8));
        }
    }
    (out, nw, nh)
}

fn unpack(t: u32) -> [u8; 4] {
    t.to_le_bytes()
}

#[test]
fn tiles_hold_every_level_with_borders_through_every_access() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fuji.rimg");
    let (w, h) = (509usize, 313usize);
    let image = real_image(w, h);
    let placement = Some([138.5, 0.001, 35.5, 0.001]);
    let r = write(&out, &image, w as u32, h as u32, placement, dir.path(), Progress::hidden()).unwrap();
    // 509 × 313 in 254-texel tiles: 3 × 2, then 255 × 157: 2 × 1, then 128 × 79: one.
    let grid = ImageGrid::new(w as u32, h as u32, 254).unwrap();
    assert_eq!((r.levels, r.tiles), (3, 9));
    assert_eq!(r.file_bytes, std::fs::metadata(&out).unwrap().len());
    assert_eq!(r.file_bytes, 4096 + 9 * 256 * 256 * 4);
    let files =
        [Access::Map, Access::Read, Access::Pool { bytes: 4 << 20 }].map(|a| ImageryFile::open(&out, a).unwrap());
    assert_eq!(files[0].header().placement, placement);
    files[0].verify().unwrap();
    let (mut level, mut lw, mut lh) = (image, w, h);
    let side = grid.slot_side() as usize;
    let mut tile = vec![0u32; side * side];
    let mut other = tile.clone();
    for k in 0..grid.levels.len() as u32 {
        let l = grid.levels[k as usize];
        assert_eq!((l.width as usize, l.height as usize), (lw, lh));
        for ty in 0..l.tiles_y {
            for tx in 0..l.tiles_x {
                let key = grid.key(k, tx, ty);
                files[0].read_tile(key, &mut tile).unwrap();
                for f in &files[1..] {
                    f.read_tile(key, &mut other).unwrap();
                    assert_eq!(tile, other, "tile {key} differs between accesses");
                }
                for j in 0..side {
                    for i in 0..side {
                        let x = (tx as i64 * 254 - 1 + i as i64).clamp(0, lw as i64 - 1) as usize;
                        let y = (ty as i64 * 254 - 1 + j as i64).clamp(0, lh as i64 - 1) as usize;
                        assert_eq!(
                            unpack(tile[j * side + i]),
                            level[y * lw + x],
                            "level {k} tile ({tx}, {ty}) texel ({i}, {j})"
                        );
                    }
                }
            }
        }
        (level, lw, lh) = halve(&level, lw, lh);
    }
    // A texel changed in the payload: the header still opens, verification names the file.
    let mut bytes = std::fs::read(&out).unwrap();
    bytes[4096 + 5 * 262_144 + 1000] ^= 0x40;
    let bad = dir.path().join("bad.rimg");
    std::fs::write(&bad, &bytes).unwrap();
    let e = ImageryFile::open(&bad, Access::Map).unwrap().verify().unwrap_err().to_string();
    assert!(e.starts_with(&format!("{}: imagery tile file: payload checksum mismatch", bad.display())), "{e}");
    // Cut short: refused at open, in one line, for every access.
    std::fs::write(&bad, &bytes[..bytes.len() - 4096]).unwrap();
    for access in [Access::Map, Access::Read] {
        let e = ImageryFile::open(&bad, access).err().unwrap().to_string();
        assert_eq!(
            e,
            format!(
                "{}: truncated imagery tile file: expected {} bytes, found {}",
                bad.display(),
                bytes.len(),
                bytes.len() - 4096
            )
        );
    }
    // The wrong number of texels for the size: refused before anything is written.
    let e = write(&dir.path().join("x.rimg"), &level, 7, 7, None, dir.path(), Progress::hidden()).unwrap_err();
    assert!(e.to_string().contains("texels for a 7 x 7 image"), "{e}");
    assert!(!dir.path().join("x.rimg").exists());
}

#[test]
fn the_imagery_cache_pages_what_a_strip_wants_within_its_slots() {
    let dir = tempfile::tempdir().unwrap();
    let terrain_path = dir.path().join("z.relief");
    convert(&common::dem("zurich_25m_i16.tif"), &terrain_path, &ConvertOptions::new(LayoutKind::Hz)).unwrap();
    let t = Arc::new(TerrainFile::open(&terrain_path).unwrap());
    // The real image stretched over the DEM's valid window, as `--imagery` without a world file.
    let (w, h) = (512usize, 512usize);
    let tiles = dir.path().join("fuji.rimg");
    write(&tiles, &real_image(w, h), w as u32, h as u32, None, dir.path(), Progress::hidden()).unwrap();
    let [_, _, x1, y1] = t.header().valid_window;
    let (sx, sy) = ((x1 - 1) as f64, (y1 - 1) as f64);
    let uv = [0.0, 1.0 / sx, 1.0, -1.0 / sy];
    let file = ImageryFile::open(&tiles, Access::Read).unwrap();
    let set = ImageryTiles { file, terrain: t.clone(), uv, wraps: false };
    let slot_bytes = set.slot_bytes();
    let grid = set.file.grid().clone();
    // Room for 4 of the image's 14 tiles (plus the table), 2 tiles uploaded a frame.
    let budget = CacheBudget {
        gpu_bytes: 4 * slot_bytes + set.table_bytes(),
        upload_bytes_per_frame: 2 * slot_bytes + set.table_bytes(),
        max_slots: 2048,
    };
    let mut cache = TileCache::of(set, budget, "imagery").unwrap();
    assert_eq!((cache.slots(), grid.tiles()), (4, 14));
    // A low oblique view over the city: it wants fine tiles near the eye.
    let cam =
        Camera::new(DVec3::new(3000.0, 2000.0, 900.0), DVec3::new(6000.0, 6000.0, 400.0), DVec3::Z, 60.0, 640, 400)
            .unwrap();
    let mut strip = Strip::new();
    Refiner::new(1)
        .unwrap()
        .refine_file(&t, &cam, &RefineOptions { tolerance_px: 1.0, ..Default::default() }, &mut strip)
        .unwrap();
    let mut heights = Vec::new();
    relief_core::heightcache::exact_heights(&t, &strip.vertices, &mut heights).unwrap();
    let view = WantView::new(&cam, t.header().spacing_m);
    cache.want(&strip.vertices, &heights, view);
    let side = grid.slot_side() as usize;
    let mut expect = vec![0u32; side * side];
    let reference = ImageryFile::open(&tiles, Access::Map).unwrap();
    let mut placed = 0;
    for _ in 0..10_000 {
        let (uploads, table) = cache.frame().unwrap();
        assert!(uploads.len() <= 2, "{} tiles in one frame, over the upload budget", uploads.len());
        let uploads: Vec<(u32, Vec<u32>)> = uploads.iter().map(|u| (u.slot, u.texels.to_vec())).collect();
        if let Some(table) = table {
            assert_eq!(&table[..TABLE_HEADER as usize], &grid.header()[..]);
            assert!(table[TABLE_HEADER as usize..].iter().filter(|&&e| e != 0).count() <= 4);
        }
        for (slot, texels) in &uploads {
            let key = cache.slot_keys()[*slot as usize].expect("an uploaded slot holds a tile");
            reference.read_tile(key, &mut expect).unwrap();
            assert_eq!(texels, &expect, "slot {slot} holds tile {key}'s texels");
            placed += 1;
        }
        let stats = cache.stats();
        assert!(stats.in_use_bytes <= budget.gpu_bytes, "{stats:?}");
        cache.uploaded();
        if cache.converged() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    assert!(cache.converged(), "the imagery cache did not settle");
    // The coarsest tile first, and at least one level-0 tile for the near ground.
    let keys: Vec<u32> = cache.slot_keys().iter().flatten().copied().collect();
    assert!(keys.contains(&(grid.tiles() - 1)), "{keys:?}");
    assert!(keys.iter().any(|&k| grid.decode(k).0 == 0), "no level-0 tile near the eye: {keys:?}");
    assert!(placed >= 4, "{placed} tiles placed");
}
