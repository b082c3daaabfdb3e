//! relief-web: relief in the browser. relief-core compiled to `wasm32-unknown-unknown` reads a
//! terrain file over HTTP ranges (the page's `fetch`, [`relief_core::pager::hosted`]), refines
//! it progressively without ever waiting (Lindstrom & Pascucci, *Visualization of Large Terrains
//! Made Easy*, 2001, refined as in [`relief_core::refine`]; missing records read as inactive, so
//! every frame is conforming), and draws the strip with wgpu on WebGL2 in a `<canvas>`
//! (ARCHITECTURE.md, "The web viewer").
//!
//! - [`scene`]: the terrain as it arrives, its strip as positions, the orbit camera;
//! - [`draw`]: the one pipeline (`shaders/web.wgsl`), for the canvas or an offscreen texture;
//! - `page` (wasm32 only): the page's fetches, events, animation frames and
//!   `window.relief.status()`.
//!
//! Natively the crate renders the same view offscreen: the reference image the browser test
//! compares the page's screenshot with.

pub mod draw;
pub mod scene;

#[cfg(target_arch = "wasm32")]
mod page;
