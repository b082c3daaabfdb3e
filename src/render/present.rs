//! Drawing what a [`FrameSource`] hands over: the presenters the headless loop
//! ([`crate::flight::frame::fly`]) draws through (the terrain renderer for strips, the mesh
//! renderer for triangle lists), the mesh drawing shared with the window ([`MeshStage`]), stills,
//! and PNG output.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use serde::Serialize;

use super::mesh_shade::MeshShadeParams;
use super::offscreen::OFFSCREEN_FORMAT;
use super::{DrawStyle, FrameView, Gpu, MeshRenderer, MeshStyle, Offscreen, RendererOptions, TerrainRenderer};
use crate::camera::{Camera, UpAxis};
use crate::error::{Error, Result};
use crate::flight::frame::{Frame, FrameSource, Presenter};
use crate::flight::terrain::TerrainSource;
use crate::format::terrain::TerrainFile;
use crate::heightcache::HeightCacheStats;
use crate::mesh::Bounds;
use crate::refine::RefineOptions;
use crate::sys::progress::Progress;

/// Writes `image` to `path` as PNG, atomically (never half-written).
pub fn save_png<P, C>(image: &image::ImageBuffer<P, C>, path: &Path) -> Result<()>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
    C: std::ops::Deref<Target = [P::Subpixel]>,
{
    crate::sys::atomic_file::write(path, |w| image.write_to(w, image::ImageFormat::Png).map_err(std::io::Error::other))
}

fn wrong_frame(what: &str) -> Error {
    Error::InvalidArgument(format!("the {what} renderer was handed the other kind of frame"))
}

/// Draws a terrain's strips offscreen.
pub struct TerrainPresenter<'g> {
    gpu: &'g Gpu,
    target: Offscreen,
    pub renderer: TerrainRenderer,
    terrain: Arc<TerrainFile>,
    pub style: DrawStyle,
}

impl<'g> TerrainPresenter<'g> {
    /// Uploads `terrain`'s heights (or starts its height cache, as `options` ask) and makes a
    /// `width_px` × `height_px` target.
    pub fn new(
        gpu: &'g Gpu,
        terrain: Arc<TerrainFile>,
        width_px: u32,
        height_px: u32,
        style: DrawStyle,
        options: RendererOptions,
        progress: Progress,
    ) -> Result<TerrainPresenter<'g>> {
        let target = Offscreen::new(gpu, width_px, height_px)?;
        let renderer = TerrainRenderer::new(gpu, &terrain, OFFSCREEN_FORMAT, options, progress)?;
        Ok(TerrainPresenter { gpu, target, renderer, terrain, style })
    }

    /// Draws `strip` as `camera` sees it until the height cache holds, fully blended in, every
    /// tile the strip wants that fits (at once without the cache): for stills and tests, which
    /// may wait; a flight never does. Returns the bytes sent.
    pub fn settle(&mut self, strip: &crate::refine::Strip, camera: &Camera) -> Result<u64> {
        let mut bytes = self.present(Frame::Strip(strip), true, camera)?;
        let started = Instant::now();
        while self.renderer.height_cache().is_some_and(|c| !c.converged()) || !self.renderer.imagery_converged() {
            if started.elapsed().as_secs() > 600 {
                return Err(Error::InvalidArgument(
                    "the height or imagery cache did not settle within 10 minutes".into(),
                ));
            }
            let sent = self.present(Frame::Strip(strip), false, camera)?;
            if sent == 0 {
                std::thread::sleep(std::time::Duration::from_millis(2));
            }
            bytes += sent;
        }
        Ok(bytes)
    }

    /// The last image drawn.
    pub fn image(&self) -> Result<image::RgbaImage> {
        self.target.read_rgba(self.gpu)
    }
}

impl Presenter for TerrainPresenter<'_> {
    fn present(&mut self, frame: Frame<'_>, changed: bool, camera: &Camera) -> Result<u64> {
        let Frame::Strip(strip) = frame else { return Err(wrong_frame("terrain")) };
        let gpu = self.gpu;
        let strip_bytes = if changed { self.renderer.upload_strip(gpu, strip)? } else { 0 };
        let height_bytes = self.renderer.sync_heights(gpu, camera, changed.then_some(strip))?;
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let view = FrameView::new(&self.terrain, *camera, self.renderer.shade_params().z_exaggeration);
        let t = &self.target;
        let uniform_bytes = self.renderer.encode(gpu, &mut encoder, &t.colour_view, &t.depth_view, &view, self.style);
        gpu.queue.submit([encoder.finish()]);
        gpu.wait_idle()?;
        Ok(strip_bytes + height_bytes + uniform_bytes)
    }

    fn save(&mut self, path: &Path) -> Result<()> {
        save_png(&self.image()?, path)
    }

    fn adapter(&self) -> String {
        self.gpu.describe()
    }

    fn resident_bytes(&self) -> u64 {
        self.renderer.heights_bytes()
    }

    fn heights(&self) -> HeightCacheStats {
        self.renderer.height_stats()
    }

    fn imagery(&self) -> HeightCacheStats {
        self.renderer.imagery_stats()
    }
}

