//! Rendering on wgpu: resident heights, strips uploaded per refinement update, triangle meshes
//! uploaded per adaptation, offscreen targets and the CPU references of the shading. See
//! `ARCHITECTURE.md` ("Rendering").

pub mod gpu;
pub mod height_cache;
pub mod heights;
pub mod imagery;
pub mod mesh;
pub mod mesh_shade;
pub mod offscreen;
mod pipeline;
pub mod present;
pub mod shade;
pub mod terrain;
mod vertex_buffer;

pub use gpu::Gpu;
pub use mesh::{DrawnBounds, MeshRenderer, MeshStyle, MeshView};
pub use offscreen::Offscreen;
pub use present::{render_still, save_png, MeshPresenter, MeshStage, StillOptions, StillReport, TerrainPresenter};
pub use shade::{Look, Ramp};
pub use terrain::{DrawStyle, FrameView, NodataStyle, RendererOptions, TerrainRenderer};
