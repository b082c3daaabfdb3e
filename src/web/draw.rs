//! The web viewer's renderer: one pipeline (`shaders/web.wgsl`) that draws the refinement's
//! triangle strip, positioned on the CPU, into any colour target: the page's canvas (WebGL2)
//! or, natively, an offscreen texture (the tests' reference image of the same view). Within
//! WebGL2's limits: a uniform block and a vertex buffer, nothing else.

use glam::{DVec3, Mat4, Vec4};

use relief_core::camera::Camera;

/// The shader, beside its owner.
pub const SHADER: &str = include_str!("../../shaders/web.wgsl");

/// Reversed-z depth in f32, as the native renderer uses (precision from a metre to the horizon).
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// The sky, linear RGB (the shader's `SKY`): the clear colour and the fog's.
pub const SKY: [f32; 3] = [0.53, 0.70, 0.88];

/// The nearest any camera sees, metres.
pub const NEAR_M: f64 = 1.0;

/// The near plane for a view `distance_m` from what it looks at: a thousandth of it, at least
/// [`NEAR_M`]. WebGL maps depth to [−1, 1], so reversed z near 0 loses the precision it has in
/// [0, 1]; a near plane that keeps `near / distance` well above f32's step at 1 keeps depth
/// ordered from a metre above Zürich to the whole globe.
pub fn near_for(distance_m: f64) -> f64 {
    (1e-3 * distance_m).max(NEAR_M)
}

/// The uniform block `Frame` of `shaders/web.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct FrameUniform {
    pub clip_from_rel: [[f32; 4]; 4],
    pub eye_in_scene: [f32; 4],
    pub sun_dir: [f32; 4],
    /// z_lo, z_hi (scene metres), fog distance (m), 1 when the target is not sRGB.
    pub ramp: [f32; 4],
    /// 1 when an image is draped, how much the hillshade lights it (0..1), 1 when u wraps, 0.
    pub imagery: [f32; 4],
}

/// What a frame is drawn with: the camera in scene coordinates (metres, z exaggerated), where the
/// scene origin is, the height ramp and the fog.
#[derive(Clone, Copy, Debug)]
pub struct Look {
    /// Scene coordinates of the vertex buffer's origin (the grid's centre at z = 0).
    pub origin_in_scene: DVec3,
    /// Heights the colour ramp spans, scene metres.
    pub z_lo: f64,
    pub z_hi: f64,
    /// Distance at which the terrain has faded into the sky, metres.
    pub fog_distance_m: f64,
}

impl FrameUniform {
    /// The uniform for `camera` (scene coordinates, near plane `near_m`: see [`near_for`]) under
    /// `look`, for a target that is sRGB (`srgb_target`) or not.
    pub fn new(camera: &Camera, look: &Look, near_m: f64, srgb_target: bool) -> FrameUniform {
        let clip = camera.clip_from_rel(near_m.max(NEAR_M));
        let eye = (camera.eye_in_world - look.origin_in_scene).as_vec3();
        let sun = glam::Vec3::new(-0.45, 0.35, 0.82).normalize();
        FrameUniform {
            clip_from_rel: clip.to_cols_array_2d(),
            eye_in_scene: Vec4::from((eye, 0.0)).to_array(),
            sun_dir: Vec4::from((sun, 0.0)).to_array(),
            ramp: [
                (look.z_lo - look.origin_in_scene.z) as f32,
                (look.z_hi - look.origin_in_scene.z) as f32,
                look.fog_distance_m as f32,
                if srgb_target { 0.0 } else { 1.0 },
            ],
            imagery: [0.0; 4],
        }
    }

    /// With an image draped, lit by the hillshade `shade` (0..1), u wrapping or not.
    pub fn with_imagery(mut self, shade: f32, wraps: bool) -> FrameUniform {
        self.imagery = [1.0, shade.clamp(0.0, 1.0), if wraps { 1.0 } else { 0.0 }, 0.0];
        self
    }

    /// The matrix, as glam's.
    pub fn clip_from_rel(&self) -> Mat4 {
        Mat4::from_cols_array_2d(&self.clip_from_rel)
    }
}

