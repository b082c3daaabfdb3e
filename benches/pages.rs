//! The disk-page backend's hot loops: the per-frame fetch (k-d query, box and normal-cone
//! culling, sorted preads of page runs, decoding every triangle) on the real bunny
//! (../shared/data/mesh) in each layout, warm in the page cache, along an orbit; and the
//! 2-factor layout (matchings over Lloyd clusters) on the bunny's triangle centroids.

use std::hint::black_box;
use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use glam::DVec3;
use relief_core::camera::{Camera, UpAxis};
use relief_core::diskpages::build::{build_page_file, PageBuildOptions};
use relief_core::diskpages::fetch::{FetchOptions, PageSource};
use relief_core::diskpages::two_factor::{two_factor_order, TwoFactorOptions};
use relief_core::flight::frame::FrameSource;
use relief_core::flight::{orbit_box, OrbitOptions};
use relief_core::format::pagefile::{PageFile, PageLayout};
use relief_core::mesh::read_mesh;

fn bench(c: &mut Criterion) {
    let bunny = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/mesh/bunny.off");
    let mesh = read_mesh(&bunny).expect("the bunny in ../shared/data/mesh");
    let dir = tempfile::tempdir().expect("a temporary directory");
    let mut group = c.benchmark_group("pages");
    group.sample_size(20);

    for layout in PageLayout::ALL {
        let out = dir.path().join(format!("bunny.{}.rpg", layout.name()));
        build_page_file(&mesh, &out, &PageBuildOptions::new(4096, layout)).expect("a page file");
        let file = PageFile::open(&out).expect("the page file");
        let path = orbit_box(&file.header().bounds, UpAxis::Y, &OrbitOptions::new(32)).expect("an orbit");
        let cameras: Vec<Camera> = path
            .frames
            .iter()
            .map(|f| Camera::new(DVec3::from(f.eye), DVec3::from(f.look), DVec3::Y, 60.0, 1280, 720).expect("a camera"))
            .collect();
        let mut source = PageSource::new(file, FetchOptions::default());
        let pages: u64 = cameras
            .iter()
            .map(|cam| {
                source.update(cam, 1.0).expect("a frame");
                source.pages().len() as u64
            })
            .sum();
        group.throughput(Throughput::Elements(pages));
        group.bench_function(format!("fetch_orbit_32_frames/{}", layout.name()), |b| {
            b.iter(|| {
                for cam in &cameras {
                    source.update(cam, 1.0).expect("a frame");
                    black_box(source.triangles().len());
                }
            })
        });
    }

    let (centroids, normals): (Vec<[f64; 3]>, Vec<[f64; 3]>) = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| DVec3::from(mesh.positions[i as usize]));
            (((a + b + c) / 3.0).to_array(), (b - a).cross(c - a).normalize_or_zero().to_array())
        })
        .unzip();
    group.sample_size(10);
    group.throughput(Throughput::Elements(centroids.len() as u64));
    group.bench_function("two_factor_order/bunny", |b| {
        b.iter(|| {
            black_box(two_factor_order(&centroids, &normals, &TwoFactorOptions::default(), &|_| {}).expect("an order"))
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
