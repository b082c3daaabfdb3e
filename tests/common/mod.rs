//! Helpers shared by the integration tests.
#![allow(dead_code)] // each test binary uses its own subset of the helpers

use std::path::{Path, PathBuf};

/// The real DEMs in ../shared/data/dem (see its README).
pub const REAL_DEMS: [&str; 6] = [
    "zurich_25m_i16.tif",
    "lidar_1m_f32.tif",
    "etopo20_world.tif",
    "fuji_terrain_rgb.png",
    "terrarium.png",
    "hugo_site_nodata.asc",
];

/// Path of a real DEM in ../shared/data/dem.
pub fn dem(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/dem").join(name)
}
