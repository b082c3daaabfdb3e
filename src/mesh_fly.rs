//! Flying around a general triangle mesh: the [`MeshFrameSource`] trait a view-dependent
//! simplification implements (adapt to a camera, hand over the triangles), a trivial source
//! ([`StaticMesh`], the whole mesh), and the loops that draw what a source adapts: headless
//! ([`fly_mesh_headless`], per-frame figures and optional PNGs) and in a window
//! (`window::mesh_window`). Both take `&mut dyn MeshFrameSource`, so a new backend is one call.
//!
//! Per frame: `update` (the adaptation, timed by the source), then, only when the triangle set
//! changed (the first frame, or any split or collapse), one upload of the whole triangle list
//! ([`MeshRenderer::upload`], 36 bytes a triangle), then the draw.

use std::path::PathBuf;
use std::time::Instant;

use serde::Serialize;

use crate::camera::{Camera, UpAxis};
use crate::error::{Error, Result};
pub use crate::flight::frame::*;
use crate::fly::{median, save_png};
use crate::mesh::Bounds;
use crate::render::mesh_shade::MeshShadeParams;
use crate::render::offscreen::OFFSCREEN_FORMAT;
use crate::render::{Gpu, MeshRenderer, MeshStyle, MeshView, Offscreen};
use crate::sys::progress::Progress;

/// The drawing side of a mesh flight, shared by the headless loop and the window: the renderer,
/// and whether it holds the source's triangles yet.
pub struct MeshStage {
    pub renderer: MeshRenderer,
    bounds: Bounds,
    loaded: bool,
}

impl MeshStage {
    /// A renderer for `colour_format`, shaded for `bounds` with `up` up.
    pub fn new(gpu: &Gpu, colour_format: wgpu::TextureFormat, bounds: Bounds, up: UpAxis) -> Result<MeshStage> {
        let renderer = MeshRenderer::new(gpu, colour_format, MeshShadeParams::for_bounds(&bounds, up))?;
        Ok(MeshStage { renderer, bounds, loaded: false })
    }

    /// Uploads `source`'s triangles if `stats` says they changed (or none were uploaded yet),
    /// relative to the eye of `camera`; returns the bytes sent (0 when nothing changed).
    pub fn sync(
        &mut self,
        gpu: &Gpu,
        source: &dyn MeshFrameSource,
        stats: &MeshFrameStats,
        camera: &Camera,
    ) -> Result<u64> {
        if self.loaded && stats.adapt() == 0 {
            return Ok(0);
        }
        let bytes = self.renderer.upload(gpu, source.triangles(), camera.eye_in_world)?;
        self.loaded = true;
        Ok(bytes)
    }

    /// Records a frame of the uploaded triangles seen by `camera` (see [`MeshRenderer::encode`]).
    pub fn encode(
        &self,
        gpu: &Gpu,
        encoder: &mut wgpu::CommandEncoder,
        colour: &wgpu::TextureView,
        depth: &wgpu::TextureView,
        camera: &Camera,
        style: MeshStyle,
    ) -> u64 {
        self.renderer.encode(gpu, encoder, colour, depth, &MeshView::new(&self.bounds, *camera), style)
    }

    /// Draws the uploaded triangles seen by `camera` offscreen in `format` and reads the image back.
    pub fn still(
        &self,
        gpu: &Gpu,
        camera: &Camera,
        format: wgpu::TextureFormat,
        style: MeshStyle,
    ) -> Result<image::RgbaImage> {
        let target = Offscreen::with_format(gpu, camera.width_px, camera.height_px, format)?;
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        self.encode(gpu, &mut encoder, &target.colour_view, &target.depth_view, camera, style);
        gpu.queue.submit([encoder.finish()]);
        target.read_rgba(gpu)
    }
}

/// Settings of a headless mesh flight.
#[derive(Clone, Debug)]
pub struct MeshFlyOptions {
    /// Image size; every camera must have it.
    pub width_px: u32,
    pub height_px: u32,
    /// Screen-space tolerance handed to the source, pixels.
    pub tolerance_px: f64,
    pub style: MeshStyle,
    /// The world's up axis (sky and sun).
    pub up: UpAxis,
    /// Write every frame as `frame_00000.png` here.
    pub frames_out: Option<PathBuf>,
    /// Write the report (`{"frames":[…],"summary":{…}}`) here as JSON.
    pub stats_out: Option<PathBuf>,
    /// Start frames at least this many milliseconds apart (0: back to back). Without rendering
    /// this stands in for a display's frame time, during which an I/O thread can prefetch; the
    /// wait is not counted in `frame_ms`.
    pub pace_ms: f64,
    pub progress: Progress,
}

