//! The terrain renderer: owns `shaders/terrain.wgsl`, the resident heights, the strip buffers and
//! the pipelines (terrain, geomorphed terrain, wireframe, sky, and the probe used by tests).
//!
//! Per refinement update only the strip is uploaded: 8 bytes per vertex (grid x, y as `u32`), plus
//! 8 more with geomorphing (blend, morphed height). Per frame a 336-byte uniform follows the
//! camera. Positions are built in the vertex shader from the heights texture; the fragment shader
//! shades from the full-resolution heights (CPU reference: `render::shade`).

use std::sync::Arc;

use glam::DVec3;

use crate::camera::Camera;
use crate::error::Result;
use crate::format::terrain::TerrainFile;
use crate::heightcache::{CacheBudget, HeightCacheStats, WantView, DEFAULT_TILE_CELLS};
use crate::refine::{Morph, Strip, StripVertex};
use crate::render::gpu::Gpu;
use crate::render::height_cache::{GpuHeightCache, DEFAULT_GPU_MEMORY, DEFAULT_UPLOAD_PER_FRAME};
use crate::render::heights::{GpuHeights, HeightTiling};
use crate::render::imagery::{GpuImagery, Imagery, DEFAULT_IMAGERY_GPU_MEMORY};
use crate::render::offscreen::{depth_clear, frame_pass};
use crate::render::pipeline::{build_pipeline, depth_state, uniform_entry, PipelineSpec};
use crate::render::shade::{Look, ShadeParams};
use crate::render::vertex_buffer::VertexBuffer;
use crate::sys::progress::Progress;

pub use crate::render::offscreen::PROBE_FORMAT;
pub use crate::render::pipeline::DEPTH_FORMAT;

/// WGSL source of the terrain shaders.
pub const TERRAIN_WGSL: &str = include_str!("../../shaders/terrain.wgsl");

/// Bytes uploaded per strip vertex without and with geomorphing.
pub const VERTEX_BYTES: u64 = std::mem::size_of::<StripVertex>() as u64;
pub const MORPH_BYTES: u64 = std::mem::size_of::<Morph>() as u64;

/// The uniform block `Frame` of `terrain.wgsl` (same field order and padding).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct FrameUniform {
    clip_from_rel: [[f32; 4]; 4],
    rel_from_clip: [[f32; 4]; 4],
    eye_in_world: [f32; 4],
    world_from_grid: [f32; 4],
    z_min: f32,
    z_land_lo: f32,
    z_max: f32,
    fog_distance_m: f32,
    sun_dir: [f32; 4],
    tile_posts: u32,
    tiles_per_row: u32,
    posts: u32,
    flags: u32,
    wire_colour: [f32; 4],
    valid_window: [f32; 4],
    cache: [u32; 4],
    nodata: [u32; 4],
    looks: [f32; 4],
    /// Imagery: texture coordinates of grid posts (u = x0 + x1·gx, v = y0 + y1·gy).
    imagery_uv: [f32; 4],
    /// Imagery: (1 when draped, hillshade amount, 1 when u wraps, 1 when paged).
    imagery: [f32; 4],
    /// Paged imagery: (level-0 width, height, tile texels, levels).
    imagery_pages: [f32; 4],
}

/// What the probe pass writes to its second target (the first always holds grid x, grid y,
/// surface height and mesh height).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Probe {
    /// The shading normal (x, y, z, 1).
    Normal = 1,
    /// The shaded, fogged colour before sRGB encoding: linear (r, g, b, 1).
    Colour = 2,
}

/// Bytes of the per-frame uniform upload.
pub const FRAME_UNIFORM_BYTES: u64 = std::mem::size_of::<FrameUniform>() as u64;
// The figure README.md and ARCHITECTURE.md quote.
const _: () = assert!(FRAME_UNIFORM_BYTES == 336);

/// How to draw a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DrawStyle {
    /// Overlay the strip's edges (shows the level of detail).
    pub wireframe: bool,
}

/// A camera and the near plane to draw it with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameView {
    pub camera: Camera,
    pub near_m: f64,
}

impl FrameView {
    /// `camera` with the near plane [`near_plane_m`] picks for it over `terrain` drawn with
    /// heights `z_exaggeration` times as high.
    pub fn new(terrain: &TerrainFile, camera: Camera, z_exaggeration: f64) -> FrameView {
        FrameView { camera, near_m: near_plane_m(terrain, camera.eye_in_world, z_exaggeration) }
    }
}

