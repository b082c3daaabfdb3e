//! Refinement checks shared by the refinement and edge-case tests: a deterministic generator,
//! random cameras and options, conversion into every layout, and the crack-free check.

use std::collections::HashSet;
use std::path::Path;

use glam::DVec3;
use relief::camera::Camera;
use relief::format::terrain::TerrainFile;
use relief::layout::LayoutKind;
use relief::preprocess::convert::{convert, ConvertOptions};
use relief::refine::metric::MetricKind;
use relief::refine::report::{refine_report, ReportOptions};
use relief::refine::{mesh_triangles, RefineOptions, Refiner, Strip, StripVertex};

/// SplitMix64: a small deterministic generator, so failures replay.
pub struct Rng(pub u64);
impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    pub fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
    pub fn direction(&mut self) -> DVec3 {
        loop {
            let v = DVec3::new(self.range(-1.0, 1.0), self.range(-1.0, 1.0), self.range(-1.0, 1.0));
            if v.length_squared() > 1e-3 && v.length_squared() <= 1.0 {
                return v.normalize();
            }
        }
    }
}

/// A random camera above, inside (between the lowest and highest ground, often underground) or
/// outside the terrain, looking anywhere.
pub fn random_camera(rng: &mut Rng, terrain: &TerrainFile) -> Camera {
    let h = terrain.header();
    let [ex, ey] = h.extent_m();
    let size = ex.max(ey);
    let (zmin, zmax) = (h.z_min, h.z_max);
    let eye = match rng.next() % 3 {
        0 => DVec3::new(rng.range(0.0, ex), rng.range(0.0, ey), zmax + rng.range(0.0, 0.5 * size)),
        1 => DVec3::new(rng.range(0.0, ex), rng.range(0.0, ey), rng.range(zmin, zmax)),
        _ => DVec3::new(
            rng.range(-2.0 * ex, 3.0 * ex),
            rng.range(-2.0 * ey, 3.0 * ey),
            rng.range(zmin - size, zmax + size),
        ),
    };
    let dir = rng.direction();
    let up = if dir.z.abs() > 0.99 { DVec3::Y } else { DVec3::Z };
    let width = 64 + (rng.next() % 1985) as u32;
    let height = 48 + (rng.next() % 1033) as u32;
    Camera::new(eye, eye + dir * size, up, rng.range(20.0, 120.0), width, height).unwrap()
}

pub fn random_options(rng: &mut Rng) -> RefineOptions {
    RefineOptions {
        tolerance_px: 2f64.powf(rng.range(-1.0, 3.0)),
        metric: if rng.next().is_multiple_of(2) { MetricKind::Isotropic } else { MetricKind::Projected },
        cull: !rng.next().is_multiple_of(4),
        morph_ratio: None,
        heights: false,
        // Now and then an exaggerated scene (refined at eye / x over posts x times closer).
        z_exaggeration: if rng.next().is_multiple_of(3) { rng.range(1.0, 6.0) } else { 1.0 },
    }
}

/// Converts `input` into every layout in `dir`.
pub fn convert_all(input: &Path, dir: &Path, tag: &str) -> Vec<TerrainFile> {
    LayoutKind::ALL
        .iter()
        .map(|&kind| {
            let out = dir.join(format!("{tag}.{kind}.relief"));
            convert(input, &out, &ConvertOptions::new(kind)).unwrap_or_else(|e| panic!("{tag} {kind}: {e}"));
            TerrainFile::open(&out).unwrap()
        })
        .collect()
}

pub fn check(
    terrain: &TerrainFile,
    camera: &Camera,
    options: &RefineOptions,
    strip: &Strip,
) -> relief::refine::check::MeshCheck {
    let report = ReportOptions { threads: 1, repeat: 1, check: true, compare_minimal: false };
    let (r, s) = refine_report(terrain, camera, options, &report).unwrap();
    assert_eq!(&s.vertices, &strip.vertices, "report refines the same strip");
    r.check.unwrap()
}

pub fn vertex_set(strip: &Strip) -> HashSet<StripVertex> {
    strip.vertices.iter().copied().collect()
}

/// Inserted vertices (corners excluded) of a strip's mesh.
pub fn inserted(strip: &Strip, terrain: &TerrainFile) -> Vec<(u32, u32)> {
    let m = terrain.grid().max_coord();
    let mut v: Vec<(u32, u32)> = vertex_set(strip)
        .into_iter()
        .filter(|v| !((v.x == 0 || v.x == m) && (v.y == 0 || v.y == m)))
        .map(|v| (v.x, v.y))
        .collect();
    v.sort();
    v
}

/// For each camera: every layout gives the identical strip, and it decodes into a conforming mesh
/// that is exactly the refinement of the active set.
pub fn crack_free_everywhere(files: &[TerrainFile], cameras: usize, seed: u64, min_mean_triangles: u64) {
    let mut rng = Rng(seed);
    let mut refiner = Refiner::new(1).unwrap();
    let mut strips: Vec<Strip> = files.iter().map(|_| Strip::new()).collect();
    let mut total_triangles = 0u64;
    for k in 0..cameras {
        let camera = random_camera(&mut rng, &files[0]);
        let options = random_options(&mut rng);
        for (f, s) in files.iter().zip(strips.iter_mut()) {
            refiner.refine_file(f, &camera, &options, s).unwrap();
        }
        for (f, s) in files.iter().zip(&strips).skip(1) {
            assert_eq!(
                s.vertices,
                strips[0].vertices,
                "camera {k}: {} differs from {}",
                f.header().layout.name(),
                files[0].header().layout.name()
            );
        }
        let c = check(&files[0], &camera, &options, &strips[0]);
        assert!(c.crack_free && c.inactive_vertices == 0, "camera {k} {camera:?} {options:?}: {c:?}");
        // The strip's triangles are exactly those of the active vertex set.
        assert_eq!(c.triangles, mesh_triangles(files[0].grid(), inserted(&strips[0], &files[0])), "camera {k}");
        total_triangles += c.triangles;
    }
    assert!(
        total_triangles > min_mean_triangles * cameras as u64,
        "cameras mostly see real meshes ({total_triangles} triangles)"
    );
}