/// Per-frame figures of a mesh flight.
#[derive(Clone, Debug, Serialize)]
pub struct MeshFrameReport {
    pub frame: usize,
    /// Splits + collapses.
    pub adapt: u64,
    pub splits: u64,
    pub collapses: u64,
    /// Triangles drawn.
    pub triangles: u64,
    pub misses: u64,
    /// 100 × misses / (adapt + misses), 0 when both are 0.
    pub miss_pct: f64,
    pub pages_read: u64,
    pub second_chance_hits: u64,
    /// The source's adaptation time, ms.
    pub adapt_ms: f64,
    /// Upload (when the triangles changed), draw and finish on the GPU (readback and PNG
    /// excluded), ms.
    pub render_ms: f64,
    /// Wall time of the whole frame (adaptation, render, readback and PNG when written), ms.
    pub frame_ms: f64,
    /// Triangle bytes sent to the GPU this frame (0 when unchanged; the 256-byte uniform aside).
    pub upload_bytes: u64,
    /// Page-fetch figures (the disk-page backend only), flattened into the frame's object.
    #[serde(flatten)]
    pub fetch: Option<PageFetchFigures>,
}

/// Whole-flight figures: means, medians and totals over the frames.
#[derive(Clone, Debug, Serialize)]
pub struct MeshFlySummary {
    pub frames: usize,
    pub frame_ms_mean: f64,
    pub frame_ms_median: f64,
    pub render_ms_mean: f64,
    pub render_ms_median: f64,
    pub adapt_ms_mean: f64,
    pub adapt_ms_median: f64,
    /// Over the flight: 100 × Σ misses / (Σ adapt + Σ misses).
    pub miss_pct: f64,
    pub adapt_mean: f64,
    pub adapt_median: f64,
    pub triangles_mean: f64,
    pub triangles_median: f64,
    /// Totals over the flight.
    pub pages_read: u64,
    pub second_chance_hits: u64,
    pub upload_bytes: u64,
    pub fps: f64,
    pub width: u32,
    pub height: u32,
    pub tolerance_px: f64,
    pub adapter: String,
    /// Page-fetch means (the disk-page backend only), flattened into the summary.
    #[serde(flatten)]
    pub fetch: Option<PageFetchSummary>,
}

/// A headless mesh flight: `{"frames":[…],"summary":{…}}` as JSON.
#[derive(Clone, Debug, Serialize)]
pub struct MeshFlyReport {
    pub frames: Vec<MeshFrameReport>,
    pub summary: MeshFlySummary,
}

impl MeshFlySummary {
    fn of(frames: &[MeshFrameReport], wall_s: f64, options: &MeshFlyOptions, adapter: String) -> MeshFlySummary {
        let col = |f: fn(&MeshFrameReport) -> f64| frames.iter().map(f).collect::<Vec<f64>>();
        let total = |f: fn(&MeshFrameReport) -> u64| frames.iter().map(f).sum::<u64>();
        let (frame_ms, render_ms, adapt_ms) = (col(|f| f.frame_ms), col(|f| f.render_ms), col(|f| f.adapt_ms));
        let (adapt, triangles) = (col(|f| f.adapt as f64), col(|f| f.triangles as f64));
        MeshFlySummary {
            frames: frames.len(),
            frame_ms_mean: mean(frame_ms.iter().copied()),
            frame_ms_median: median(frame_ms),
            render_ms_mean: mean(render_ms.iter().copied()),
            render_ms_median: median(render_ms),
            adapt_ms_mean: mean(adapt_ms.iter().copied()),
            adapt_ms_median: median(adapt_ms),
            miss_pct: pct(total(|f| f.misses), total(|f| f.adapt)),
            adapt_mean: mean(adapt.iter().copied()),
            adapt_median: median(adapt),
            triangles_mean: mean(triangles.iter().copied()),
            triangles_median: median(triangles),
            pages_read: total(|f| f.pages_read),
            second_chance_hits: total(|f| f.second_chance_hits),
            upload_bytes: total(|f| f.upload_bytes),
            fps: if wall_s > 0.0 { frames.len() as f64 / wall_s } else { 0.0 },
            width: options.width_px,
            height: options.height_px,
            tolerance_px: options.tolerance_px,
            adapter,
            fetch: PageFetchSummary::of_figures(&frames.iter().filter_map(|f| f.fetch).collect::<Vec<_>>()),
        }
    }
}

