//! relief-core's integration tests, in one test binary that links no GPU or window code: every
//! backend over every access of the pager (identical frames), the four file formats (golden
//! bytes, malformations), the DEM readers on real and fixture files. Run with
//! `cargo test -p relief-core`; the rest of the suite is relief's (`tests/app`).

mod common {
    //! The real data beside the checkout (`../shared/data`, see its README).
    use std::path::{Path, PathBuf};

    /// The real DEMs in ../shared/data/dem.
    pub const REAL_DEMS: [&str; 6] = [
        "zurich_25m_i16.tif",
        "lidar_1m_f32.tif",
        "etopo20_world.tif",
        "fuji_terrain_rgb.png",
        "terrarium.png",
        "hugo_site_nodata.asc",
    ];

    fn shared(dir: &str, name: &str) -> PathBuf {
        // This crate is src/core of the checkout; ../shared sits beside the checkout.
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data").join(dir).join(name)
    }

    /// Path of a real DEM.
    pub fn dem(name: &str) -> PathBuf {
        shared("dem", name)
    }

    /// Path of a mesh.
    pub fn mesh(name: &str) -> PathBuf {
        shared("mesh", name)
    }
}

mod backends;
mod compressed_tiffs;
mod dem_readers;
mod exaggeration;
mod export;
mod formats;
mod height_cache;
mod imagery_tiles;
mod non_square;
mod remote;
