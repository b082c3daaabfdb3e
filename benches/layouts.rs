//! Throughput of the layouts' hot functions on a 4097² grid (n = 12): `index`, `coords` and
//! `split_children`, each over a fixed pseudo-random sample of 65536 inputs.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use relief_core::layout::hierarchy::{split_children, Grid};
use relief_core::layout::{Embedded, Hz, Interleaved, Layout, RowMajor, Tiled, Vertex};

const N: u32 = 12;
const SAMPLES: usize = 65536;

/// xorshift64*: a fixed, dependency-free pseudo-random sequence.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

fn positions(g: Grid) -> Vec<(u32, u32)> {
    let mut rng = Rng(0x1234_5678_9ABC_DEF1);
    let s = g.size() as u64;
    (0..SAMPLES).map(|_| (rng.below(s) as u32, rng.below(s) as u32)).collect()
}

/// Valid refinement steps: a split vertex above level 1 (not the centre) and one of its DAG
/// parents as apex.
fn pairs(g: Grid) -> Vec<((u32, u32), (u32, u32))> {
    let mut rng = Rng(0x0F1E_2D3C_4B5A_6978);
    let s = g.size() as u64;
    let mut out = Vec::with_capacity(SAMPLES);
    while out.len() < SAMPLES {
        let (x, y) = (rng.below(s) as u32, rng.below(s) as u32);
        let l = g.level(x, y);
        if l <= 1 || l >= g.levels() {
            continue;
        }
        let (ps, np) = g.dag_parents(x, y);
        out.push((ps[rng.below(np as u64) as usize], (x, y)));
    }
    out
}

fn bench_layout<L: Layout>(c: &mut Criterion, name: &str, layout: L) {
    let g = layout.grid();
    let pos = positions(g);
    let idx: Vec<u64> = pos.iter().map(|&(x, y)| layout.index(x, y)).collect();
    let steps: Vec<(Vertex, Vertex)> =
        pairs(g).into_iter().map(|(a, s)| (layout.vertex(a.0, a.1), layout.vertex(s.0, s.1))).collect();
    // Make sure the sample is valid before timing it.
    for &(a, s) in &steps[..1000] {
        let want = split_children((a.x, a.y), (s.x, s.y)).map(|(x, y)| layout.vertex(x, y));
        assert_eq!(layout.split_children(a, s), want);
    }

    let mut group = c.benchmark_group("layout");
    group.throughput(Throughput::Elements(SAMPLES as u64));
    group.bench_function(BenchmarkId::new("index", name), |b| {
        b.iter(|| {
            let l = black_box(&layout);
            let mut acc = 0u64;
            for &(x, y) in &pos {
                acc = acc.wrapping_add(l.index(black_box(x), black_box(y)));
            }
            acc
        })
    });
    group.bench_function(BenchmarkId::new("coords", name), |b| {
        b.iter(|| {
            let l = black_box(&layout);
            let mut acc = 0u32;
            for &i in &idx {
                if let Some((x, y)) = l.coords(black_box(i)) {
                    acc = acc.wrapping_add(x ^ y);
                }
            }
            acc
        })
    });
    group.bench_function(BenchmarkId::new("split_children", name), |b| {
        b.iter(|| {
            let l = black_box(&layout);
            let mut acc = 0u64;
            for &(a, s) in &steps {
                let [p, q] = l.split_children(black_box(a), black_box(s));
                acc = acc.wrapping_add(p.index ^ q.index);
            }
            acc
        })
    });
    group.finish();
}

fn layouts(c: &mut Criterion) {
    let g = Grid::new(N).unwrap();
    bench_layout(c, "row-major", RowMajor::new(g));
    bench_layout(c, "tiled-16", Tiled::new(g, 16));
    bench_layout(c, "interleaved", Interleaved::new(g));
    bench_layout(c, "embedded", Embedded::new(g));
    bench_layout(c, "hz", Hz::new(g));
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(30)
        .warm_up_time(std::time::Duration::from_millis(500))
        .measurement_time(std::time::Duration::from_secs(2));
    targets = layouts
}
criterion_main!(benches);
