//! Render-time vertical exaggeration refines in the exaggerated scene within τ: against the same
//! real DEM converted with its heights scaled (`--z-scale x`, where errors and radii are those of
//! the exaggerated surface), the mesh refined with `z_exaggeration = x` on the unscaled file holds
//! every vertex the scaled file's mesh holds (its radii, the unscaled ones, are conservative in
//! the scene scaled by 1/x), and not many more; and it is crack-free.

use std::collections::HashSet;

use crate::common;

use glam::DVec3;
use relief_core::camera::Camera;
use relief_core::format::terrain::TerrainFile;
use relief_core::layout::LayoutKind;
use relief_core::preprocess::convert::{convert, ConvertOptions};
use relief_core::refine::check::check_strip;
use relief_core::refine::{RefineOptions, Refiner, Strip, StripVertex};

#[test]
fn an_exaggerated_scene_is_refined_within_tolerance() {
    let dir = tempfile::tempdir().unwrap();
    let src = common::dem("zurich_25m_i16.tif");
    let plain = dir.path().join("plain.relief");
    convert(&src, &plain, &ConvertOptions::new(LayoutKind::Hz)).unwrap();
    let plain = TerrainFile::open(&plain).unwrap();
    let mut refiner = Refiner::new(1).unwrap();
    for x in [2.0, 5.0] {
        let tall = dir.path().join(format!("tall_{x}.relief"));
        convert(&src, &tall, &ConvertOptions { z_scale: x, ..ConvertOptions::new(LayoutKind::Hz) }).unwrap();
        let tall = TerrainFile::open(&tall).unwrap();
        // Cameras in the exaggerated scene (metres, heights x times as high).
        let views = [
            (DVec3::new(2000.0, -1500.0, 1500.0 * x), DVec3::new(5000.0, 4500.0, 500.0 * x)),
            (DVec3::new(9000.0, 9000.0, 1200.0 * x), DVec3::new(4000.0, 4000.0, 400.0 * x)),
            (DVec3::new(5000.0, 4500.0, 900.0 * x), DVec3::new(7000.0, 2000.0, 450.0 * x)),
        ];
        for (k, (eye, look)) in views.into_iter().enumerate() {
            let camera = Camera::new(eye, look, DVec3::Z, 60.0, 1280, 720).unwrap();
            let mut want = Strip::new();
            refiner.refine_file(&tall, &camera, &RefineOptions::default(), &mut want).unwrap();
            let mut got = Strip::new();
            let options = RefineOptions { z_exaggeration: x, ..Default::default() };
            refiner.refine_file(&plain, &camera, &options, &mut got).unwrap();
            let have: HashSet<StripVertex> = got.vertices.iter().copied().collect();
            let missing = want.vertices.iter().filter(|v| !have.contains(v)).count();
            assert_eq!(missing, 0, "x {x}, view {k}: vertices of the scaled file's mesh missing");
            let (a, b) = (got.triangle_counts().0, want.triangle_counts().0);
            assert!(b > 1000 && (a as f64) < 1.5 * b as f64, "x {x}, view {k}: {a} triangles against {b}");
            eprintln!("x {x}, view {k}: {a} triangles exaggerated, {b} from the scaled file");
            let check = check_strip(plain.grid(), &got, |_, _| false);
            assert!(check.crack_free, "x {x}, view {k}: {check:?}");
        }
    }
}
