//! relief: a GPU-resident terrain renderer for regular-grid height fields.
//!
//! This crate is the renderer (wgpu), the window (winit, egui) and the figures (plotters) over
//! [`relief_core`], whose modules it re-exports: DEM readers, conversion, layouts, file formats,
//! the pager, refinement and the two mesh backends. See `ARCHITECTURE.md`.

pub use relief_core::*;

pub mod app_error;
pub use app_error::AppError;

pub mod plot;
pub mod render;
pub mod window;

/// The bundled default terrain (`data/zurich_25m_i16.tif`, a real DEM), converted on first use
/// into the user's cache directory ([`preprocess::convert::cache_dir`]).
pub fn bundled_terrain(progress: sys::progress::Progress) -> Result<std::path::PathBuf> {
    use std::path::Path;
    const NAME: &str = "zurich_25m_i16.tif";
    let candidates = [Path::new("data").join(NAME), Path::new(env!("CARGO_MANIFEST_DIR")).join("data").join(NAME)];
    let Some(dem) = candidates.iter().find(|p| p.is_file()) else {
        return Err(Error::InvalidArgument(format!(
            "no FILE given and the bundled terrain data/{NAME} is not here; pass a terrain file"
        )));
    };
    let cache = preprocess::convert::cache_dir();
    let out = cache.join("zurich_25m_i16.interleaved.relief");
    if format::terrain::TerrainFile::open(&out).is_ok() {
        return Ok(out);
    }
    std::fs::create_dir_all(&cache).map_err(|e| Error::io(&cache, e))?;
    let mut opts = preprocess::convert::ConvertOptions::new(layout::LayoutKind::Interleaved);
    opts.progress = progress;
    preprocess::convert::convert(dem, &out, &opts)?;
    Ok(out)
}
