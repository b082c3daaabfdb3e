//! relief: a GPU-resident terrain renderer for regular-grid height fields.
//!
//! This crate is the renderer (wgpu), the window (winit, egui) and the figures (plotters) over
//! [`relief_core`], whose modules it re-exports: DEM readers, conversion, layouts, file formats,
//! the pager, refinement and the two mesh backends. See `ARCHITECTURE.md`.

pub use relief_core::*;

pub mod fly;
pub mod mesh_fly;
pub mod plot;
pub mod render;
pub mod window;
