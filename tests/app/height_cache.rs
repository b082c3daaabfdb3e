//! The GPU height cache on lavapipe: renders whose heights are paged match renders with the whole
//! grid resident, and a cache far too small for the view never puts a vertex off its height nor
//! goes over its budgets.

use crate::common;

use std::sync::Arc;

use common::{compare, dem, gpu};
use glam::DVec3;
use relief::camera::Camera;
use relief::flight::frame::{FrameSource, Presenter};
use relief::flight::path::{flyover, FlyoverOptions};
use relief::flight::terrain::TerrainSource;
use relief::format::terrain::TerrainFile;
use relief::layout::LayoutKind;
use relief::preprocess::convert::{convert, ConvertOptions};
use relief::refine::{RefineOptions, Strip};
use relief::render::offscreen::{ProbeTargets, OFFSCREEN_FORMAT};
use relief::render::terrain::Probe;
use relief::render::{DrawStyle, FrameView, Gpu, RendererOptions, TerrainPresenter, TerrainRenderer};
use relief::sys::progress::Progress;

fn zurich(layout: LayoutKind) -> (tempfile::TempDir, Arc<TerrainFile>) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("z.relief");
    let mut opts = ConvertOptions::new(layout);
    opts.progress = Progress::hidden();
    convert(&dem("zurich_25m_i16.tif"), &out, &opts).unwrap();
    let t = Arc::new(TerrainFile::open(&out).unwrap());
    (dir, t)
}

/// Zürich's 513² grid takes 1,052,676 bytes resident; tiles of 32 cells (35² posts, 4,900 bytes
/// a slot) in 800 KB hold 162 of its 341 tiles, so the view's tiles are paged.
const BUDGET: u64 = 800_000;
const PAGED: RendererOptions = RendererOptions {
    tile_posts: None,
    gpu_memory: Some(BUDGET),
    upload_per_frame: Some(64_000),
    cache_tile_cells: Some(32),
    nodata: relief::render::NodataStyle::Void,
    look: relief::render::Look::DEFAULT,
    imagery: None,
    imagery_gpu_memory: None,
};

#[test]
fn paged_heights_render_as_the_resident_grid_along_a_flight() {
    let gpu = gpu();
    let (_dir, t) = zurich(LayoutKind::Hz);
    let path = flyover(&t, &FlyoverOptions::new(30)).unwrap();
    let (w, h) = (320, 200);
    let mut resident = TerrainPresenter::new(
        &gpu,
        t.clone(),
        w,
        h,
        DrawStyle::default(),
        RendererOptions::default(),
        Progress::hidden(),
    )
    .unwrap();
    let mut paged =
        TerrainPresenter::new(&gpu, t.clone(), w, h, DrawStyle::default(), PAGED, Progress::hidden()).unwrap();
    assert!(!resident.renderer.cached() && paged.renderer.cached());
    assert!(paged.renderer.heights_bytes() <= BUDGET);
    let options = RefineOptions { tolerance_px: 1.0, heights: true, ..Default::default() };
    let mut source = TerrainSource::new(t.clone(), options, 1, false).unwrap();
    let mut checked = 0;
    for k in [0, 10, 20, 29] {
        let cam = path.camera(k, 60.0, w, h).unwrap();
        source.update(&cam, 1.0).unwrap();
        resident.present(source.frame(), true, &cam).unwrap();
        paged.settle(source.strip(), &cam).unwrap();
        let stats = paged.heights();
        assert!(stats.cached && stats.in_use_bytes <= BUDGET, "{stats:?}");
        assert!(stats.tiles_resident > 1, "frame {k}: nothing was paged in: {stats:?}");
        let (a, b) = (resident.image().unwrap(), paged.image().unwrap());
        // Within the golden tolerance, and in fact much closer: tiles that did not fit shade
        // from the next level, a few pixels far away.
        let (mean, off) = mean_diff(&b, &a);
        assert!(mean < 0.05 && off < 1e-3, "frame {k}: mean difference {mean} levels, {off} of pixels off by > 8");
        if let Err(e) = compare(&b, &a) {
            let out = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"));
            a.save(out.join(format!("cache_resident_{k}.png"))).unwrap();
            b.save(out.join(format!("cache_paged_{k}.png"))).unwrap();
            panic!("frame {k}: paged heights differ from the resident grid: {e} (images in {})", out.display());
        }
        checked += 1;
    }
    assert_eq!(checked, 4);

    // Before the cache has settled, only the coarsest tiles are there: the image is visibly
    // coarser (about 1 level on average, inside the golden tolerance), so the strict bound above
    // compares something. One tile a frame (4,900 bytes and the 1,492-byte table): after one
    // frame at most one tile below the coarsest.
    let cam = path.camera(15, 60.0, w, h).unwrap();
    let one_a_frame = RendererOptions { upload_per_frame: Some(4_900 + 1_492), ..PAGED };
    let mut cold =
        TerrainPresenter::new(&gpu, t.clone(), w, h, DrawStyle::default(), one_a_frame, Progress::hidden()).unwrap();
    source.update(&cam, 1.0).unwrap();
    cold.present(source.frame(), true, &cam).unwrap();
    resident.present(source.frame(), true, &cam).unwrap();
    assert!(cold.heights().tiles_resident <= 2, "{:?}", cold.heights());
    let (c, r) = (cold.image().unwrap(), resident.image().unwrap());
    paged.settle(source.strip(), &cam).unwrap();
    let (cold_mean, settled_mean) = (mean_diff(&c, &r).0, mean_diff(&paged.image().unwrap(), &r).0);
    assert!(cold_mean > 0.5 && settled_mean < 0.05, "cold {cold_mean}, settled {settled_mean} levels");
}

