//! Rendering on wgpu: resident heights, strips uploaded per refinement update, offscreen targets
//! and the CPU reference of the shading. See `ARCHITECTURE.md` ("Rendering").

pub mod gpu;
pub mod heights;
pub mod offscreen;
pub mod shade;
pub mod terrain;

pub use gpu::Gpu;
pub use offscreen::Offscreen;
pub use terrain::{DrawStyle, FrameView, RendererOptions, TerrainRenderer};
