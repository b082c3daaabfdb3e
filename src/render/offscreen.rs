//! Offscreen targets and readback: a colour + depth target drawn without a window and copied
//! back to memory (headless `relief render` and `relief fly --path`, golden-image tests), and the
//! float probe targets used to compare the GPU with the CPU reference.

use crate::error::{Error, Result};
use crate::render::gpu::Gpu;
use crate::render::pipeline::DEPTH_FORMAT;

/// Format of the two probe targets, see `fs_probe` and [`Probe`](crate::render::terrain::Probe).
pub const PROBE_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;

/// Colour format of offscreen images: 8-bit sRGB, what PNG stores.
pub const OFFSCREEN_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;

fn target(gpu: &Gpu, label: &str, w: u32, h: u32, format: wgpu::TextureFormat) -> wgpu::Texture {
    gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d { width: w, height: h, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
        view_formats: &[],
    })
}

/// A depth target for a `w × h` image.
pub fn depth_target(gpu: &Gpu, w: u32, h: u32) -> wgpu::Texture {
    target(gpu, "relief depth", w, h, DEPTH_FORMAT)
}

/// The depth attachment of a frame: cleared to 0, which is infinitely far with reversed z.
pub(crate) fn depth_clear(view: &wgpu::TextureView) -> wgpu::RenderPassDepthStencilAttachment<'_> {
    wgpu::RenderPassDepthStencilAttachment {
        view,
        depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(0.0), store: wgpu::StoreOp::Store }),
        stencil_ops: None,
    }
}

/// The render pass of a frame: `colour` cleared to black, `depth` to the far plane.
pub(crate) fn frame_pass<'e>(
    encoder: &'e mut wgpu::CommandEncoder,
    label: &str,
    colour: &wgpu::TextureView,
    depth: &wgpu::TextureView,
) -> wgpu::RenderPass<'e> {
    encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some(label),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: colour,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations { load: wgpu::LoadOp::Clear(wgpu::Color::BLACK), store: wgpu::StoreOp::Store },
        })],
        depth_stencil_attachment: Some(depth_clear(depth)),
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    })
}

/// Copies a whole 2-D texture with `bytes_per_texel` into memory, rows tightly packed.
fn read_texture(gpu: &Gpu, texture: &wgpu::Texture, bytes_per_texel: u32) -> Result<Vec<u8>> {
    let (w, h) = (texture.width(), texture.height());
    let row = w * bytes_per_texel;
    let padded = row.next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("relief readback"),
        size: padded as u64 * h as u64,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut encoder = gpu.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("readback") });
    encoder.copy_texture_to_buffer(
        texture.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &buffer,
            layout: wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(padded), rows_per_image: Some(h) },
        },
        texture.size(),
    );
    gpu.queue.submit([encoder.finish()]);
    let slice = buffer.slice(..);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    gpu.wait_idle()?;
    rx.recv()
        .map_err(|_| crate::app_error::gpu("readback was dropped"))?
        .map_err(|e| crate::app_error::gpu(format!("readback failed: {e}")))?;
    let mapped =
        slice.get_mapped_range().map_err(|e| crate::app_error::gpu(format!("readback mapping failed: {e}")))?;
    let mut out = Vec::with_capacity(row as usize * h as usize);
    for r in 0..h as usize {
        out.extend_from_slice(&mapped[r * padded as usize..r * padded as usize + row as usize]);
    }
    drop(mapped);
    buffer.unmap();
    Ok(out)
}

/// A colour and depth target of a fixed size, readable back as an RGBA image.
pub struct Offscreen {
    pub colour: wgpu::Texture,
    pub colour_view: wgpu::TextureView,
    pub depth: wgpu::Texture,
    pub depth_view: wgpu::TextureView,
}

impl Offscreen {
    pub fn new(gpu: &Gpu, width_px: u32, height_px: u32) -> Result<Offscreen> {
        Self::with_format(gpu, width_px, height_px, OFFSCREEN_FORMAT)
    }

    /// A target in `format`: 8-bit RGBA or BGRA (a window's format, so a renderer built for the
    /// window can draw a screenshot).
    pub fn with_format(gpu: &Gpu, width_px: u32, height_px: u32, format: wgpu::TextureFormat) -> Result<Offscreen> {
        use wgpu::TextureFormat::*;
        if !matches!(format, Rgba8Unorm | Rgba8UnormSrgb | Bgra8Unorm | Bgra8UnormSrgb) {
            return Err(crate::app_error::gpu(format!("cannot read back images in format {format:?}")));
        }
        let max = gpu.device.limits().max_texture_dimension_2d;
        if width_px == 0 || height_px == 0 || width_px > max || height_px > max {
            return Err(Error::InvalidArgument(format!(
                "image size {width_px} x {height_px} is outside 1 .. {max} pixels per side (the GPU's limit)"
            )));
        }
        let colour = target(gpu, "relief colour", width_px, height_px, format);
        let depth = depth_target(gpu, width_px, height_px);
        let colour_view = colour.create_view(&Default::default());
        let depth_view = depth.create_view(&Default::default());
        Ok(Offscreen { colour, colour_view, depth, depth_view })
    }

    pub fn width(&self) -> u32 {
        self.colour.width()
    }

    pub fn height(&self) -> u32 {
        self.colour.height()
    }

    /// Waits for the GPU and reads the colour target back.
    pub fn read_rgba(&self, gpu: &Gpu) -> Result<image::RgbaImage> {
        let mut bytes = read_texture(gpu, &self.colour, 4)?;
        if matches!(self.colour.format(), wgpu::TextureFormat::Bgra8Unorm | wgpu::TextureFormat::Bgra8UnormSrgb) {
            for px in bytes.chunks_exact_mut(4) {
                px.swap(0, 2);
            }
        }
        image::RgbaImage::from_raw(self.width(), self.height(), bytes)
            .ok_or_else(|| crate::app_error::gpu("readback has the wrong size"))
    }
}

/// The two float targets of the probe pass and their depth.
pub struct ProbeTargets {
    pub targets: [wgpu::Texture; 2],
    pub views: [wgpu::TextureView; 2],
    pub depth_view: wgpu::TextureView,
}

impl ProbeTargets {
    pub fn new(gpu: &Gpu, width_px: u32, height_px: u32) -> ProbeTargets {
        let targets =
            ["probe position", "probe value"].map(|label| target(gpu, label, width_px, height_px, PROBE_FORMAT));
        let views = [0, 1].map(|k| targets[k].create_view(&Default::default()));
        let depth_view = depth_target(gpu, width_px, height_px).create_view(&Default::default());
        ProbeTargets { targets, views, depth_view }
    }

    /// Reads target `k` back as `[f32; 4]` per pixel, row-major from the top-left.
    pub fn read(&self, gpu: &Gpu, k: usize) -> Result<Vec<[f32; 4]>> {
        let bytes = read_texture(gpu, &self.targets[k], 16)?;
        Ok(bytemuck::pod_collect_to_vec(&bytes))
    }
}