/// How posts that were nodata in the DEM (the terrain file's void mask) are drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum NodataStyle {
    /// Not drawn: discarded like the padding around the DEM.
    #[default]
    Void,
    /// Calm water at the filled heights (voids that are sea, as in many coastal DEMs).
    SeaLevel,
    /// The heights filled in for the hierarchy, drawn as terrain.
    Filled,
}

impl NodataStyle {
    fn code(self) -> u32 {
        match self {
            NodataStyle::Filled => 0,
            NodataStyle::Void => 1,
            NodataStyle::SeaLevel => 2,
        }
    }
}

/// Options for building a renderer.
#[derive(Clone, Debug, Default)]
pub struct RendererOptions {
    /// How the DEM's nodata posts are drawn.
    pub nodata: NodataStyle,
    /// Force a heights tile size (posts per side); default: the least memory within the limits.
    pub tile_posts: Option<u32>,
    /// GPU memory for heights, bytes: the whole grid stays resident when it fits, else the height
    /// cache keeps within this. Default [`DEFAULT_GPU_MEMORY`].
    pub gpu_memory: Option<u64>,
    /// Height-tile bytes sent to the GPU per frame at most (cache only). Default
    /// [`DEFAULT_UPLOAD_PER_FRAME`].
    pub upload_per_frame: Option<u64>,
    /// The cache's tile side in cells (a power of two). Default [`DEFAULT_TILE_CELLS`].
    pub cache_tile_cells: Option<u32>,
    /// Ramp, sun and vertical exaggeration.
    pub look: Look,
    /// An image draped on the terrain, and how much of the hillshade lights it (0: the image
    /// as it is, 1: fully shaded).
    pub imagery: Option<(Arc<Imagery>, f32)>,
    /// GPU memory for a paged image's tiles, bytes. Default [`DEFAULT_IMAGERY_GPU_MEMORY`].
    pub imagery_gpu_memory: Option<u64>,
}

/// Where the shaders read heights from.
enum Heights {
    /// The whole grid, uploaded once.
    Resident(GpuHeights),
    /// Tiles paged in as the strip asks (the strip carries its own heights).
    Cached { pool: Box<GpuHeightCache>, terrain: Arc<TerrainFile>, tiling: HeightTiling },
}

/// Renders strips of one terrain.
pub struct TerrainRenderer {
    heights: Heights,
    /// Exact heights computed here for a strip that came without them (cache only).
    own_morph: Vec<Morph>,
    shade: ShadeParams,
    /// The DEM's posts in the grid, inclusive `[x0, y0, x1, y1]`.
    valid_window: [u32; 4],
    /// (style code, 1 when the file has a void mask, 0, 0); see `Frame.nodata` in the shader.
    nodata: [u32; 4],
    /// The draped image (a 1 × 1 texel without one): whole, or paged through its cache.
    imagery: GpuImagery,
    /// The void mask's bits (one word when the file has none), kept for the bind group.
    _void_mask: wgpu::Buffer,
    uniform: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    terrain_pipeline: wgpu::RenderPipeline,
    terrain_morph_pipeline: wgpu::RenderPipeline,
    /// Line strips over every vertex (edges i–i+1) and over every other vertex (edges i–i+2).
    wire_pipelines: [wgpu::RenderPipeline; 2],
    wire_morph_pipelines: [wgpu::RenderPipeline; 2],
    sky_pipeline: wgpu::RenderPipeline,
    overlay_pipeline: wgpu::RenderPipeline,
    /// World-space line segments drawn over the frame (see [`Self::set_overlay_lines`]).
    overlay: VertexBuffer,
    overlay_vertices: u32,
    probe_pipeline: wgpu::RenderPipeline,
    probe_morph_pipeline: wgpu::RenderPipeline,
    vertices: VertexBuffer,
    morph: VertexBuffer,
    strip_len: u32,
    strip_morph: bool,
    triangles: u64,
    /// Bytes of the last strip upload.
    last_upload_bytes: u64,
}

