//! DEM readers: every supported input format streams its samples into a sink, row runs at a time,
//! so conversion never needs the whole image in anonymous memory.
//!
//! Formats are chosen by content (magic bytes) and extension, or forced with [`DemFormat`].
//! Readers report samples in the file's own vertical unit (Terrain-RGB and Terrarium decode to
//! metres as their encodings define); nodata, void and non-finite samples arrive as `NaN` and are
//! filled later by [`crate::fill`].

use std::path::Path;

use crate::error::Result;

/// Input formats. The names are those of `--format`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DemFormat {
    /// GeoTIFF / TIFF: 8/16/32-bit integers, f32/f64; strips or tiles; uncompressed, deflate, LZW.
    GeoTiff,
    /// Grayscale PNG, 8 or 16 bits: the sample value is the height.
    Png,
    /// Mapbox Terrain-RGB PNG: h = (R·65536 + G·256 + B) · 0.1 − 10000 metres.
    TerrainRgb,
    /// Terrarium PNG: h = R·256 + G + B/256 − 32768 metres.
    Terrarium,
    /// Single-channel OpenEXR, f16 or f32 (or u32).
    Exr,
    /// SRTM `.hgt`: square, big-endian i16, void −32768, 1201² (3″) or 3601² (1″).
    Hgt,
    /// ESRI ASCII grid (`.asc`).
    Asc,
}

impl DemFormat {
    pub const ALL: [DemFormat; 7] = [
        DemFormat::GeoTiff,
        DemFormat::Png,
        DemFormat::TerrainRgb,
        DemFormat::Terrarium,
        DemFormat::Exr,
        DemFormat::Hgt,
        DemFormat::Asc,
    ];

    pub fn name(self) -> &'static str {
        match self {
            DemFormat::GeoTiff => "geotiff",
            DemFormat::Png => "png",
            DemFormat::TerrainRgb => "terrain-rgb",
            DemFormat::Terrarium => "terrarium",
            DemFormat::Exr => "exr",
            DemFormat::Hgt => "hgt",
            DemFormat::Asc => "asc",
        }
    }

    pub fn from_name(name: &str) -> Option<DemFormat> {
        DemFormat::ALL.into_iter().find(|f| f.name() == name)
    }
}

impl std::fmt::Display for DemFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Post spacing as the file states it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SourceSpacing {
    /// Projected grid, posts `x` (east) and `y` (north) metres apart.
    Metres { x: f64, y: f64 },
    /// Geographic grid, posts `x` (longitude) and `y` (latitude) degrees apart; `centre_lat_deg`
    /// is the latitude of the grid's centre, where degrees are converted to metres.
    Degrees { x: f64, y: f64, centre_lat_deg: f64 },
}

/// What a reader learned from the file's header.
#[derive(Clone, Debug, PartialEq)]
pub struct DemInfo {
    pub format: DemFormat,
    /// Samples per row.
    pub width: u32,
    /// Rows (row 0 is the northernmost).
    pub height: u32,
    /// Post spacing, if the file says.
    pub spacing: Option<SourceSpacing>,
    /// The nodata value the file declares, if any (samples equal to it arrive as NaN).
    pub nodata: Option<f64>,
    /// Sample type as stored, e.g. "int16", "float32", "uint8 rgb".
    pub sample_type: String,
}

/// A run of consecutive samples on one row: `values[k]` is the sample at column `x0 + k` of row
/// `row` (row 0 = north). NaN marks nodata.
pub struct Run<'a> {
    pub row: u32,
    pub x0: u32,
    pub values: &'a [f64],
}

/// A DEM opened for streaming.
pub trait DemSource {
    fn info(&self) -> &DemInfo;

    /// Streams every sample exactly once, in runs, in any order. Stops at the first error the
    /// sink returns (used for cancellation) and passes it on.
    fn read(&mut self, sink: &mut dyn FnMut(Run<'_>) -> Result<()>) -> Result<()>;
}

/// Opens `path` as a DEM: `format` forces a reader; otherwise the format is detected from the
/// content (magic bytes, PNG colour type and a sample of its pixels) and the extension.
pub fn open(path: &Path, format: Option<DemFormat>) -> Result<Box<dyn DemSource>> {
    let _ = (path, format);
    todo!("DEM readers")
}
