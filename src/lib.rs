//! relief: a GPU-resident terrain renderer for regular-grid height fields.
//!
//! The terrain core follows Lindstrom & Pascucci, *Visualization of Large Terrains Made Easy*
//! (2001): DEMs are converted into memory-mapped files whose vertex records (height, nested error,
//! bounding radius) are stored in a hierarchical index layout. See `ARCHITECTURE.md`.

#[cfg(target_endian = "big")]
compile_error!("relief's terrain files are little-endian and mapped in place; big-endian targets are not supported");

pub mod dem;
pub mod error;
pub mod hierarchy;
pub mod layout;
pub mod layout_faults;
mod mapped;

pub use error::{Error, Result};
pub mod atomic_file;
pub mod camera;
pub mod cancel;
pub mod convert;
pub mod fill;
pub mod flight;
pub mod fly;
pub mod format;
pub mod inspect;
pub mod mem;
pub mod mesh;
pub mod mesh_check;
pub mod mesh_fly;
pub mod metric;
pub mod minimal;
pub mod pager;
pub mod pages;
pub mod plot;
pub mod pool;
pub mod preprocess;
pub mod progress;
pub mod refine;
pub mod refine_report;
pub mod render;
pub mod sigbus;
pub mod vdtree;
pub mod window;