/// Mean absolute difference per channel, levels, and the fraction of pixels off by more than 8.
fn mean_diff(a: &image::RgbaImage, b: &image::RgbaImage) -> (f64, f64) {
    let (mut sum, mut big) = (0u64, 0u64);
    for (p, q) in a.pixels().zip(b.pixels()) {
        let d: Vec<u64> = (0..3).map(|c| (p[c] as i64 - q[c] as i64).unsigned_abs()).collect();
        sum += d.iter().sum::<u64>();
        big += (d.iter().max().copied().unwrap_or(0) > 8) as u64;
    }
    let n = (a.width() * a.height()) as f64;
    (sum as f64 / (3.0 * n), big as f64 / n)
}

/// Deterministic jumps over the terrain (xorshift).
fn jumps(t: &TerrainFile, n: usize, w: u32, h: u32) -> Vec<Camera> {
    let mut s = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let [ex, ey] = t.header().extent_m();
    (0..n)
        .map(|_| {
            let eye = DVec3::new(next() * ex, next() * ey, t.header().z_max + 50.0 + 3000.0 * next());
            let look = DVec3::new(next() * ex, next() * ey, t.header().z_min);
            Camera::new(eye, look, DVec3::Z, 60.0, w, h).unwrap()
        })
        .collect()
}

/// The probe's first target (grid x, grid y, surface height, mesh height) of `strip`.
fn probe_positions(gpu: &Gpu, r: &mut TerrainRenderer, t: &TerrainFile, strip: &Strip, cam: &Camera) -> Vec<[f32; 4]> {
    r.upload_strip(gpu, strip).unwrap();
    let targets = ProbeTargets::new(gpu, cam.width_px, cam.height_px);
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let views = [&targets.views[0], &targets.views[1]];
    r.encode_probe(gpu, &mut enc, views, &targets.depth_view, &FrameView::new(t, *cam, 1.0), Probe::Normal);
    gpu.queue.submit([enc.finish()]);
    targets.read(gpu, 0).unwrap()
}

