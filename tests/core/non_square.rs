//! A non-square real DEM (ETOPO20, 1081 × 540 posts in a 2049² grid) stored without its padding
//! (ARCHITECTURE.md, "Padding that is never stored"): every layout's file within 1.5× of the DEM's
//! posts × 12 bytes, the DEM's heights exact, the nesting invariants as `verify` checks them, and
//! from many views — along a flyover, from beyond the data's edges, over the padding — strips that
//! are crack-free on one and two threads and identical in every layout.

use crate::common;

use relief_core::camera::Camera;
use relief_core::dem::{self, Run};
use relief_core::flight::{flyover, FlyoverOptions};
use relief_core::format::terrain::TerrainFile;
use relief_core::layout::{Layout, LayoutKind};
use relief_core::pager::Access;
use relief_core::preprocess::convert::{convert, ConvertOptions};
use relief_core::preprocess::inspect::verify;
use relief_core::refine::check::check_strip;
use relief_core::refine::metric::{Isotropic, Projected};
use relief_core::refine::{RefineOptions, Refiner, Strip, View};
use relief_core::sys::progress::Progress;

use glam::DVec3;

fn views(terrain: &TerrainFile) -> Vec<Camera> {
    let h = terrain.header();
    let [w, d] = [(h.valid_window[2] - 1) as f64 * h.spacing_m[0], (h.valid_window[3] - 1) as f64 * h.spacing_m[1]];
    let path = flyover(terrain, &FlyoverOptions::new(12)).unwrap();
    let mut cameras: Vec<Camera> = (0..12).map(|k| path.camera(k, 60.0, 1920, 1080).unwrap()).collect();
    // From beyond the east and north edges (over the padding) looking back at the data, low over
    // the data's north-east corner, and from high above the padded square's far corner.
    let looks = [
        (DVec3::new(1.05 * w, 0.5 * d, 60_000.0), DVec3::new(0.8 * w, 0.5 * d, 0.0)),
        (DVec3::new(0.5 * w, 1.2 * d, 200_000.0), DVec3::new(0.5 * w, 0.9 * d, 0.0)),
        (DVec3::new(0.99 * w, 0.99 * d, 20_000.0), DVec3::new(0.9 * w, 0.9 * d, 0.0)),
        (DVec3::new(1.8 * w, 3.5 * d, 2_000_000.0), DVec3::new(0.5 * w, 0.5 * d, 0.0)),
        (DVec3::new(1.5 * w, 0.5 * d, 5_000.0), DVec3::new(1.9 * w, 0.5 * d, 0.0)),
    ];
    for (eye, look) in looks {
        cameras.push(Camera::new(eye, look, DVec3::Z, 60.0, 1920, 1080).unwrap());
    }
    cameras
}