/// CPU reference of the shader's `shade` (linear RGB): a facet with unit normal `n` at scene
/// height `z` (relative to the origin), `d` metres from the eye, under the draped image's
/// colour `image` (linear; used where the uniform says an image is draped).
pub fn shade(u: &FrameUniform, n: [f32; 3], z: f32, d: f32, image: [f32; 3]) -> [f32; 3] {
    let c0 = [0.13, 0.30, 0.10];
    let c1 = [0.42, 0.36, 0.18];
    let c2 = [0.45, 0.43, 0.40];
    let c3 = [0.92, 0.92, 0.95];
    let mix = |a: [f32; 3], b: [f32; 3], t: f32| [0, 1, 2].map(|i| a[i] + (b[i] - a[i]) * t);
    let t = (z - u.ramp[0]) / (u.ramp[1] - u.ramp[0]).max(1e-3);
    let s = t.clamp(0.0, 1.0) * 3.0;
    let ramp = if s < 1.0 {
        mix(c0, c1, s)
    } else if s < 2.0 {
        mix(c1, c2, s - 1.0)
    } else {
        mix(c2, c3, s - 2.0)
    };
    let sun = u.sun_dir;
    let light = 0.25 + 0.75 * (n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2]).max(0.0);
    let fog = (d / u.ramp[2]).clamp(0.0, 1.0);
    let c = if u.imagery[0] > 0.5 {
        let k = 1.0 + (light - 1.0) * u.imagery[1];
        image.map(|c| c * k)
    } else {
        ramp.map(|c| c * light)
    };
    mix(c, SKY, fog * fog)
}

/// A strip vertex as the shader takes it: scene metres relative to the origin, and where the
/// draped image is (u, v; unused without one).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Vertex {
    pub in_scene: [f32; 3],
    pub uv: [f32; 2],
}

/// A 2D texture of `width × height` texels with `mips` levels.
fn texture_2d(
    device: &wgpu::Device,
    label: &str,
    (width, height): (u32, u32),
    mips: u32,
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
        mip_level_count: mips,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    })
}

/// An sRGB texture holding `levels` (finest first, at least one), for sampling.
fn upload_levels(device: &wgpu::Device, queue: &wgpu::Queue, label: &str, levels: &[Level]) -> wgpu::Texture {
    let (w, h) = levels.first().map_or((1, 1), |l| (l.0, l.1));
    let usage = wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST;
    let texture =
        texture_2d(device, label, (w, h), levels.len().max(1) as u32, wgpu::TextureFormat::Rgba8UnormSrgb, usage);
    for (k, (lw, lh, rgba)) in levels.iter().enumerate() {
        queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &texture,
                mip_level: k as u32,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            rgba,
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(lw * 4), rows_per_image: Some(*lh) },
            wgpu::Extent3d { width: *lw, height: *lh, depth_or_array_layers: 1 },
        );
    }
    texture
}

/// One opaque white texel: the image bound when none is draped.
fn white_texel(device: &wgpu::Device, queue: &wgpu::Queue) -> wgpu::Texture {
    upload_levels(device, queue, "relief web no imagery", &[(1, 1, vec![255; 4])])
}

/// A texture with its trilinear sampler (u repeating where it `wraps`).
fn image_texture(device: &wgpu::Device, texture: wgpu::Texture, wraps: bool) -> (wgpu::Texture, wgpu::Sampler) {
    let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
        label: Some("relief web imagery"),
        address_mode_u: if wraps { wgpu::AddressMode::Repeat } else { wgpu::AddressMode::ClampToEdge },
        address_mode_v: wgpu::AddressMode::ClampToEdge,
        mag_filter: wgpu::FilterMode::Linear,
        min_filter: wgpu::FilterMode::Linear,
        mipmap_filter: wgpu::MipmapFilterMode::Linear,
        ..Default::default()
    });
    (texture, sampler)
}

/// The frame's bind group: the uniform, the image and its sampler.
fn bind(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    uniform: &wgpu::Buffer,
    (texture, sampler): &(wgpu::Texture, wgpu::Sampler),
) -> wgpu::BindGroup {
    let view = texture.create_view(&Default::default());
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("relief web frame"),
        layout,
        entries: &[
            wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 1, resource: wgpu::BindingResource::TextureView(&view) },
            wgpu::BindGroupEntry { binding: 2, resource: wgpu::BindingResource::Sampler(sampler) },
        ],
    })
}

/// One mip level of an image: width, height, RGBA8 sRGB rows from the top.
pub type Level = (u32, u32, Vec<u8>);

/// An image's mip levels, finest first, each half the last (box filter over sRGB bytes, as
/// both the page and the native reference compute them), down to 1 × 1.
pub fn mip_levels(width: u32, height: u32, rgba: Vec<u8>) -> Vec<Level> {
    let mut levels = vec![(width, height, rgba)];
    loop {
        let (w, h, last) = levels.last().expect("one level");
        let (w, h) = (*w, *h);
        if w <= 1 && h <= 1 {
            break;
        }
        let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
        let mut next = vec![0u8; (nw * nh * 4) as usize];
        for y in 0..nh {
            for x in 0..nw {
                for c in 0..4 {
                    let mut sum = 0u32;
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (sx, sy) = ((2 * x + dx).min(w - 1), (2 * y + dy).min(h - 1));
                        sum += last[((sy * w + sx) * 4 + c) as usize] as u32;
                    }
                    next[((y * nw + x) * 4 + c) as usize] = ((sum + 2) / 4) as u8;
                }
            }
        }
        levels.push((nw, nh, next));
    }
    levels
}

