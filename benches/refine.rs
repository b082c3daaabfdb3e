//! The refinement loop: one view of the real Zurich DEM (513², 25 m; ../shared/data/dem) refined
//! into a strip, per layout, culled and unculled, and unculled with 2 threads. Throughput is in strip
//! triangles (non-degenerate), so criterion reports triangles per second.
//!
//! `RELIEF_BENCH_TERRAIN=file.relief` benchmarks an existing terrain file (e.g. a converted
//! SYNTHETIC 16385² grid) with a low-altitude view across it instead.

use std::hint::black_box;
use std::path::Path;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::DVec3;
use relief_core::camera::Camera;
use relief_core::format::terrain::TerrainFile;
use relief_core::layout::LayoutKind;
use relief_core::preprocess::convert::{convert, ConvertOptions};
use relief_core::refine::{RefineOptions, Refiner, Strip};

/// A low oblique view from the south edge across the terrain, 1920 × 1080, 60°.
fn view(file: &TerrainFile) -> Camera {
    let h = file.header();
    let [ex, ey] = h.extent_m();
    let eye = DVec3::new(0.5 * ex, 0.05 * ey, h.z_max + 0.02 * ex.max(ey));
    let look = DVec3::new(0.5 * ex, 0.6 * ey, h.z_min);
    Camera::new(eye, look, DVec3::Z, 60.0, 1920, 1080).expect("valid camera")
}

fn bench_file(c: &mut Criterion, group_name: &str, file: &TerrainFile) {
    let camera = view(file);
    let mut group = c.benchmark_group(group_name);
    group.sample_size(20);
    let layout = file.header().layout.name();
    // Two threads on the unculled view: about 4·10⁴ triangles, above the strip length from which
    // the refiner uses its pool (the culled view's 10⁴ triangles stay on one thread).
    for (label, cull, threads) in [("cull", true, 1), ("nocull", false, 1), ("nocull-2threads", false, 2)] {
        let options = RefineOptions { cull, ..RefineOptions::default() };
        let mut refiner = Refiner::new(threads).expect("thread pool");
        let mut strip = Strip::new();
        refiner.refine_file(file, &camera, &options, &mut strip).unwrap();
        let (triangles, _) = strip.triangle_counts();
        group.throughput(Throughput::Elements(triangles));
        group.bench_function(BenchmarkId::new(label, layout), |b| {
            b.iter(|| {
                refiner.refine_file(file, &camera, &options, &mut strip).unwrap();
                black_box(&strip);
            })
        });
    }
    group.finish();
}

fn refine(c: &mut Criterion) {
    if let Some(path) = std::env::var_os("RELIEF_BENCH_TERRAIN") {
        let file = TerrainFile::open(Path::new(&path)).expect("RELIEF_BENCH_TERRAIN opens");
        bench_file(c, "refine-file", &file);
        return;
    }
    let dem = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/dem/zurich_25m_i16.tif");
    let dir = tempfile::tempdir().expect("temp dir");
    for kind in LayoutKind::ALL {
        let out = dir.path().join(format!("zurich.{kind}.relief"));
        convert(&dem, &out, &ConvertOptions::new(kind)).expect("zurich converts");
        let file = TerrainFile::open(&out).expect("opens");
        bench_file(c, "refine-zurich", &file);
    }
}

criterion_group!(benches, refine);
criterion_main!(benches);