#[test]
fn a_non_square_real_dem_is_stored_without_its_padding_and_refines_crack_free_in_every_layout() {
    let dir = tempfile::tempdir().unwrap();
    let src = common::dem("etopo20_world.tif");
    // The DEM's heights, grid row y from the south.
    let mut source = dem::open(&src, None).unwrap();
    let (w, hgt) = (source.info().width, source.info().height);
    assert_eq!((w, hgt), (1081, 540));
    let mut want = vec![0f32; (w * hgt) as usize];
    source
        .read(&mut |run: Run<'_>| {
            let y = (hgt - 1 - run.row) as usize;
            for (k, v) in run.values.iter().enumerate() {
                want[y * w as usize + run.x0 as usize + k] = *v as f32;
            }
            Ok(())
        })
        .unwrap();
    let own_bytes = (w * hgt) as f64 * 12.0;

    let mut strips: Vec<(LayoutKind, Vec<Strip>)> = Vec::new();
    for kind in LayoutKind::ALL {
        let out = dir.path().join(format!("etopo20_{kind}.relief"));
        let report = convert(&src, &out, &ConvertOptions::new(kind)).unwrap();
        let bytes = std::fs::metadata(&out).unwrap().len();
        assert_eq!(report.file_bytes, bytes);
        assert_eq!(report.grid_size, 2049);
        let ratio = bytes as f64 / own_bytes;
        assert!(ratio <= 1.5, "{kind}: {bytes} bytes are {ratio:.3}× the DEM's posts × 12 bytes");
        for access in [Access::Map, Access::Read] {
            let terrain = TerrainFile::open_with(&out, access).unwrap();
            assert_eq!(terrain.stored_bytes(), bytes);
            assert!(terrain.header().stores_pages() && terrain.page_map().is_some());
            // Every post of the DEM as it was; the padding reads the edge.
            for y in 0..hgt {
                for x in 0..w {
                    assert_eq!(terrain.record_at(x, y).unwrap().z, want[(y * w + x) as usize], "{kind} ({x}, {y})");
                }
            }
            assert_eq!(terrain.height_at(2048, 2048).unwrap(), want[(w * hgt - 1) as usize]);
            let v = verify(&terrain, Progress::hidden()).unwrap();
            assert!(v.ok, "{kind} {access:?}: {:?}", v.problems);
        }
        let terrain = TerrainFile::open(&out).unwrap();
        let h = terrain.header().clone();
        let records = terrain.records().unwrap();
        let layout = terrain.layout().clone();
        let grid = layout.grid();
        let options = RefineOptions { tolerance_px: 0.5, ..Default::default() };
        let mut mine = Vec::new();
        for (k, camera) in views(&terrain).iter().enumerate() {
            let z = [h.z_min, h.z_max];
            let extent = h.extent_m();
            let iso = View::new(camera, &options, Isotropic, h.spacing_m, extent, z);
            let proj = View::new(camera, &options, Projected { forward: camera.forward() }, h.spacing_m, extent, z);
            for threads in [1, 2] {
                let mut refiner = Refiner::new(threads).unwrap();
                let mut strip = Strip::new();
                refiner.refine(&layout, &*records, &iso, &mut strip);
                let check = check_strip(grid, &strip, |x, y| {
                    iso.is_active(x, y, grid.level(x, y), records[layout.index(x, y) as usize])
                });
                assert!(check.crack_free, "{kind} view {k}, {threads} threads: {check:?}");
                if threads == 1 {
                    mine.push(strip);
                } else {
                    assert_eq!(strip.triangle_counts().0, mine.last().unwrap().triangle_counts().0, "{kind} view {k}");
                }
                let mut strip = Strip::new();
                refiner.refine(&layout, &*records, &proj, &mut strip);
                let check = check_strip(grid, &strip, |x, y| {
                    proj.is_active(x, y, grid.level(x, y), records[layout.index(x, y) as usize])
                });
                assert!(check.crack_free, "{kind} view {k}, projected, {threads} threads: {check:?}");
            }
        }
        let total: u64 = mine.iter().map(|s| s.triangle_counts().0).sum();
        assert!(total > 10_000, "{total} triangles over every view");
        strips.push((kind, mine));
    }
    for (kind, s) in &strips[1..] {
        for (k, (a, b)) in s.iter().zip(&strips[0].1).enumerate() {
            assert!(a.vertices == b.vertices, "{kind} view {k}: another strip than {}", strips[0].0);
        }
    }
}

/// A damaged page map, or a file cut short of its stored pages, is one line naming the file.
#[test]
fn a_damaged_page_map_is_refused_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("etopo20.relief");
    convert(&common::dem("etopo20_world.tif"), &out, &ConvertOptions::new(LayoutKind::Hz)).unwrap();
    let good = std::fs::read(&out).unwrap();
    type Damage = Box<dyn Fn(&mut Vec<u8>)>;
    let cases: [(&str, Damage, &str); 3] = [
        ("map.relief", Box::new(|b: &mut Vec<u8>| b[4096 + 20] ^= 1), "page map checksum"),
        (
            "count.relief",
            Box::new(|b: &mut Vec<u8>| b[4096 + 8..4096 + 16].copy_from_slice(&u64::MAX.to_le_bytes())),
            "runs do not fit",
        ),
        ("short.relief", Box::new(|b: &mut Vec<u8>| b.truncate(b.len() - 4096)), "truncated"),
    ];
    for (name, damage, want) in cases {
        let path = dir.path().join(name);
        let mut bytes = good.clone();
        damage(&mut bytes);
        std::fs::write(&path, &bytes).unwrap();
        for access in [Access::Map, Access::Read] {
            let e = TerrainFile::open_with(&path, access).err().unwrap().to_string();
            assert!(e.starts_with(&path.display().to_string()) && !e.contains('\n') && e.contains(want), "{e}");
        }
    }
}
