//! Gathering heights into GPU tiles (`render::heights::fill_tile`): the one pass over the whole
//! terrain the renderer makes, at start-up. The real Zurich DEM (513², 25 m; ../shared/data/dem)
//! per layout, in 64-post tiles (81 of them) so every layout's index arithmetic is exercised;
//! throughput in posts.

use std::hint::black_box;
use std::path::Path;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use relief::format::terrain::TerrainFile;
use relief::layout::LayoutKind;
use relief::preprocess::convert::{convert, ConvertOptions};
use relief::render::heights::{fill_tile, HeightTiling};
use relief::sys::progress::Progress;

fn bench(c: &mut Criterion) {
    let dem = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/dem/zurich_25m_i16.tif");
    let dir = tempfile::tempdir().expect("temp dir");
    let mut group = c.benchmark_group("fill_tile");
    group.sample_size(20);
    for kind in LayoutKind::ALL {
        let out = dir.path().join(format!("zurich.{}.relief", kind.name()));
        let mut opts = ConvertOptions::new(kind);
        opts.progress = Progress::hidden();
        convert(&dem, &out, &opts).expect("convert the Zurich DEM");
        let file = TerrainFile::open(&out).expect("open");
        let tiling = HeightTiling::with_tile(file.grid().size(), 64);
        let records = file.mapped_records().expect("a mapped terrain");
        let mut tile = vec![0f32; 64 * 64];
        group.throughput(Throughput::Elements(tiling.layers() as u64 * 64 * 64));
        group.bench_function(BenchmarkId::from_parameter(kind.name()), |b| {
            b.iter(|| {
                for layer in 0..tiling.layers() {
                    fill_tile(records, &file, &tiling, layer, &mut tile);
                    black_box(&tile);
                }
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
