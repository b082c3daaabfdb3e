//! The disk-page backend (Sajadi, Huang, Diaz-Gutierrez, Yoon & Gopi, "A Novel Page-Based Data
//! Structure for Interactive Walkthroughs", I3D 2009): any triangle soup written as
//! self-contained fixed-size pages in a layout order, a k-d tree over the pages' bounding boxes
//! whose leaves name page numbers, and a per-frame fetch of whole pages in sorted order.
//!
//! - [`matching`]: minimum-weight perfect matching (Edmonds' blossom algorithm).
//! - [`two_factor`]: the 2-factor layout (Sajadi et al. §6).
//! - [`hilbert`]: 3D Hilbert order of triangle centroids; raster is the input order.
//! - [`build`]: the pages filled in layout order and written as a page file (the format and its
//!   reader are [`crate::format::pagefile`]).
//! - [`kdtree`]: the disk-page k-d tree and the box / normal-cone culling.
//! - [`fetch`]: the per-frame fetch through the page file's pager, as a
//!   [`crate::flight::frame::FrameSource`].

pub mod build;
pub mod fetch;
pub mod hilbert;
pub mod kdtree;
pub mod matching;
pub mod two_factor;
