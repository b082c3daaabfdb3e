//! Flying over terrains with the GPU: the strip source that feeds the renderer, headless flights
//! and stills.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use serde::Serialize;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::flight::terrain::refine_once;
pub use crate::flight::terrain::{median, Mailbox, RefineJob, RefineThread, Refined};
use crate::format::terrain::TerrainFile;
use crate::refine::{RefineCounters, RefineOptions, Refiner, Strip};
use crate::render::{DrawStyle, FrameView, Gpu, Offscreen, TerrainRenderer};
use crate::sys::progress::Progress;

pub enum StripSource {
    Sync { refiner: Refiner, terrain: Arc<TerrainFile>, strip: Strip },
    Thread { thread: RefineThread, last_request: Option<(Camera, RefineOptions)> },
}

/// What one update did.
#[derive(Clone, Copy, Debug, Default)]
pub struct Update {
    /// A new strip was uploaded.
    pub uploaded: bool,
    /// Bytes sent to the GPU for the strip (0 when none was new).
    pub upload_bytes: u64,
    /// Refinement time of the uploaded strip, ms.
    pub refine_ms: Option<f64>,
    /// Camera updates between the drawn strip's request and now (0 in synchronous mode).
    pub lag: u64,
    /// Page faults (major, minor) during the uploaded strip's refinement.
    pub faults: (u64, u64),
    pub counters: RefineCounters,
}

impl StripSource {
    pub fn new(terrain: Arc<TerrainFile>, threads: usize, refine_thread: bool) -> Result<StripSource> {
        Ok(if refine_thread {
            StripSource::Thread { thread: RefineThread::spawn(terrain, threads)?, last_request: None }
        } else {
            StripSource::Sync { refiner: Refiner::new(threads)?, terrain, strip: Strip::new() }
        })
    }

    /// Brings the renderer's strip up to date with `job` as far as this mode allows: synchronous
    /// mode refines now; thread mode asks for `job` (if the view changed) and uploads the newest
    /// finished strip, if there is one. With `block`, thread mode waits for a strip (first frame).
    pub fn update(&mut self, gpu: &Gpu, renderer: &mut TerrainRenderer, job: RefineJob, block: bool) -> Update {
        match self {
            StripSource::Sync { refiner, terrain, strip } => {
                let r = refine_once(refiner, terrain, job, std::mem::take(strip));
                let upload_bytes = renderer.upload_strip(gpu, &r.strip);
                *strip = r.strip;
                Update {
                    uploaded: true,
                    upload_bytes,
                    refine_ms: Some(r.refine_ms),
                    lag: 0,
                    faults: r.faults,
                    counters: r.counters,
                }
            }
            StripSource::Thread { thread, last_request } => {
                if *last_request != Some((job.camera, job.options)) {
                    thread.request(job);
                    *last_request = Some((job.camera, job.options));
                }
                let got = if block { thread.wait() } else { thread.take() };
                match got {
                    Some(r) => {
                        let upload_bytes = renderer.upload_strip(gpu, &r.strip);
                        let u = Update {
                            uploaded: true,
                            upload_bytes,
                            refine_ms: Some(r.refine_ms),
                            lag: job.seq.saturating_sub(r.job.seq),
                            faults: r.faults,
                            counters: r.counters,
                        };
                        thread.recycle(r.strip);
                        u
                    }
                    None => Update::default(),
                }
            }
        }
    }
}

/// Settings of a headless flight.
#[derive(Clone, Debug)]
pub struct HeadlessOptions {
    pub width_px: u32,
    pub height_px: u32,
    pub fov_x_deg: f64,
    pub refine: RefineOptions,
    pub style: DrawStyle,
    /// Threads refinement uses.
    pub threads: usize,
    /// Refine on a separate thread (mailbox) instead of before each frame.
    pub refine_thread: bool,
    /// Write every frame as `frame_00000.png` here.
    pub frames_out: Option<PathBuf>,
    pub progress: Progress,
}

/// Per-frame figures of a flight.
#[derive(Clone, Debug, Serialize)]
pub struct FrameStats {
    pub frame: usize,
    /// Refinement time of the strip uploaded this frame (null: no new strip).
    pub refine_ms: Option<f64>,
    /// Time to upload, draw and finish on the GPU (readback and PNG excluded), ms.
    pub render_ms: f64,
    /// Wall time of the whole frame, ms.
    pub frame_ms: f64,
    pub triangles: u64,
    pub strip_len: u32,
    /// CPU → GPU bytes this frame: the strip (when new) and the frame uniform.
    pub upload_bytes: u64,
    /// Camera updates between the drawn strip's camera and this frame's.
    pub lag_frames: u64,
    pub major_faults: u64,
    pub minor_faults: u64,
}

