//! Flying: camera paths, the frame protocol every backend implements, and the terrain's
//! refinement thread.

pub mod frame;
pub mod path;
pub mod terrain;

pub use path::*;