#[test]
fn a_tiny_cache_keeps_every_vertex_at_its_height_and_within_budget() {
    let gpu = gpu();
    let (_dir, t) = zurich(LayoutKind::Interleaved);
    // Three slots of 16-cell tiles (1,444 bytes each, a 5,588-byte table of 1,365 tiles) for a
    // view that wants dozens: nearly every tile falls back to a coarser one.
    let budget = 3 * 19 * 19 * 4 + 5_588;
    let tiny = RendererOptions {
        gpu_memory: Some(budget),
        upload_per_frame: Some(19 * 19 * 4 + 5_588),
        cache_tile_cells: Some(16),
        ..Default::default()
    };
    let mut cached = TerrainRenderer::new(&gpu, &t, OFFSCREEN_FORMAT, tiny.clone(), Progress::hidden()).unwrap();
    let mut resident =
        TerrainRenderer::new(&gpu, &t, OFFSCREEN_FORMAT, RendererOptions::default(), Progress::hidden()).unwrap();
    assert_eq!(cached.height_cache().unwrap().slots(), 3);
    assert!(cached.heights_bytes() <= budget);
    let options = RefineOptions { tolerance_px: 2.0, heights: true, ..Default::default() };
    let mut source = TerrainSource::new(t.clone(), options, 1, false).unwrap();
    let (mut fell_back, mut evicted, mut covered) = (0, 0, 0usize);
    for (k, cam) in jumps(&t, 12, 160, 100).iter().enumerate() {
        source.update(cam, 2.0).unwrap();
        let strip = source.strip();
        // The strip carries every vertex's exact height, read back from the file here.
        assert_eq!(strip.morph.len(), strip.vertices.len());
        for (v, m) in strip.vertices.iter().zip(&strip.morph) {
            assert_eq!((m.z_m, m.blend), (t.record_at(v.x, v.y).unwrap().z, 1.0), "frame {k} vertex {v:?}");
        }
        cached.upload_strip(&gpu, strip).unwrap();
        for _ in 0..3 {
            let sent = cached.sync_heights(&gpu, cam, Some(strip)).unwrap();
            let s = cached.height_stats();
            assert!(
                s.in_use_bytes <= budget && sent <= tiny.upload_per_frame.unwrap(),
                "frame {k}: {s:?}, {sent} sent"
            );
            (fell_back, evicted) = (fell_back + s.fallbacks, evicted + s.evicted);
        }
        // Placed positions: the cache's vertices (heights from the strip) against the resident
        // grid's (heights from its texture, the strip sent without them), pixel for pixel.
        let got = probe_positions(&gpu, &mut cached, &t, strip, cam);
        let want = probe_positions(&gpu, &mut resident, &t, &Strip::from_vertices(strip.vertices.clone()), cam);
        for (p, (a, b)) in got.iter().zip(&want).enumerate() {
            assert_eq!((a[0], a[1], a[3]), (b[0], b[1], b[3]), "frame {k} pixel {p}: a vertex is off its height");
        }
        covered += want.iter().filter(|p| p[3] != 0.0).count();
    }
    assert!(covered > 12 * 160 * 100 / 4, "the jumps saw little terrain ({covered} pixels)");
    assert!(fell_back > 0 && evicted > 0, "the budget was not tight: {fell_back} fallbacks, {evicted} evictions");
}

#[test]
fn budgets_too_small_for_the_cache_are_refused_with_the_sizes() {
    let gpu = gpu();
    let (_dir, t) = zurich(LayoutKind::Interleaved);
    let small = RendererOptions { gpu_memory: Some(5_000), cache_tile_cells: Some(32), ..Default::default() };
    let e = TerrainRenderer::new(&gpu, &t, OFFSCREEN_FORMAT, small, Progress::hidden()).err().unwrap().to_string();
    assert!(e.contains("GPU height budget of 5000 bytes is too small") && e.contains("at least 11292"), "{e}");
    let slow = RendererOptions { upload_per_frame: Some(1_000), ..PAGED };
    let e = TerrainRenderer::new(&gpu, &t, OFFSCREEN_FORMAT, slow, Progress::hidden()).err().unwrap().to_string();
    assert!(e.contains("upload budget of 1000 bytes per frame is too small"), "{e}");
}
