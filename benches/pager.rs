//! The pager's costs: an LRU touch on a random page trace, and one refinement of the real Zürich
//! DEM (513², ../shared/data/dem; interleaved, low oblique 1920 × 1080 view) read three ways: the
//! plain record slice, `MappedRecords<NoTrace>` (instrumentation off: must cost the same) and
//! `MappedRecords<&LruTrace>` (every read charged to the LRU model).

use std::hint::black_box;
use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use glam::DVec3;
use relief_core::camera::Camera;
use relief_core::format::terrain::TerrainFile;
use relief_core::layout::LayoutKind;
use relief_core::pager::{LruCache, LruTrace, NoTrace, PageGeometry};
use relief_core::preprocess::convert::{convert, ConvertOptions};
use relief_core::refine::MappedRecords;
use relief_core::refine::{RefineOptions, Refiner, Strip};

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("pager");
    group.sample_size(20);

    // LRU: 1M touches over 4096 distinct pages with a 1024-page cache (xorshift trace).
    let mut seed = 0x2545f4914f6cdd1du64;
    let trace: Vec<u64> = (0..1_000_000)
        .map(|_| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed % 4096
        })
        .collect();
    group.throughput(Throughput::Elements(trace.len() as u64));
    group.bench_function("lru_touch", |b| {
        b.iter(|| {
            let mut cache = LruCache::with_pages(1024);
            for &p in &trace {
                black_box(cache.touch(p));
            }
            cache.stats().misses
        })
    });

    let dem = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/dem/zurich_25m_i16.tif");
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("zurich.relief");
    convert(&dem, &out, &ConvertOptions::new(LayoutKind::Interleaved)).expect("convert");
    let file = TerrainFile::open(&out).expect("open");
    let [ex, ey] = file.header().extent_m();
    let camera = Camera::new(
        DVec3::new(0.5 * ex, 0.05 * ey, file.header().z_max + 0.02 * ex),
        DVec3::new(0.5 * ex, 0.6 * ey, file.header().z_min),
        DVec3::Z,
        60.0,
        1920,
        1080,
    )
    .expect("camera");
    let options = RefineOptions::default();
    let geometry = PageGeometry::new(4096).expect("page size");
    let offset = file.header().payload_offset;
    let mut refiner = Refiner::new(1).expect("refiner");
    let mut strip = Strip::new();
    let counters = refiner.refine_file_counted(&file, &camera, &options, &mut strip).unwrap();
    group.throughput(Throughput::Elements(counters.visited));
    group.bench_function("refine_plain", |b| {
        b.iter(|| refiner.refine_file(&file, &camera, &options, &mut strip).unwrap())
    });
    let records = file.mapped_records().expect("a mapped terrain");
    let untraced = MappedRecords::new(records, offset, NoTrace);
    group.bench_function("refine_notrace", |b| {
        b.iter(|| refiner.refine_source(&file, &untraced, &camera, &options, &mut strip))
    });
    let lru = LruTrace::new(LruCache::with_pages(48), geometry);
    let traced = MappedRecords::new(records, offset, &lru);
    group.bench_function("refine_lru", |b| {
        b.iter(|| refiner.refine_source(&file, &traced, &camera, &options, &mut strip))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