/// The drawing side of a mesh flight, shared by the headless presenter and the window: the
/// renderer, and whether it holds the source's triangles yet. Triangles are uploaded whole, 12
/// bytes a vertex relative to the eye, only when they changed.
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

    /// Uploads `frame`'s triangles if they `changed` (or none were uploaded yet), relative to the
    /// eye of `camera`; returns the bytes sent (0 when nothing changed).
    pub fn sync(&mut self, gpu: &Gpu, frame: Frame<'_>, changed: bool, camera: &Camera) -> Result<u64> {
        let Frame::Triangles(triangles) = frame else { return Err(wrong_frame("mesh")) };
        if self.loaded && !changed {
            return Ok(0);
        }
        let bytes = self.renderer.upload(gpu, triangles, camera.eye_in_world)?;
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
        self.renderer.encode(gpu, encoder, colour, depth, &self.renderer.view(&self.bounds, *camera), style)
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

/// Draws a mesh source's triangles offscreen.
pub struct MeshPresenter<'g> {
    gpu: &'g Gpu,
    target: Offscreen,
    pub stage: MeshStage,
    pub style: MeshStyle,
}

impl<'g> MeshPresenter<'g> {
    /// A `width_px` × `height_px` target for triangles within `bounds`, `up` up.
    pub fn new(
        gpu: &'g Gpu,
        bounds: Bounds,
        up: UpAxis,
        width_px: u32,
        height_px: u32,
        style: MeshStyle,
    ) -> Result<MeshPresenter<'g>> {
        let target = Offscreen::new(gpu, width_px, height_px)?;
        let stage = MeshStage::new(gpu, OFFSCREEN_FORMAT, bounds, up)?;
        Ok(MeshPresenter { gpu, target, stage, style })
    }

    /// The last image drawn.
    pub fn image(&self) -> Result<image::RgbaImage> {
        self.target.read_rgba(self.gpu)
    }
}

impl Presenter for MeshPresenter<'_> {
    fn present(&mut self, frame: Frame<'_>, changed: bool, camera: &Camera) -> Result<u64> {
        let gpu = self.gpu;
        let bytes = self.stage.sync(gpu, frame, changed, camera)?;
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let t = &self.target;
        let uniform_bytes = self.stage.encode(gpu, &mut encoder, &t.colour_view, &t.depth_view, camera, self.style);
        gpu.queue.submit([encoder.finish()]);
        gpu.wait_idle()?;
        Ok(bytes + uniform_bytes)
    }

    fn save(&mut self, path: &Path) -> Result<()> {
        save_png(&self.image()?, path)
    }

    fn adapter(&self) -> String {
        self.gpu.describe()
    }
}

/// Figures of one still image.
#[derive(Clone, Debug, Serialize)]
pub struct StillReport {
    pub triangles: u64,
    pub strip_len: u64,
    pub refine_ms: f64,
    pub render_ms: f64,
    /// CPU → GPU bytes of the frame: the strip and the frame uniform (the heights are uploaded
    /// once, see `heights_gpu_bytes`), and with the height cache the tiles the view wanted.
    pub upload_bytes: u64,
    pub heights_gpu_bytes: u64,
    /// Whether heights came from the height cache (the grid exceeds `--gpu-memory`).
    pub height_cache: bool,
    /// GPU bytes of the draped image (whole with its mip levels, or a tile file's slot pool and
    /// table), and for a tile file the tiles resident once the view settled (0 otherwise).
    pub imagery_gpu_bytes: u64,
    pub imagery_tiles_resident: u64,
    pub width: u32,
    pub height: u32,
    pub adapter: String,
}

/// How to draw a still: the style, the renderer's options (GPU height memory), refinement threads.
#[derive(Clone, Debug)]
pub struct StillOptions {
    pub style: DrawStyle,
    pub renderer: RendererOptions,
    pub threads: usize,
}

impl Default for StillOptions {
    fn default() -> Self {
        StillOptions { style: DrawStyle::default(), renderer: RendererOptions::default(), threads: 1 }
    }
}

/// Refines and renders one view of `terrain` offscreen; with the height cache, once the cache
/// holds what the view wants.
pub fn render_still(
    gpu: &Gpu,
    terrain: Arc<TerrainFile>,
    camera: &Camera,
    refine: &RefineOptions,
    still: StillOptions,
    progress: Progress,
) -> Result<(image::RgbaImage, StillReport)> {
    let StillOptions { style, renderer, threads } = still;
    let mut presenter =
        TerrainPresenter::new(gpu, terrain.clone(), camera.width_px, camera.height_px, style, renderer, progress)?;
    let refine = RefineOptions { heights: presenter.renderer.cached(), ..*refine };
    let mut source = TerrainSource::new(terrain, refine, threads, false)?;
    let stats = source.update(camera, refine.tolerance_px)?;
    let t0 = Instant::now();
    let upload_bytes = presenter.settle(source.strip(), camera)?;
    let render_ms = t0.elapsed().as_secs_f64() * 1e3;
    let image = presenter.image()?;
    let report = StillReport {
        triangles: presenter.renderer.triangles(),
        strip_len: stats.strip_len,
        refine_ms: stats.update_ms.unwrap_or(0.0),
        render_ms,
        upload_bytes,
        heights_gpu_bytes: presenter.renderer.heights_bytes(),
        height_cache: presenter.renderer.cached(),
        imagery_gpu_bytes: presenter.renderer.imagery_gpu_bytes(),
        imagery_tiles_resident: presenter.renderer.imagery_stats().tiles_resident,
        width: camera.width_px,
        height: camera.height_px,
        adapter: gpu.describe(),
    };
    Ok((image, report))
}