/// Whole-flight figures.
#[derive(Clone, Debug, Serialize)]
pub struct FlySummary {
    pub frames: usize,
    pub fps: f64,
    pub frame_ms_median: f64,
    pub refine_ms_median: f64,
    pub render_ms_median: f64,
    pub triangles_mean: f64,
    pub upload_bytes_mean: f64,
    pub upload_bytes_max: u64,
    pub major_faults: u64,
    pub minor_faults: u64,
    pub refine_thread: bool,
    pub width: u32,
    pub height: u32,
    pub tolerance_px: f64,
    pub adapter: String,
    pub heights_gpu_bytes: u64,
}

#[derive(Clone, Debug, Serialize)]
pub struct FlyReport {
    pub frames: Vec<FrameStats>,
    pub summary: FlySummary,
}

/// Writes `image` to `path` as PNG, atomically (never half-written).
pub fn save_png<P, C>(image: &image::ImageBuffer<P, C>, path: &Path) -> Result<()>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    crate::sys::atomic_file::write(path, |w| image.write_to(w, image::ImageFormat::Png).map_err(std::io::Error::other))
}

/// Renders `cameras` one frame each, offscreen, and reports per-frame figures.
pub fn fly_headless(terrain: Arc<TerrainFile>, cameras: &[Camera], options: &HeadlessOptions) -> Result<FlyReport> {
    let gpu = Gpu::headless()?;
    fly_headless_on(&gpu, terrain, cameras, options)
}