/// Adapts `source` to each of `cameras` and renders it offscreen, one frame each; writes the PNGs
/// and the JSON report where `options` asks, and returns the report.
pub fn fly_mesh_headless(
    gpu: Option<&Gpu>,
    source: &mut dyn MeshFrameSource,
    cameras: &[Camera],
    options: &MeshFlyOptions,
) -> Result<MeshFlyReport> {
    if cameras.is_empty() {
        return Err(Error::InvalidArgument("a mesh flight needs at least one camera".into()));
    }
    let size = (options.width_px, options.height_px);
    if let Some((k, c)) = cameras.iter().enumerate().find(|(_, c)| (c.width_px, c.height_px) != size) {
        return Err(Error::InvalidArgument(format!(
            "camera {k} is {} x {} pixels, the flight {} x {}",
            c.width_px, c.height_px, size.0, size.1
        )));
    }
    if let Some(dir) = &options.frames_out {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    // Without a GPU only the adaptation runs (timing navigation alone).
    let mut targets = match gpu {
        Some(gpu) => Some((
            Offscreen::new(gpu, options.width_px, options.height_px)?,
            MeshStage::new(gpu, OFFSCREEN_FORMAT, source.bounds(), options.up)?,
        )),
        None => None,
    };
    let bar = options.progress.bar("fly", cameras.len() as u64, "frames");
    let mut frames = Vec::with_capacity(cameras.len());
    let t_all = Instant::now();
    let mut next_start = Instant::now();
    for (k, camera) in cameras.iter().enumerate() {
        crate::sys::cancel::check()?;
        if let Some(wait) = next_start.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        next_start = Instant::now() + std::time::Duration::from_secs_f64(options.pace_ms.max(0.0) / 1e3);
        let t0 = Instant::now();
        let stats = source.update(camera, options.tolerance_px)?;
        let t_render = Instant::now();
        let (mut upload_bytes, mut triangles) = (0, stats.triangles);
        if let (Some(gpu), Some((target, stage))) = (gpu, targets.as_mut()) {
            upload_bytes = stage.sync(gpu, source, &stats, camera)?;
            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            stage.encode(gpu, &mut encoder, &target.colour_view, &target.depth_view, camera, options.style);
            gpu.queue.submit([encoder.finish()]);
            gpu.wait_idle()?;
            triangles = stage.renderer.triangles();
            if let Some(dir) = &options.frames_out {
                save_png(&target.read_rgba(gpu)?, &dir.join(format!("frame_{k:05}.png")))?;
            }
        }
        let render_ms = t_render.elapsed().as_secs_f64() * 1e3;
        frames.push(MeshFrameReport {
            frame: k,
            adapt: stats.adapt(),
            splits: stats.splits,
            collapses: stats.collapses,
            triangles,
            misses: stats.misses,
            miss_pct: stats.miss_pct(),
            pages_read: stats.pages_read,
            second_chance_hits: stats.second_chance_hits,
            adapt_ms: stats.adapt_ms,
            render_ms,
            frame_ms: t0.elapsed().as_secs_f64() * 1e3,
            upload_bytes,
            fetch: source.page_fetch(),
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    let summary = MeshFlySummary::of(
        &frames,
        t_all.elapsed().as_secs_f64(),
        options,
        gpu.map_or_else(|| "none (adaptation only)".to_string(), Gpu::describe),
    );
    let report = MeshFlyReport { frames, summary };
    if let Some(out) = &options.stats_out {
        let text = serde_json::to_string_pretty(&report)
            .map_err(|e| Error::InvalidArgument(format!("cannot encode the flight report: {e}")))?;
        crate::sys::atomic_file::write(out, |w| std::io::Write::write_all(w, text.as_bytes()))?;
    }
    Ok(report)
}
