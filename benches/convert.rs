//! Criterion benchmarks of the conversion hot loops on a SYNTHETIC 1025² height field (a sum of
//! sines, generated in memory so the numbers do not depend on any reader):
//! - `bounds`: nested error and radius for every vertex (preprocess::compute_bounds),
//! - `fill`: void filling with 10% of the samples void in 8×8 blocks,
//! - `checksum`: XXH3 over the payload bytes.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use relief_core::format::terrain::{payload_checksum, Record};
use relief_core::layout::hierarchy::Grid;
use relief_core::preprocess::compute_bounds;
use relief_core::preprocess::fill;

fn synthetic(grid: Grid) -> Vec<Record> {
    let s = grid.size();
    (0..s)
        .flat_map(|y| (0..s).map(move |x| (x, y)))
        .map(|(x, y)| {
            let (fx, fy) = (x as f32 * 0.013, y as f32 * 0.017);
            Record {
                z: 300.0 * (fx.sin() + (fy * 1.7).cos()) + 20.0 * (fx * 9.0).sin() * (fy * 7.0).cos(),
                error: 0.0,
                radius: 0.0,
            }
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let grid = Grid::new(10).unwrap();
    let base = synthetic(grid);
    let n = grid.vertices();

    let mut g = c.benchmark_group("convert");
    g.sample_size(10);
    g.throughput(Throughput::Elements(n));
    g.bench_function(BenchmarkId::new("bounds", grid.size()), |b| {
        let z: Vec<f32> = base.iter().map(|r| r.z).collect();
        let mut bounds = vec![[0.0f32; 2]; z.len()];
        b.iter(|| {
            compute_bounds(grid, [10.0, 10.0], &z, [grid.size(), grid.size()], &mut bounds, &|_| {}, &|| Ok(()))
                .unwrap()
        })
    });
    let side = grid.size() as usize;
    g.bench_function(BenchmarkId::new("fill_10pct_void", grid.size()), |b| {
        b.iter_batched_ref(
            || {
                let mut z: Vec<f32> = base.iter().map(|r| r.z).collect();
                for (i, v) in z.iter_mut().enumerate() {
                    let (x, y) = (i % side, i / side);
                    if (x / 8 + y / 8 * 7) % 10 == 3 {
                        *v = f32::NAN;
                    }
                }
                (z, vec![[0.0f32; 2]; side * side])
            },
            |(z, acc)| fill::fill_voids(z, acc, side, side, side),
            criterion::BatchSize::LargeInput,
        )
    });
    let bytes: &[u8] = bytemuck::cast_slice(&base);
    g.throughput(Throughput::Bytes(bytes.len() as u64));
    g.bench_function(BenchmarkId::new("checksum", grid.size()), |b| {
        b.iter(|| payload_checksum(std::hint::black_box(bytes)))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
