//! The mesh renderer: owns `shaders/mesh.wgsl`, the triangle buffer and the pipelines (mesh, sky).
//!
//! Meshes arrive as non-indexed triangle lists of world positions, 3 per triangle, and are uploaded
//! whole each time the triangle set changes (a view-dependent mesh changes with the camera; an
//! index buffer would need the adaptation to keep vertex slots stable, which it does not promise).
//! Each vertex is 12 bytes: its position minus a per-upload origin, subtracted in f64 and then
//! rounded to f32, so a mesh whose world coordinates are tens of kilometres (a terrain exported as
//! a mesh) keeps millimetres near the origin. The vertex shader subtracts the eye's offset from
//! that origin (also computed in f64), so no large number meets the GPU. Nothing else is uploaded:
//! the face normal comes from screen-space derivatives in the fragment shader (CPU reference:
//! `render::mesh_shade`), the wireframe from the corner's index (`vertex_index % 3`).
//! Depth is reversed-z f32 with an infinite far plane, as for terrains; the near plane comes from
//! the triangles drawn ([`DrawnBounds`]: boxes around runs of them, made at upload), so a coarse
//! view-dependent mesh or a culled page set gets the depth range of what is on screen, not of
//! the whole model.

use glam::DVec3;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::mesh::Bounds;
use crate::render::gpu::Gpu;
use crate::render::mesh_shade::{MeshShadeParams, AMBIENT, HEADLIGHT, SUN};
use crate::render::offscreen::frame_pass;
use crate::render::pipeline::{build_pipeline, depth_state, uniform_entry, PipelineSpec};
use crate::render::vertex_buffer::VertexBuffer;

/// WGSL source of the mesh shaders.
pub const MESH_WGSL: &str = include_str!("../../shaders/mesh.wgsl");

/// Bytes uploaded per vertex: an origin-relative position, 3 × f32. A triangle is 36 bytes.
pub const MESH_VERTEX_BYTES: u64 = 12;

/// Near plane as a fraction of the box's diagonal when the eye is in or at the bounding box.
/// Reversed-z f32 depth keeps its precision however small the near plane, so this only has to be
/// small enough never to clip what the eye flies over: 5 cm on a 50 km terrain.
pub const NEAR_OF_DIAGONAL: f64 = 1e-6;

/// The uniform block `Frame` of `mesh.wgsl` (same field order and padding).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
pub struct MeshFrameUniform {
    clip_from_rel: [[f32; 4]; 4],
    rel_from_clip: [[f32; 4]; 4],
    eye_from_origin: [f32; 4],
    zenith: [f32; 4],
    sun_dir: [f32; 4],
    front_albedo: [f32; 4],
    back_albedo: [f32; 4],
    wire_colour: [f32; 4],
    light: [f32; 4],
    fog_distance_m: f32,
    flags: u32,
    pad: [u32; 2],
}

/// Bytes of the per-frame uniform upload.
pub const MESH_FRAME_UNIFORM_BYTES: u64 = std::mem::size_of::<MeshFrameUniform>() as u64;

/// How to draw a mesh frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MeshStyle {
    /// Draw every triangle's edges about a pixel wide (barycentric, no extra geometry), fainter
    /// on triangles under 6 pixels across so a dense mesh does not turn black.
    pub wireframe: bool,
}

/// A camera and the near plane to draw it with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshView {
    pub camera: Camera,
    pub near_m: f64,
}

impl MeshView {
    /// `camera` with the near plane [`near_plane_m`] picks for it around `bounds`.
    pub fn new(bounds: &Bounds, camera: Camera) -> MeshView {
        MeshView { camera, near_m: near_plane_m(bounds, camera.eye_in_world) }
    }
}

/// A near plane for an eye: a quarter of its distance to the mesh's bounding box (no surface is
/// nearer, and a quarter leaves room for the corners of a wide view), at least
/// [`NEAR_OF_DIAGONAL`] of the box's diagonal (the eye inside the box).
pub fn near_plane_m(bounds: &Bounds, eye_in_world: DVec3) -> f64 {
    let diagonal = bounds.diagonal();
    let floor = if diagonal > 0.0 && diagonal.is_finite() { NEAR_OF_DIAGONAL * diagonal } else { 1e-6 };
    let d = bounds.distance_to(eye_in_world);
    if d.is_finite() {
        (0.25 * d).max(floor)
    } else {
        floor
    }
}

/// Consecutive triangles per box of [`DrawnBounds`].
pub const TRIANGLES_PER_BOX: usize = 256;

/// Boxes around the triangles of an upload, one per run of [`TRIANGLES_PER_BOX`] consecutive
/// triangles (world units, of the f32 positions as drawn), and their union: what the depth range
/// is taken from. A box holds its triangles, so the distance to the nearest box is a lower bound
/// on the distance to anything drawn (the near plane never clips), and the union's farthest
/// corner an upper bound.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DrawnBounds {
    boxes: Vec<Bounds>,
    all: Option<Bounds>,
}