/// A read-only storage buffer of the fragment stage (the tables and the void mask). Fragment only:
/// a storage buffer read in the vertex stage made lavapipe's memory grow by ~100 KiB a frame
/// (tests/long_flight.rs).
fn fragment_storage(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn grid_layout(stride: u64) -> wgpu::VertexBufferLayout<'static> {
    const ATTR: [wgpu::VertexAttribute; 1] =
        [wgpu::VertexAttribute { format: wgpu::VertexFormat::Uint32x2, offset: 0, shader_location: 0 }];
    wgpu::VertexBufferLayout { array_stride: stride, step_mode: wgpu::VertexStepMode::Vertex, attributes: &ATTR }
}

fn morph_layout(stride: u64) -> wgpu::VertexBufferLayout<'static> {
    const ATTR: [wgpu::VertexAttribute; 1] =
        [wgpu::VertexAttribute { format: wgpu::VertexFormat::Float32x2, offset: 0, shader_location: 1 }];
    wgpu::VertexBufferLayout { array_stride: stride, step_mode: wgpu::VertexStepMode::Vertex, attributes: &ATTR }
}

impl TerrainRenderer {
    /// Uploads the heights of `terrain` and builds the pipelines for `colour_format`; GPU errors
    /// (too little memory, limits) come back as [`crate::AppError::Gpu`].
    pub fn new(
        gpu: &Gpu,
        terrain: &Arc<TerrainFile>,
        colour_format: wgpu::TextureFormat,
        options: RendererOptions,
        progress: Progress,
    ) -> Result<TerrainRenderer> {
        gpu.scoped("building the terrain renderer", || Self::build(gpu, terrain, colour_format, options, progress))
    }

