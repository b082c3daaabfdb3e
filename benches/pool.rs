//! The buffer pool's costs (`relief_core::pager::pool`; El-Sana & Chiang §3.3.3–3.3.4), with 4 KiB blocks
//! whose "read" is a fill (so the figures are the pool's own overhead, not a disk's):
//! - the navigation hot path on blocks in real memory: `get`, a usage count raised and dropped,
//!   a reference count raised and dropped, and a second chance (a released block taken back);
//! - the miss path: a reference on a block not in memory, the I/O thread's read and install,
//!   then `get` — one block at a time (`drain` after each: a full thread round trip) and eight at a
//!   time (the I/O thread works through the board while Navigate waits once).

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use relief_core::pager::pool::{BlockLoader, BufferPool};
use relief_core::Result;

const BLOCK_BYTES: usize = 4096;

struct Pages;

impl BlockLoader for Pages {
    type Block = Vec<u8>;
    fn load(&self, id: u32, recycled: Option<Vec<u8>>) -> Result<Vec<u8>> {
        let mut v = recycled.unwrap_or_else(|| vec![0; BLOCK_BYTES]);
        v.fill(id as u8);
        Ok(v)
    }
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("pool");
    group.sample_size(20);
    const OPS: u32 = 1024;
    group.throughput(Throughput::Elements(OPS as u64));

    // 32 referenced blocks in a 64-holder pool.
    let pool = BufferPool::new(Pages, 64).expect("pool");
    for id in 0..32 {
        pool.reference(id, 1);
    }
    pool.drain().expect("load");
    group.bench_function("get_hit", |b| {
        b.iter(|| {
            let mut sum = 0u64;
            for i in 0..OPS {
                sum += pool.get(i % 32).map_or(0, |b| b[0] as u64);
            }
            sum
        })
    });
    group.bench_function("use_pair", |b| {
        b.iter(|| {
            for i in 0..OPS {
                black_box(pool.use_block(i % 32, 1));
                black_box(pool.use_block(i % 32, -1));
            }
        })
    });
    group.bench_function("reference_pair", |b| {
        b.iter(|| {
            for i in 0..OPS {
                black_box(pool.reference(i % 32, 1));
                black_box(pool.reference(i % 32, -1));
            }
        })
    });
    // Released to the free list and taken back: each pair is one second chance.
    for id in 0..32 {
        pool.reference(id, -1);
    }
    group.bench_function("second_chance_pair", |b| {
        b.iter(|| {
            for i in 0..OPS {
                black_box(pool.reference(i % 32, 1));
                black_box(pool.reference(i % 32, -1));
            }
        })
    });
    assert_eq!(pool.stats().disk_reads, 32, "the hot path read nothing");
    drop(pool);

    // Misses: 8 holders, 256 blocks visited in a cycle, so each visit reads.
    let pool = BufferPool::new(Pages, 8).expect("pool");
    let mut next = 0u32;
    group.throughput(Throughput::Elements(1));
    group.bench_function("miss_one", |b| {
        b.iter(|| {
            let id = next % 256;
            next += 1;
            pool.reference(id, 1);
            pool.drain().expect("load");
            let got = pool.get(id).map_or(0, |b| b[0]);
            pool.reference(id, -1);
            got
        })
    });
    group.throughput(Throughput::Elements(8));
    group.bench_function("miss_batch_of_8", |b| {
        b.iter(|| {
            let first = next;
            for _ in 0..8 {
                pool.reference(next % 256, 1);
                next += 1;
            }
            pool.drain().expect("load");
            let mut sum = 0u64;
            for id in first..next {
                sum += pool.get(id % 256).map_or(0, |b| b[0] as u64);
                pool.reference(id % 256, -1);
            }
            sum
        })
    });
    let s = pool.stats();
    assert_eq!(s.second_chance_hits, 0, "every visit missed");
    assert_eq!(s.prefetch_given_up, 0);
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