impl DrawnBounds {
    /// The boxes of a triangle list (3 positions per triangle; non-finite coordinates are
    /// skipped, as the GPU draws nothing sensible of them).
    pub fn of(positions: &[[f32; 3]]) -> DrawnBounds {
        let empty = Bounds { min: [f64::INFINITY; 3], max: [f64::NEG_INFINITY; 3] };
        let grow = |b: &mut Bounds, p: &[f32; 3]| {
            if p.iter().all(|c| c.is_finite()) {
                for (k, &c) in p.iter().enumerate() {
                    b.min[k] = b.min[k].min(c as f64);
                    b.max[k] = b.max[k].max(c as f64);
                }
            }
        };
        let boxes: Vec<Bounds> = positions
            .chunks(3 * TRIANGLES_PER_BOX)
            .map(|run| {
                let mut b = empty;
                run.iter().for_each(|p| grow(&mut b, p));
                b
            })
            .filter(|b| b.min[0] <= b.max[0])
            .collect();
        let all = boxes.iter().copied().reduce(|mut a, b| {
            for k in 0..3 {
                a.min[k] = a.min[k].min(b.min[k]);
                a.max[k] = a.max[k].max(b.max[k]);
            }
            a
        });
        DrawnBounds { boxes, all }
    }

    /// The depth range of what is drawn seen from `eye_in_world`: the distance to the nearest
    /// box and to the union's farthest corner; `None` when nothing is drawn.
    pub fn depth_range_m(&self, eye_in_world: DVec3) -> Option<(f64, f64)> {
        let all = self.all?;
        let nearest = self.boxes.iter().map(|b| b.distance_to(eye_in_world)).fold(f64::INFINITY, f64::min);
        let far = (DVec3::from(all.min) - eye_in_world).abs().max((DVec3::from(all.max) - eye_in_world).abs());
        Some((nearest, far.length()))
    }

    /// The near plane for `eye_in_world` over what is drawn: a quarter of the distance to the
    /// nearest box (room for the corners of a wide view, as [`near_plane_m`]), at least
    /// [`NEAR_OF_DIAGONAL`] of the larger of the union's diagonal and its farthest corner's
    /// distance (the eye among the triangles), always > 0; `None` when nothing is drawn.
    pub fn near_plane_m(&self, eye_in_world: DVec3) -> Option<f64> {
        let (nearest, farthest) = self.depth_range_m(eye_in_world)?;
        let scale = self.all.map_or(0.0, |b| b.diagonal()).max(farthest);
        let floor = if scale > 0.0 && scale.is_finite() { NEAR_OF_DIAGONAL * scale } else { 1e-6 };
        Some(if nearest.is_finite() { (0.25 * nearest).max(floor) } else { floor })
    }
}

/// Renders one triangle list at a time.
pub struct MeshRenderer {
    shade: MeshShadeParams,
    uniform: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    mesh_pipeline: wgpu::RenderPipeline,
    sky_pipeline: wgpu::RenderPipeline,
    vertices: VertexBuffer,
    /// Origin-relative positions of the last upload (kept to reuse the allocation).
    staging: Vec<[f32; 3]>,
    vertex_count: u32,
    origin_in_world: DVec3,
    last_upload_bytes: u64,
    /// Boxes around the uploaded triangles, for the near plane.
    drawn: DrawnBounds,
}

impl MeshRenderer {
    /// Builds the pipelines for `colour_format`; GPU errors come back as [`crate::AppError::Gpu`].
    pub fn new(gpu: &Gpu, colour_format: wgpu::TextureFormat, shade: MeshShadeParams) -> Result<MeshRenderer> {
        gpu.scoped("building the mesh renderer", || Ok(Self::build(gpu, colour_format, shade)))
    }