    fn build(
        gpu: &Gpu,
        terrain: &Arc<TerrainFile>,
        colour_format: wgpu::TextureFormat,
        options: RendererOptions,
        progress: Progress,
    ) -> Result<TerrainRenderer> {
        let device = &gpu.device;
        let limits = device.limits();
        let posts = terrain.grid().size();
        let tiling = match options.tile_posts {
            Some(t) => {
                let t = HeightTiling::with_tile(posts, t);
                if t.tile_posts > limits.max_texture_dimension_2d || t.layers() > limits.max_texture_array_layers {
                    return Err(crate::Error::InvalidArgument(format!(
                        "heights tile of {} posts needs {} layers, over the GPU's limits",
                        t.tile_posts,
                        t.layers()
                    )));
                }
                t
            }
            None => HeightTiling::plan(posts, limits.max_texture_dimension_2d, limits.max_texture_array_layers)
                .unwrap_or(HeightTiling::with_tile(posts, limits.max_texture_dimension_2d)),
        };
        let budget = options.gpu_memory.unwrap_or(DEFAULT_GPU_MEMORY);
        let fits = tiling.tile_posts <= limits.max_texture_dimension_2d
            && tiling.layers() <= limits.max_texture_array_layers
            && tiling.bytes() <= budget;
        let heights = if fits {
            // A budget the adapter cannot honour fails here: say what would help.
            let what = format!(
                "making the whole {posts}² grid resident ({} bytes of GPU heights; a smaller GPU memory \
                 budget pages it through the height cache instead)",
                tiling.bytes()
            );
            Heights::Resident(gpu.scoped(&what, || GpuHeights::upload(device, &gpu.queue, terrain, tiling, progress))?)
        } else {
            let budget = CacheBudget {
                gpu_bytes: budget,
                upload_bytes_per_frame: options.upload_per_frame.unwrap_or(DEFAULT_UPLOAD_PER_FRAME),
                max_slots: limits.max_texture_array_layers,
            };
            let tile = options.cache_tile_cells.unwrap_or(DEFAULT_TILE_CELLS);
            let pool = GpuHeightCache::new(device, terrain.clone(), tile, budget)?;
            Heights::Cached { pool: Box::new(pool), terrain: terrain.clone(), tiling }
        };
        let h = terrain.header();
        let shade = ShadeParams::for_terrain(h.spacing_m, posts, h.z_min, h.z_max).with_look(&options.look);

        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("terrain.wgsl"),
            source: wgpu::ShaderSource::Wgsl(TERRAIN_WGSL.into()),
        });
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("relief frame"),
            size: FRAME_UNIFORM_BYTES,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("relief frame"),
            entries: &[
                uniform_entry(FRAME_UNIFORM_BYTES),
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                fragment_storage(2),
                fragment_storage(3),
                wgpu::BindGroupLayoutEntry {
                    binding: 4,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2Array,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 5,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
                fragment_storage(6),
            ],
        });
        // The draped image with its mip levels, or its tile cache, or one texel when there is none.
        let imagery_budget = CacheBudget {
            gpu_bytes: options.imagery_gpu_memory.unwrap_or(DEFAULT_IMAGERY_GPU_MEMORY),
            upload_bytes_per_frame: options.upload_per_frame.unwrap_or(DEFAULT_UPLOAD_PER_FRAME),
            max_slots: limits.max_texture_array_layers,
        };
        let imagery = GpuImagery::new(gpu, terrain, options.imagery.as_ref(), imagery_budget)?;
        // The void mask as 32-bit words (its bytes are little-endian bit order already).
        let mask = if options.nodata == NodataStyle::Filled { None } else { terrain.void_mask()? };
        let mut words = vec![0u32; 1];
        if let Some(m) = &mask {
            words = vec![0u32; m.bits.len().div_ceil(4).max(1)];
            bytemuck::cast_slice_mut::<u32, u8>(&mut words)[..m.bits.len()].copy_from_slice(&m.bits);
            let bytes = 4 * words.len() as u64;
            if bytes > limits.max_storage_buffer_binding_size {
                return Err(crate::Error::InvalidArgument(format!(
                    "{}: the void mask ({bytes} bytes) is over the GPU's storage buffer limit ({} bytes); \
                     draw nodata as filled terrain",
                    terrain.path().display(),
                    limits.max_storage_buffer_binding_size
                )));
            }
        }
        let void_mask = {
            use wgpu::util::DeviceExt;
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("relief void mask"),
                contents: bytemuck::cast_slice(&words),
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        let nodata = [options.nodata.code(), u32::from(mask.is_some()), 0, 0];
        // Without the cache the table is never read; a small buffer fills the binding.
        let no_table = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("relief height table (unused)"),
            size: 4 * crate::heightcache::TABLE_HEADER as u64,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        let (heights_view, table) = match &heights {
            Heights::Resident(h) => (&h.view, &no_table),
            Heights::Cached { pool, .. } => (&pool.view, &pool.table),
        };
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("relief frame"),
            layout: &bind_layout,
            entries: &[
                wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(heights_view) },
                wgpu::BindGroupEntry { binding: 2, resource: table.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 3, resource: void_mask.as_entire_binding() },
                wgpu::BindGroupEntry { binding: 4, resource: wgpu::BindingResource::TextureView(&imagery.view) },
                wgpu::BindGroupEntry { binding: 5, resource: wgpu::BindingResource::Sampler(&imagery.sampler) },
                wgpu::BindGroupEntry { binding: 6, resource: imagery.table().as_entire_binding() },
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("relief"),
            bind_group_layouts: &[Some(&bind_layout)],
            immediate_size: 0,
        });

        let depth = |write: bool, compare: wgpu::CompareFunction| {
            // Triangles are pushed back (reversed z: towards 0) by their depth slope, so the
            // wireframe drawn over them wins the depth test even at grazing angles.
            let bias = if write {
                wgpu::DepthBiasState { constant: -4, slope_scale: -1.5, clamp: 0.0 }
            } else {
                wgpu::DepthBiasState::default()
            };
            depth_state(write, compare, bias)
        };
        let colour_target =
            [Some(wgpu::ColorTargetState { format: colour_format, blend: None, write_mask: wgpu::ColorWrites::ALL })];
        let probe_targets = [0; 2].map(|_| {
            Some(wgpu::ColorTargetState { format: PROBE_FORMAT, blend: None, write_mask: wgpu::ColorWrites::ALL })
        });
        let pipeline = |label: &str,
                        vs: &str,
                        buffers: &[Option<wgpu::VertexBufferLayout>],
                        topology: wgpu::PrimitiveTopology,
                        depth_stencil: Option<wgpu::DepthStencilState>,
                        fs: &str,
                        targets: &[Option<wgpu::ColorTargetState>]| {
            // Strips alternate winding; the shaders do not look at front_facing.
            let front_face = wgpu::FrontFace::Cw;
            let spec = PipelineSpec { label, vs, buffers, topology, front_face, depth_stencil, fs, targets };
            build_pipeline(device, &layout, &module, spec)
        };
        use wgpu::CompareFunction::{Equal, Greater, GreaterEqual};
        use wgpu::PrimitiveTopology::{LineStrip, TriangleList, TriangleStrip};
        let (v1, v2) = (VERTEX_BYTES, 2 * VERTEX_BYTES);
        let (m1, m2) = (MORPH_BYTES, 2 * MORPH_BYTES);
        // A strip's two pipelines for a fragment entry: heights from the resident grid, or carried
        // by the strip (geomorphing, the height cache).
        let strip_pipelines = |label: &str, fs: &str, targets: &[Option<wgpu::ColorTargetState>]| {
            [
                ("vs_terrain", vec![Some(grid_layout(v1))]),
                ("vs_terrain_morph", vec![Some(grid_layout(v1)), Some(morph_layout(m1))]),
            ]
            .map(|(vs, buffers)| pipeline(label, vs, &buffers, TriangleStrip, depth(true, Greater), fs, targets))
        };
        let [terrain_pipeline, terrain_morph_pipeline] = strip_pipelines("terrain", "fs_terrain", &colour_target);
        let wire_pipelines = [v1, v2].map(|stride| {
            pipeline(
                "wire",
                "vs_wire",
                &[Some(grid_layout(stride))],
                LineStrip,
                depth(false, GreaterEqual),
                "fs_wire",
                &colour_target,
            )
        });
        let wire_morph_pipelines = [(v1, m1), (v2, m2)].map(|(sv, sm)| {
            pipeline(
                "wire morph",
                "vs_wire_morph",
                &[Some(grid_layout(sv)), Some(morph_layout(sm))],
                LineStrip,
                depth(false, GreaterEqual),
                "fs_wire",
                &colour_target,
            )
        });
        // The sky fills what the terrain left at the cleared (infinite) depth.
        let sky_pipeline = pipeline("sky", "vs_sky", &[], TriangleList, depth(false, Equal), "fs_sky", &colour_target);
        const OVERLAY_ATTR: [wgpu::VertexAttribute; 1] =
            [wgpu::VertexAttribute { format: wgpu::VertexFormat::Float32x3, offset: 0, shader_location: 0 }];
        let overlay_layout = wgpu::VertexBufferLayout {
            array_stride: 12,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &OVERLAY_ATTR,
        };
        let overlay_pipeline = pipeline(
            "overlay",
            "vs_overlay",
            &[Some(overlay_layout)],
            wgpu::PrimitiveTopology::LineList,
            depth(false, wgpu::CompareFunction::Always),
            "fs_overlay",
            &colour_target,
        );
        let [probe_pipeline, probe_morph_pipeline] = strip_pipelines("probe", "fs_probe", &probe_targets);

        let vertices = VertexBuffer::new(device, "relief strip", 1 << 20);
        let morph = VertexBuffer::new(device, "relief strip morph", 1 << 20);
        Ok(TerrainRenderer {
            heights,
            own_morph: Vec::new(),
            shade,
            valid_window: {
                let [x0, y0, x1, y1] = h.valid_window;
                [x0, y0, x1 - 1, y1 - 1]
            },
            nodata,
            _void_mask: void_mask,
            imagery,
            uniform,
            bind_group,
            terrain_pipeline,
            terrain_morph_pipeline,
            wire_pipelines,
            wire_morph_pipelines,
            sky_pipeline,
            overlay_pipeline,
            overlay: VertexBuffer::new(device, "relief overlay", 256),
            overlay_vertices: 0,
            probe_pipeline,
            probe_morph_pipeline,
            vertices,
            morph,
            strip_len: 0,
            strip_morph: false,
            triangles: 0,
            last_upload_bytes: 0,
        })
    }

    /// The whole grid's tiling (what is resident without the cache).
    pub fn tiling(&self) -> HeightTiling {
        match &self.heights {
            Heights::Resident(h) => h.tiling,
            Heights::Cached { tiling, .. } => *tiling,
        }
    }

    /// GPU memory taken by the heights, bytes: the whole grid, or the cache's pool and table.
    pub fn heights_bytes(&self) -> u64 {
        match &self.heights {
            Heights::Resident(h) => h.tiling.bytes(),
            Heights::Cached { pool, .. } => pool.cache.pool_bytes(),
        }
    }

    /// Whether heights come from the cache (the grid does not fit the GPU memory budget).
    pub fn cached(&self) -> bool {
        matches!(self.heights, Heights::Cached { .. })
    }

    /// The height cache's figures of the last frame (the whole grid when resident).
    pub fn height_stats(&self) -> HeightCacheStats {
        match &self.heights {
            Heights::Resident(h) => HeightCacheStats {
                cached: false,
                budget_bytes: h.tiling.bytes(),
                in_use_bytes: h.tiling.bytes(),
                tiles_resident: h.tiling.layers() as u64,
                ..Default::default()
            },
            Heights::Cached { pool, .. } => pool.stats(),
        }
    }

    /// The height cache, if heights come from one (tests and the panel).
    pub fn height_cache(&self) -> Option<&crate::heightcache::HeightCache> {
        match &self.heights {
            Heights::Cached { pool, .. } => Some(&pool.cache),
            Heights::Resident(_) => None,
        }
    }

    /// The height cache's step for a frame seen by `camera`: tells the loader about `new_strip`
    /// (the strip just uploaded, if it changed), then writes the finished tiles that fit the
    /// upload budget, never waiting for the loader. Returns the bytes sent (0 without the cache).
    pub fn sync_heights(&mut self, gpu: &Gpu, camera: &Camera, new_strip: Option<&Strip>) -> Result<u64> {
        // In the scene scaled by 1 / exaggeration, where the heights are the file's (as the
        // refinement sees it).
        let x = self.shade.z_exaggeration;
        let scaled =
            Camera { eye_in_world: camera.eye_in_world / x, look_at_world: camera.look_at_world / x, ..*camera };
        let [sx, sy] = self.shade.spacing_m;
        let view = WantView::new(&scaled, [sx / x, sy / x]);
        let mut bytes = 0;
        if let Heights::Cached { pool, .. } = &mut self.heights {
            if let Some(strip) = new_strip {
                let heights = if strip.morph.len() == strip.vertices.len() { &strip.morph } else { &self.own_morph };
                pool.want(&strip.vertices, heights, view);
            }
            bytes += pool.sync(&gpu.queue)?;
        }
        if self.imagery.paged() {
            let heights = match (&self.heights, new_strip) {
                (Heights::Cached { .. }, Some(s)) if s.morph.len() != s.vertices.len() => &self.own_morph[..],
                (_, Some(s)) => &s.morph[..],
                (_, None) => &[],
            };
            let strip = new_strip.map(|s| (&s.vertices[..], heights));
            bytes += self.imagery.sync(&gpu.queue, strip, view)?;
        }
        Ok(bytes)
    }

    /// GPU bytes the draped image takes (see [`GpuImagery::gpu_bytes`]).
    pub fn imagery_gpu_bytes(&self) -> u64 {
        self.imagery.gpu_bytes()
    }

    /// The imagery cache's figures of the last frame (zero when the image is whole or absent).
    pub fn imagery_stats(&self) -> HeightCacheStats {
        self.imagery.stats()
    }

    /// Whether the draped image's wanted tiles are all resident and blended in (always when
    /// whole).
    pub fn imagery_converged(&self) -> bool {
        self.imagery.converged()
    }

    /// Draws with `look` from the next frame on (the caller refines with its exaggeration).
    pub fn set_look(&mut self, look: &Look) {
        self.shade = self.shade.with_look(look);
    }

    pub fn shade_params(&self) -> &ShadeParams {
        &self.shade
    }

    /// Uploads a new strip (and its geomorph values, if any); returns the bytes sent. With the
    /// height cache every vertex needs its height: a strip without them (refined without
    /// [`crate::refine::RefineOptions::heights`]) has them read from the file here.
    pub fn upload_strip(&mut self, gpu: &Gpu, strip: &Strip) -> Result<u64> {
        let vbytes: &[u8] = bytemuck::cast_slice(&strip.vertices);
        self.vertices.write(&gpu.device, &gpu.queue, vbytes);
        let mut morph = !strip.morph.is_empty() && strip.morph.len() == strip.vertices.len();
        let mut own = false;
        if let (false, Heights::Cached { terrain, .. }) = (morph, &self.heights) {
            crate::heightcache::exact_heights(terrain, &strip.vertices, &mut self.own_morph)?;
            (morph, own) = (true, true);
        }
        let mbytes: &[u8] = match (morph, own) {
            (true, false) => bytemuck::cast_slice(&strip.morph),
            (true, true) => bytemuck::cast_slice(&self.own_morph),
            _ => &[],
        };
        self.morph.write(&gpu.device, &gpu.queue, mbytes);
        self.strip_len = u32::try_from(strip.vertices.len()).unwrap_or(u32::MAX);
        self.strip_morph = morph;
        self.triangles = strip.triangle_counts().0;
        self.last_upload_bytes = (vbytes.len() + mbytes.len()) as u64;
        Ok(self.last_upload_bytes)
    }

    /// Line segments (world metres) to draw over the next frames; empty to clear. Positions are
    /// sent as f32, so keep them within a few hundred kilometres of the eye.
    pub fn set_overlay_lines(&mut self, gpu: &Gpu, lines: &[[glam::DVec3; 2]]) {
        let v: Vec<[f32; 3]> = lines.iter().flatten().map(|p| p.as_vec3().to_array()).collect();
        self.overlay.write(&gpu.device, &gpu.queue, bytemuck::cast_slice(&v));
        self.overlay_vertices = v.len() as u32;
    }

    /// Bytes of the last strip upload.
    pub fn last_upload_bytes(&self) -> u64 {
        self.last_upload_bytes
    }

    pub fn strip_len(&self) -> u32 {
        self.strip_len
    }

    /// Non-degenerate triangles of the current strip.
    pub fn triangles(&self) -> u64 {
        self.triangles
    }

    /// The frame uniform for `camera` with near plane `near_m`.
    fn frame_uniform(&self, camera: &Camera, near_m: f64, flags: u32) -> FrameUniform {
        let clip_from_rel = camera.clip_from_rel(near_m);
        let s = &self.shade;
        let t = self.tiling();
        let cache = match &self.heights {
            Heights::Resident(_) => [0; 4],
            Heights::Cached { pool, .. } => [1, pool.cache.grid().tile_cells(), pool.cache.grid().levels(), 0],
        };
        let e = camera.eye_in_world.as_vec3();
        FrameUniform {
            clip_from_rel: clip_from_rel.to_cols_array_2d(),
            rel_from_clip: clip_from_rel.inverse().to_cols_array_2d(),
            eye_in_world: [e.x, e.y, e.z, 1.0],
            world_from_grid: [s.spacing_m[0] as f32, s.spacing_m[1] as f32, (s.posts - 1) as f32, 0.0],
            z_min: s.z_min as f32,
            z_land_lo: s.z_land_lo as f32,
            z_max: s.z_max as f32,
            fog_distance_m: s.fog_distance_m as f32,
            sun_dir: [s.sun_dir.x as f32, s.sun_dir.y as f32, s.sun_dir.z as f32, 0.0],
            tile_posts: t.tile_posts,
            tiles_per_row: t.tiles_per_row,
            posts: t.posts,
            flags,
            wire_colour: [0.02, 0.02, 0.03, 1.0],
            valid_window: self.valid_window.map(|v| v as f32),
            cache,
            nodata: self.nodata,
            looks: [s.z_exaggeration as f32, s.ramp.code() as f32, 0.0, 0.0],
            imagery_uv: self.imagery.uv,
            imagery: self.imagery.params,
            imagery_pages: self.imagery.pages,
        }
    }

    /// Records a frame of `view`: terrain, optional wireframe, then sky, into `colour` and
    /// `depth` (both cleared). Returns the uniform bytes written.
    pub fn encode(
        &self,
        gpu: &Gpu,
        encoder: &mut wgpu::CommandEncoder,
        colour: &wgpu::TextureView,
        depth: &wgpu::TextureView,
        view: &FrameView,
        style: DrawStyle,
    ) -> u64 {
        let uniform = self.frame_uniform(&view.camera, view.near_m, 0);
        gpu.queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&uniform));
        let mut pass = frame_pass(encoder, "relief frame", colour, depth);
        pass.set_bind_group(0, &self.bind_group, &[]);
        let n = self.strip_len;
        if n >= 3 {
            let vb = self.vertices.buffer.slice(..n as u64 * VERTEX_BYTES);
            let mb = self.morph.buffer.slice(..if self.strip_morph { n as u64 * MORPH_BYTES } else { 0 });
            if self.strip_morph {
                pass.set_pipeline(&self.terrain_morph_pipeline);
                pass.set_vertex_buffer(1, mb);
            } else {
                pass.set_pipeline(&self.terrain_pipeline);
            }
            pass.set_vertex_buffer(0, vb);
            pass.draw(0..n, 0..1);
            if style.wireframe {
                let pipes = if self.strip_morph { &self.wire_morph_pipelines } else { &self.wire_pipelines };
                // Edges (i, i+1): one line strip over all vertices.
                pass.set_pipeline(&pipes[0]);
                pass.draw(0..n, 0..1);
                // Edges (i, i+2): line strips over the even and the odd vertices (stride 2).
                pass.set_pipeline(&pipes[1]);
                for start in 0..2u64 {
                    let count = ((n as u64 - start).div_ceil(2)) as u32;
                    pass.set_vertex_buffer(
                        0,
                        self.vertices.buffer.slice(start * VERTEX_BYTES..n as u64 * VERTEX_BYTES),
                    );
                    if self.strip_morph {
                        pass.set_vertex_buffer(1, self.morph.buffer.slice(start * MORPH_BYTES..n as u64 * MORPH_BYTES));
                    }
                    pass.draw(0..count, 0..1);
                }
            }
        }
        pass.set_pipeline(&self.sky_pipeline);
        pass.draw(0..3, 0..1);
        if self.overlay_vertices > 0 {
            pass.set_pipeline(&self.overlay_pipeline);
            pass.set_vertex_buffer(0, self.overlay.buffer.slice(..self.overlay_vertices as u64 * 12));
            pass.draw(0..self.overlay_vertices, 0..1);
        }
        FRAME_UNIFORM_BYTES
    }

    /// Records the probe pass (what `fs_terrain` computes, as floats) into two [`PROBE_FORMAT`]
    /// targets: (grid x, grid y, surface height, mesh height) and what `probe` asks for. Pixels
    /// the terrain does not cover keep (0, 0, 0, 0). Submit before recording another probe: the
    /// uniform is written at submission.
    pub fn encode_probe(
        &self,
        gpu: &Gpu,
        encoder: &mut wgpu::CommandEncoder,
        targets: [&wgpu::TextureView; 2],
        depth: &wgpu::TextureView,
        view: &FrameView,
        probe: Probe,
    ) {
        let uniform = self.frame_uniform(&view.camera, view.near_m, probe as u32);
        gpu.queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&uniform));
        let attachments = targets.map(|view| {
            Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                    store: wgpu::StoreOp::Store,
                },
            })
        });
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("relief probe"),
            color_attachments: &attachments,
            depth_stencil_attachment: Some(depth_clear(depth)),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        if self.strip_len >= 3 {
            pass.set_bind_group(0, &self.bind_group, &[]);
            let n = self.strip_len as u64;
            if self.strip_morph {
                pass.set_pipeline(&self.probe_morph_pipeline);
                pass.set_vertex_buffer(1, self.morph.buffer.slice(..n * MORPH_BYTES));
            } else {
                pass.set_pipeline(&self.probe_pipeline);
            }
            pass.set_vertex_buffer(0, self.vertices.buffer.slice(..n * VERTEX_BYTES));
            pass.draw(0..self.strip_len, 0..1);
        }
    }
}