/// [`fly_headless`] on a given device.
pub fn fly_headless_on(
    gpu: &Gpu,
    terrain: Arc<TerrainFile>,
    cameras: &[Camera],
    options: &HeadlessOptions,
) -> Result<FlyReport> {
    if let Some(dir) = &options.frames_out {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    let target = Offscreen::new(gpu, options.width_px, options.height_px)?;
    let mut renderer = TerrainRenderer::new(
        gpu,
        &terrain,
        crate::render::offscreen::OFFSCREEN_FORMAT,
        Default::default(),
        options.progress,
    )?;
    let mut source = StripSource::new(terrain.clone(), options.threads, options.refine_thread)?;
    let bar = options.progress.bar("fly", cameras.len() as u64, "frames");
    let mut frames = Vec::with_capacity(cameras.len());
    let t_all = Instant::now();
    for (k, camera) in cameras.iter().enumerate() {
        crate::sys::cancel::check()?;
        let t0 = Instant::now();
        let job = RefineJob { camera: *camera, options: options.refine, seq: k as u64 };
        let update = source.update(gpu, &mut renderer, job, k == 0);
        let t_render = Instant::now();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let view = FrameView::new(&terrain, *camera);
        let uniform_bytes =
            renderer.encode(gpu, &mut encoder, &target.colour_view, &target.depth_view, &view, options.style);
        gpu.queue.submit([encoder.finish()]);
        gpu.wait_idle()?;
        let render_ms = t_render.elapsed().as_secs_f64() * 1e3;
        if let Some(dir) = &options.frames_out {
            let image = target.read_rgba(gpu)?;
            save_png(&image, &dir.join(format!("frame_{k:05}.png")))?;
        }
        let strip_len = renderer.strip_len();
        frames.push(FrameStats {
            frame: k,
            refine_ms: update.refine_ms,
            render_ms,
            frame_ms: t0.elapsed().as_secs_f64() * 1e3,
            triangles: renderer.triangles(),
            strip_len,
            upload_bytes: update.upload_bytes + uniform_bytes,
            lag_frames: update.lag,
            major_faults: update.faults.0,
            minor_faults: update.faults.1,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    let wall_s = t_all.elapsed().as_secs_f64();
    let n = frames.len().max(1) as f64;
    let summary = FlySummary {
        frames: frames.len(),
        fps: if wall_s > 0.0 { frames.len() as f64 / wall_s } else { 0.0 },
        frame_ms_median: median(frames.iter().map(|f| f.frame_ms).collect()),
        refine_ms_median: median(frames.iter().filter_map(|f| f.refine_ms).collect()),
        render_ms_median: median(frames.iter().map(|f| f.render_ms).collect()),
        triangles_mean: frames.iter().map(|f| f.triangles as f64).sum::<f64>() / n,
        upload_bytes_mean: frames.iter().map(|f| f.upload_bytes as f64).sum::<f64>() / n,
        upload_bytes_max: frames.iter().map(|f| f.upload_bytes).max().unwrap_or(0),
        major_faults: frames.iter().map(|f| f.major_faults).sum(),
        minor_faults: frames.iter().map(|f| f.minor_faults).sum(),
        refine_thread: options.refine_thread,
        width: options.width_px,
        height: options.height_px,
        tolerance_px: options.refine.tolerance_px,
        adapter: gpu.describe(),
        heights_gpu_bytes: renderer.heights_bytes(),
    };
    Ok(FlyReport { frames, summary })
}

/// The bundled default terrain (`data/zurich_25m_i16.tif`), converted on first use into the
/// user's cache directory ([`crate::preprocess::convert::cache_dir`]).
pub fn bundled_terrain(progress: Progress) -> Result<PathBuf> {
    const NAME: &str = "zurich_25m_i16.tif";
    let candidates = [Path::new("data").join(NAME), Path::new(env!("CARGO_MANIFEST_DIR")).join("data").join(NAME)];
    let Some(dem) = candidates.iter().find(|p| p.is_file()) else {
        return Err(Error::InvalidArgument(format!(
            "no FILE given and the bundled terrain data/{NAME} is not here; pass a terrain file"
        )));
    };
    let cache = crate::preprocess::convert::cache_dir();
    let out = cache.join("zurich_25m_i16.interleaved.relief");
    if TerrainFile::open(&out).is_ok() {
        return Ok(out);
    }
    std::fs::create_dir_all(&cache).map_err(|e| Error::io(&cache, e))?;
    let mut opts = crate::preprocess::convert::ConvertOptions::new(crate::layout::LayoutKind::Interleaved);
    opts.progress = progress;
    crate::preprocess::convert::convert(dem, &out, &opts)?;
    Ok(out)
}

/// Figures of one still image.
#[derive(Clone, Debug, Serialize)]
pub struct StillReport {
    pub triangles: u64,
    pub strip_len: u32,
    pub refine_ms: f64,
    pub render_ms: f64,
    /// CPU → GPU bytes of the frame: the strip and the frame uniform (the heights are uploaded
    /// once, see `heights_gpu_bytes`).
    pub upload_bytes: u64,
    pub heights_gpu_bytes: u64,
    pub width: u32,
    pub height: u32,
    pub adapter: String,
}

/// Refines and renders one view offscreen.
pub fn render_still(
    gpu: &Gpu,
    terrain: &TerrainFile,
    camera: &Camera,
    refine: &RefineOptions,
    style: DrawStyle,
    threads: usize,
    progress: Progress,
) -> Result<(image::RgbaImage, StillReport)> {
    let target = Offscreen::new(gpu, camera.width_px, camera.height_px)?;
    let mut renderer =
        TerrainRenderer::new(gpu, terrain, crate::render::offscreen::OFFSCREEN_FORMAT, Default::default(), progress)?;
    let mut refiner = Refiner::new(threads)?;
    let job = RefineJob { camera: *camera, options: *refine, seq: 0 };
    let refined = refine_once(&mut refiner, terrain, job, Strip::new());
    let t0 = Instant::now();
    let strip_bytes = renderer.upload_strip(gpu, &refined.strip);
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    let view = FrameView::new(terrain, *camera);
    let uniform_bytes = renderer.encode(gpu, &mut encoder, &target.colour_view, &target.depth_view, &view, style);
    gpu.queue.submit([encoder.finish()]);
    gpu.wait_idle()?;
    let render_ms = t0.elapsed().as_secs_f64() * 1e3;
    let image = target.read_rgba(gpu)?;
    let report = StillReport {
        triangles: renderer.triangles(),
        strip_len: renderer.strip_len(),
        refine_ms: refined.refine_ms,
        render_ms,
        upload_bytes: strip_bytes + uniform_bytes,
        heights_gpu_bytes: renderer.heights_bytes(),
        width: camera.width_px,
        height: camera.height_px,
        adapter: gpu.describe(),
    };
    Ok((image, report))
}