    fn build(gpu: &Gpu, colour_format: wgpu::TextureFormat, shade: MeshShadeParams) -> MeshRenderer {
        let device = &gpu.device;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("mesh.wgsl"),
            source: wgpu::ShaderSource::Wgsl(MESH_WGSL.into()),
        });
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("relief mesh frame"),
            size: MESH_FRAME_UNIFORM_BYTES,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("relief mesh frame"),
            entries: &[uniform_entry(MESH_FRAME_UNIFORM_BYTES)],
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("relief mesh frame"),
            layout: &bind_layout,
            entries: &[wgpu::BindGroupEntry { binding: 0, resource: uniform.as_entire_binding() }],
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("relief mesh"),
            bind_group_layouts: &[Some(&bind_layout)],
            immediate_size: 0,
        });
        let targets =
            [Some(wgpu::ColorTargetState { format: colour_format, blend: None, write_mask: wgpu::ColorWrites::ALL })];
        const POSITION: [wgpu::VertexAttribute; 1] =
            [wgpu::VertexAttribute { format: wgpu::VertexFormat::Float32x3, offset: 0, shader_location: 0 }];
        let buffers = [Some(wgpu::VertexBufferLayout {
            array_stride: MESH_VERTEX_BYTES,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &POSITION,
        })];
        let no_bias = wgpu::DepthBiasState::default();
        let mesh_pipeline = build_pipeline(
            device,
            &layout,
            &module,
            PipelineSpec {
                label: "mesh",
                vs: "vs_mesh",
                buffers: &buffers,
                topology: wgpu::PrimitiveTopology::TriangleList,
                // Files store counter-clockwise front faces; back faces get their own colour.
                front_face: wgpu::FrontFace::Ccw,
                depth_stencil: depth_state(true, wgpu::CompareFunction::Greater, no_bias),
                fs: "fs_mesh",
                targets: &targets,
            },
        );
        // The sky fills what the mesh left at the cleared (infinite) depth.
        let sky_pipeline = build_pipeline(
            device,
            &layout,
            &module,
            PipelineSpec {
                label: "mesh sky",
                vs: "vs_sky",
                buffers: &[],
                topology: wgpu::PrimitiveTopology::TriangleList,
                front_face: wgpu::FrontFace::Ccw,
                depth_stencil: depth_state(false, wgpu::CompareFunction::Equal, no_bias),
                fs: "fs_sky",
                targets: &targets,
            },
        );
        MeshRenderer {
            shade,
            uniform,
            bind_group,
            mesh_pipeline,
            sky_pipeline,
            vertices: VertexBuffer::new(device, "relief mesh triangles", 1 << 20),
            staging: Vec::new(),
            vertex_count: 0,
            origin_in_world: DVec3::ZERO,
            last_upload_bytes: 0,
            drawn: DrawnBounds::default(),
        }
    }

    pub fn shade_params(&self) -> &MeshShadeParams {
        &self.shade
    }

    /// Uploads a triangle list (`positions`: world positions, 3 per triangle) relative to
    /// `origin_in_world` (the eye at upload, or the mesh's centre) and returns the bytes sent:
    /// exactly `positions.len()` × [`MESH_VERTEX_BYTES`]. A length that is not a multiple of 3, or
    /// a list larger than the GPU's buffer limit, is an error and leaves the previous mesh.
    pub fn upload(&mut self, gpu: &Gpu, positions: &[[f32; 3]], origin_in_world: DVec3) -> Result<u64> {
        if !positions.len().is_multiple_of(3) {
            return Err(Error::InvalidArgument(format!(
                "a triangle list needs 3 positions per triangle, got {} positions",
                positions.len()
            )));
        }
        let bytes = positions.len() as u64 * MESH_VERTEX_BYTES;
        let limit = gpu.device.limits().max_buffer_size;
        let count = u32::try_from(positions.len()).ok().filter(|_| bytes <= limit).ok_or_else(|| {
            crate::app_error::gpu(format!(
                "{} triangles need {bytes} bytes of vertices, over the GPU's buffer limit of {limit} bytes",
                positions.len() / 3
            ))
        })?;
        let o = origin_in_world;
        self.staging.clear();
        self.staging.extend(
            positions
                .iter()
                .map(|p| [(p[0] as f64 - o.x) as f32, (p[1] as f64 - o.y) as f32, (p[2] as f64 - o.z) as f32]),
        );
        self.vertices.write(&gpu.device, &gpu.queue, bytemuck::cast_slice(&self.staging));
        self.vertex_count = count;
        self.drawn = DrawnBounds::of(positions);
        self.origin_in_world = o;
        self.last_upload_bytes = bytes;
        Ok(bytes)
    }

    /// Triangles of the last upload.
    pub fn triangles(&self) -> u64 {
        self.vertex_count as u64 / 3
    }

    /// Bytes of the last upload.
    pub fn last_upload_bytes(&self) -> u64 {
        self.last_upload_bytes
    }

    /// Boxes around the uploaded triangles.
    pub fn drawn_bounds(&self) -> &DrawnBounds {
        &self.drawn
    }

    /// The view of `camera` over the uploaded triangles: the near plane from their boxes
    /// ([`DrawnBounds::near_plane_m`]), or from `bounds` (the whole model's box) before any
    /// upload or when none was drawn.
    pub fn view(&self, bounds: &Bounds, camera: Camera) -> MeshView {
        match self.drawn.near_plane_m(camera.eye_in_world) {
            Some(near_m) => MeshView { camera, near_m },
            None => MeshView::new(bounds, camera),
        }
    }

    /// The origin the uploaded positions are relative to.
    pub fn origin_in_world(&self) -> DVec3 {
        self.origin_in_world
    }

    fn frame_uniform(&self, view: &MeshView, style: MeshStyle) -> MeshFrameUniform {
        let clip_from_rel = view.camera.clip_from_rel(view.near_m);
        let s = &self.shade;
        let v4 = |v: DVec3, w: f32| [v.x as f32, v.y as f32, v.z as f32, w];
        MeshFrameUniform {
            clip_from_rel: clip_from_rel.to_cols_array_2d(),
            rel_from_clip: clip_from_rel.inverse().to_cols_array_2d(),
            eye_from_origin: v4(view.camera.eye_in_world - self.origin_in_world, 1.0),
            zenith: v4(s.zenith, 0.0),
            sun_dir: v4(s.sun_dir, 0.0),
            front_albedo: v4(s.front_albedo, 1.0),
            back_albedo: v4(s.back_albedo, 1.0),
            wire_colour: [0.02, 0.02, 0.03, 1.0],
            light: [AMBIENT as f32, HEADLIGHT as f32, SUN as f32, 0.0],
            fog_distance_m: s.fog_distance_m as f32,
            flags: style.wireframe as u32,
            pad: [0; 2],
        }
    }

    /// Records a frame of `view`: the mesh, then the sky, into `colour` and `depth` (both cleared).
    /// Returns the uniform bytes written.
    pub fn encode(
        &self,
        gpu: &Gpu,
        encoder: &mut wgpu::CommandEncoder,
        colour: &wgpu::TextureView,
        depth: &wgpu::TextureView,
        view: &MeshView,
        style: MeshStyle,
    ) -> u64 {
        gpu.queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&self.frame_uniform(view, style)));
        let mut pass = frame_pass(encoder, "relief mesh frame", colour, depth);
        pass.set_bind_group(0, &self.bind_group, &[]);
        if self.vertex_count >= 3 {
            pass.set_pipeline(&self.mesh_pipeline);
            pass.set_vertex_buffer(0, self.vertices.buffer.slice(..self.vertex_count as u64 * MESH_VERTEX_BYTES));
            pass.draw(0..self.vertex_count, 0..1);
        }
        pass.set_pipeline(&self.sky_pipeline);
        pass.draw(0..3, 0..1);
        MESH_FRAME_UNIFORM_BYTES
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_uniform_matches_the_wgsl_block() {
        // 2 matrices (128) + 7 vec4 (112) + fog, flags and padding (16).
        assert_eq!(MESH_FRAME_UNIFORM_BYTES, 256);
    }

    #[test]
    fn the_near_plane_follows_the_drawn_triangles_and_never_clips_them() {
        // Two runs of triangles: one near x = 10, one near x = 100 (a box each).
        let tri = |x: f32| [[x, 0.0, 0.0], [x, 1.0, 0.0], [x, 0.0, 1.0]];
        let mut list: Vec<[f32; 3]> = (0..TRIANGLES_PER_BOX).flat_map(|_| tri(10.0)).collect();
        list.extend((0..TRIANGLES_PER_BOX).flat_map(|_| tri(100.0)));
        let d = DrawnBounds::of(&list);
        let eye = DVec3::new(0.0, 0.5, 0.5);
        let (nearest, farthest) = d.depth_range_m(eye).unwrap();
        assert!((nearest - 10.0).abs() < 1e-12, "{nearest}");
        assert!((100.0..101.0).contains(&farthest), "{farthest}");
        assert!((d.near_plane_m(eye).unwrap() - 2.5).abs() < 1e-12);
        // Every drawn corner is beyond the near plane.
        let near = d.near_plane_m(eye).unwrap();
        assert!(list.iter().all(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64).distance(eye) > near));
        // Among the triangles: the floor, a small fraction of the depth range, > 0.
        let inside = d.near_plane_m(DVec3::new(10.0, 0.2, 0.2)).unwrap();
        assert!(inside > 0.0 && inside <= NEAR_OF_DIAGONAL * 91.0, "{inside}");
        assert_eq!(DrawnBounds::of(&[]).near_plane_m(eye), None);
        // Only the far run drawn: the near plane moves out with it.
        let far_only = DrawnBounds::of(&list[3 * TRIANGLES_PER_BOX..]);
        assert!((far_only.near_plane_m(eye).unwrap() - 25.0).abs() < 1e-12);
    }

    #[test]
    fn near_plane_is_a_quarter_of_the_distance_to_the_box() {
        let b = Bounds { min: [0.0; 3], max: [1.0, 1.0, 1.0] };
        assert!((near_plane_m(&b, DVec3::new(5.0, 0.5, 0.5)) - 1.0).abs() < 1e-12);
        let inside = near_plane_m(&b, DVec3::splat(0.5));
        assert!((inside - NEAR_OF_DIAGONAL * 3f64.sqrt()).abs() < 1e-15);
    }
}