/// A near plane for an eye: a quarter of a lower bound on its distance to the terrain (so the
/// ground is never clipped), between 5 cm and 1 km. Reversed-z f32 depth keeps precision to the
/// horizon whatever this is.
pub fn near_plane_m(terrain: &TerrainFile, eye_in_world: DVec3, z_exaggeration: f64) -> f64 {
    let h = terrain.header();
    let last = terrain.grid().max_coord();
    let (ex, ey) = (eye_in_world.x / h.spacing_m[0], eye_in_world.y / h.spacing_m[1]);
    let x = z_exaggeration;
    let above_all = eye_in_world.z - h.z_max * x;
    let bound = if ex >= 0.0 && ey >= 0.0 && ex <= last as f64 && ey <= last as f64 {
        // Above the grid: height over the highest post of the cell around the eye.
        let (x0, y0) = ((ex.floor() as u32).min(last - 1), (ey.floor() as u32).min(last - 1));
        let ground = [(0, 0), (1, 0), (0, 1), (1, 1)]
            .iter()
            .map(|&(dx, dy)| terrain.height_at(x0 + dx, y0 + dy).map_or(h.z_max, |z| z as f64) * x)
            .fold(f64::MIN, f64::max);
        (eye_in_world.z - ground).max(above_all)
    } else {
        // Beside the grid: at least the horizontal distance to its edge.
        let dx = (-ex).max(ex - last as f64).max(0.0) * h.spacing_m[0];
        let dy = (-ey).max(ey - last as f64).max(0.0) * h.spacing_m[1];
        dx.hypot(dy).max(above_all)
    };
    (bound * 0.25).clamp(0.05, 1000.0)
}