/// The pipeline, its uniform and the strip's vertex buffer.
pub struct Renderer {
    pipeline: wgpu::RenderPipeline,
    uniform: wgpu::Buffer,
    group_layout: wgpu::BindGroupLayout,
    bind_group: wgpu::BindGroup,
    /// The draped image (one texel when there is none) and its sampler.
    image: (wgpu::Texture, wgpu::Sampler),
    vertices: Option<wgpu::Buffer>,
    vertex_count: u32,
    depth: Option<(wgpu::TextureView, u32, u32)>,
    srgb_target: bool,
}

impl Renderer {
    /// The pipeline for colour targets of `format`.
    pub fn new(device: &wgpu::Device, queue: &wgpu::Queue, format: wgpu::TextureFormat) -> Renderer {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("relief web terrain"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let layout_entry = wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<FrameUniform>() as u64),
            },
            count: None,
        };
        let group_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("relief web frame"),
            entries: &[
                layout_entry,
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: true },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                    count: None,
                },
            ],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("relief web"),
            bind_group_layouts: &[Some(&group_layout)],
            immediate_size: 0,
        });
        let attributes = wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x2];
        let buffers = [Some(wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<Vertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &attributes,
        })];
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("relief web terrain"),
            layout: Some(&layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_terrain"),
                compilation_options: Default::default(),
                buffers: &buffers,
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleStrip,
                strip_index_format: None,
                front_face: wgpu::FrontFace::Cw,
                // Terrain is seen from below under cliffs: both faces.
                cull_mode: None,
                unclipped_depth: false,
                polygon_mode: wgpu::PolygonMode::Fill,
                conservative: false,
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(true),
                depth_compare: Some(wgpu::CompareFunction::Greater),
                stencil: wgpu::StencilState::default(),
                bias: wgpu::DepthBiasState::default(),
            }),
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_terrain"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState { format, blend: None, write_mask: wgpu::ColorWrites::ALL })],
            }),
            multiview_mask: None,
            cache: None,
        });
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("relief web frame"),
            size: std::mem::size_of::<FrameUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let image = image_texture(device, white_texel(device, queue), false);
        let bind_group = bind(device, &group_layout, &uniform, &image);
        Renderer {
            pipeline,
            uniform,
            group_layout,
            bind_group,
            image,
            vertices: None,
            vertex_count: 0,
            depth: None,
            srgb_target: format.is_srgb(),
        }
    }

    /// Drapes `levels` (RGBA8 sRGB, finest first, each half the last: see [`mip_levels`]); u
    /// repeats where it `wraps` around the world, else it is clamped.
    pub fn set_image(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, levels: &[Level], wraps: bool) {
        if levels.is_empty() {
            return;
        }
        let texture = upload_levels(device, queue, "relief web imagery", levels);
        self.image = image_texture(device, texture, wraps);
        self.bind_group = bind(device, &self.group_layout, &self.uniform, &self.image);
    }

    /// Whether the colour target encodes sRGB itself (else the shader does).
    pub fn srgb_target(&self) -> bool {
        self.srgb_target
    }

    /// Replaces the strip: its vertices in strip order.
    pub fn set_strip(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, positions: &[Vertex]) {
        let bytes: &[u8] = bytemuck::cast_slice(positions);
        let fits = self.vertices.as_ref().is_some_and(|b| b.size() >= bytes.len() as u64);
        if !fits {
            // Grown by half again, so a flight's growing strips reallocate rarely.
            let size = (bytes.len() as u64 * 3 / 2).max(4096).next_multiple_of(4);
            self.vertices = Some(device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("relief web strip"),
                size,
                usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }));
        }
        if let Some(b) = &self.vertices {
            if !bytes.is_empty() {
                queue.write_buffer(b, 0, bytes);
            }
        }
        self.vertex_count = positions.len() as u32;
    }

    /// Draws the strip into `colour` (`width × height`), cleared to the sky.
    pub fn draw(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        colour: &wgpu::TextureView,
        (width, height): (u32, u32),
        uniform: &FrameUniform,
    ) {
        if !matches!(&self.depth, Some((_, w, h)) if (*w, *h) == (width, height)) {
            let usage = wgpu::TextureUsages::RENDER_ATTACHMENT;
            let depth = texture_2d(device, "relief web depth", (width, height), 1, DEPTH_FORMAT, usage);
            self.depth = Some((depth.create_view(&Default::default()), width, height));
        }
        queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(uniform));
        let Some((depth, _, _)) = &self.depth else { return };
        // The clear colour as the target stores it.
        let sky = if self.srgb_target { SKY } else { SKY.map(srgb_encode) };
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("relief web") });
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("relief web frame"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: colour,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color {
                            r: sky[0] as f64,
                            g: sky[1] as f64,
                            b: sky[2] as f64,
                            a: 1.0,
                        }),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: depth,
                    depth_ops: Some(wgpu::Operations { load: wgpu::LoadOp::Clear(0.0), store: wgpu::StoreOp::Store }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if let (Some(v), true) = (&self.vertices, self.vertex_count >= 3) {
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, &self.bind_group, &[]);
                pass.set_vertex_buffer(0, v.slice(..));
                pass.draw(0..self.vertex_count, 0..1);
            }
        }
        queue.submit([encoder.finish()]);
    }
}

