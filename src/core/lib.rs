//! relief-core: the GPU-free core of relief, a terrain renderer for regular-grid height fields.
//!
//! The terrain core follows Lindstrom & Pascucci, *Visualization of Large Terrains Made Easy*
//! (2001): DEMs are converted into memory-mapped files whose vertex records (height, nested error,
//! bounding radius) are stored in a hierarchical index layout, and refined top-down into one
//! triangle strip per view. Beside it stand two backends for general meshes (meta-node trees and
//! disk-page hierarchies). Everything here builds without a GPU or a window: an engine with its
//! own renderer uses this crate alone. See `ARCHITECTURE.md`.

// Without `native` (the wasm build of the web viewer) the OS-only items are left out, and what
// only they used is unused there; the native build is where unused code is a warning.
#![cfg_attr(
    not(feature = "native"),
    allow(unused_imports, unused_variables, dead_code, reason = "items used only by native-only code")
)]

#[cfg(target_endian = "big")]
compile_error!("relief's terrain files are little-endian and mapped in place; big-endian targets are not supported");

pub mod camera;
pub mod dem;
pub mod diskpages;
pub mod error;
#[cfg(feature = "native")]
pub mod faults;
pub mod flight;
pub mod format;
pub mod georef;
pub mod heightcache;
pub mod layout;
pub mod lod;
pub mod mesh;
#[cfg(feature = "native")]
pub mod metanode;
pub mod pager;
pub mod preprocess;
pub mod refine;
pub mod sys;

pub use error::{Error, Result};
