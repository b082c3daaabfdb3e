//! From a DEM to a terrain file: void filling and padding ([`fill`]), nested errors and bounding
//! radii ([`bounds`]), the conversion pipeline that lays the records out and writes the file
//! ([`convert`]), and the reports that read a terrain file back ([`inspect`]).

pub mod bounds;
#[cfg(feature = "native")]
pub mod convert;
pub mod fill;
pub mod inspect;
#[cfg(feature = "native")]
pub mod shard;

pub use bounds::*;