/// A frame drawn into a texture of its own and copied into a mappable buffer: the tests'
/// reference image natively, and in the page the pixels a WebGPU canvas cannot screenshot.
pub struct Readback {
    /// Kept until the pixels are read: a browser's WebGPU destroys what wgpu drops at once.
    _texture: wgpu::Texture,
    _renderer: Renderer,
    buffer: wgpu::Buffer,
    row_bytes: u32,
    width: u32,
    height: u32,
}

impl Readback {
    /// Draws the strip `positions` for `uniform` into a new `width × height` sRGB texture and
    /// queues its copy into a buffer.
    pub fn draw(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        positions: &[Vertex],
        image: Option<(&[Level], bool)>,
        (width, height): (u32, u32),
        uniform: &FrameUniform,
    ) -> Readback {
        let format = wgpu::TextureFormat::Rgba8UnormSrgb;
        let usage = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC;
        let texture = texture_2d(device, "relief web offscreen", (width, height), 1, format, usage);
        let mut renderer = Renderer::new(device, queue, format);
        if let Some((levels, wraps)) = image {
            renderer.set_image(device, queue, levels, wraps);
        }
        renderer.set_strip(device, queue, positions);
        renderer.draw(device, queue, &texture.create_view(&Default::default()), (width, height), uniform);
        let row_bytes = (width * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("relief web readback"),
            size: row_bytes as u64 * height as u64,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut encoder = device.create_command_encoder(&Default::default());
        encoder.copy_texture_to_buffer(
            texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row_bytes),
                    rows_per_image: Some(height),
                },
            },
            wgpu::Extent3d { width, height, depth_or_array_layers: 1 },
        );
        queue.submit([encoder.finish()]);
        Readback { _texture: texture, _renderer: renderer, buffer, row_bytes, width, height }
    }

    /// Asks for the buffer's mapping; `done` is called when it is mapped (natively, after a
    /// device poll; in a page, from the event loop).
    pub fn map(&self, done: impl FnOnce(Result<(), wgpu::BufferAsyncError>) + wgpu::WasmNotSend + 'static) {
        self.buffer.slice(..).map_async(wgpu::MapMode::Read, done);
    }

    /// The pixels once mapped: RGBA8 rows from the top.
    pub fn pixels(&self) -> Result<Vec<u8>, String> {
        let mapped = self.buffer.slice(..).get_mapped_range().map_err(|e| format!("reading the image back: {e}"))?;
        let (row, w) = (self.row_bytes as usize, self.width as usize * 4);
        let mut out = Vec::with_capacity(w * self.height as usize);
        for r in 0..self.height as usize {
            out.extend_from_slice(&mapped[r * row..r * row + w]);
        }
        Ok(out)
    }
}

/// Native only (the tests' reference image): [`Readback`] drawn, waited for, read.
#[cfg(not(target_arch = "wasm32"))]
pub fn render_offscreen(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    positions: &[Vertex],
    image: Option<(&[Level], bool)>,
    size: (u32, u32),
    uniform: &FrameUniform,
) -> Result<Vec<u8>, String> {
    let readback = Readback::draw(device, queue, positions, image, size, uniform);
    readback.map(|_| {});
    device
        .poll(wgpu::PollType::Wait { submission_index: None, timeout: None })
        .map_err(|e| format!("waiting for the GPU: {e}"))?;
    readback.pixels()
}

/// Linear to sRGB, as the shader's `srgb_encode`.
pub fn srgb_encode(c: f32) -> f32 {
    if c <= 0.003_130_8 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}
