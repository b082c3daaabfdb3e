//! DEM readers: every supported input format streams its samples into a sink, row runs at a time,
//! so conversion never needs the whole image in anonymous memory.
//!
//! Formats are chosen by content (magic bytes) and extension, or forced with [`DemFormat`].
//! Readers report samples in the file's own vertical unit (Terrain-RGB and Terrarium decode to
//! metres as their encodings define); nodata, void and non-finite samples arrive as `NaN` and are
//! filled later by [`crate::preprocess::fill`].

mod asc;
mod exr;
#[cfg(feature = "gdal")]
mod gdal;
#[cfg(feature = "gdal")]
pub use gdal::{read_rgba, RgbaRaster, RgbaReader};
mod geotiff;
mod hgt;
mod mosaic;
mod png;

pub use mosaic::Mosaic;

use std::fs::File;
use std::io::Read;
use std::path::Path;

use crate::error::{Error, IoContext, Result};

/// Input formats. The names are those of `--format`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DemFormat {
    /// GeoTIFF / TIFF: 8/16/32/64-bit integers, f16/f32/f64; strips or tiles; uncompressed,
    /// deflate, LZW, ZSTD, PackBits, JPEG (what the `tiff` crate decodes), and with the `gdal`
    /// feature LERC, LZMA, WebP, JPEG 2000 and JPEG XL through GDAL.
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
    /// Any raster GDAL reads (VRT, NetCDF, JPEG 2000, …), band 1; needs relief built with the
    /// `gdal` feature.
    Gdal,
}

impl DemFormat {
    /// Every format, in the order of the terrain header's `source_format` index.
    pub const ALL: [DemFormat; 8] = [
        DemFormat::GeoTiff,
        DemFormat::Png,
        DemFormat::TerrainRgb,
        DemFormat::Terrarium,
        DemFormat::Exr,
        DemFormat::Hgt,
        DemFormat::Asc,
        DemFormat::Gdal,
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
            DemFormat::Gdal => "gdal",
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

impl SourceSpacing {
    /// The spacing of posts `step` CRS units apart: degrees in a geographic CRS (converted to
    /// metres at `centre_lat_deg`, taken as 0 when not finite), else metres by the CRS's `unit`
    /// (an EPSG unit code; metres when not stated).
    pub(crate) fn from_step(kind: crate::georef::CrsKind, unit: u16, step: [f64; 2], centre_lat_deg: f64) -> Self {
        let [x, y] = step.map(f64::abs);
        if kind == crate::georef::CrsKind::Geographic {
            let centre_lat_deg = if centre_lat_deg.is_finite() { centre_lat_deg } else { 0.0 };
            SourceSpacing::Degrees { x, y, centre_lat_deg }
        } else {
            let metres = crate::georef::unit::metres(unit).unwrap_or(1.0);
            SourceSpacing::Metres { x: x * metres, y: y * metres }
        }
    }
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
    /// The CRS and where the posts lie in it, if the file says (see [`crate::georef`]).
    pub georef: Option<crate::georef::Georef>,
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

    /// Streams at least the samples of the window `[x0, x1) × [row0, row1)` (columns, rows from
    /// the north), each once, and possibly others (the caller keeps what it needs). The default
    /// streams every sample; a mosaic opens only the tiles the window touches.
    fn read_window(&mut self, window: [u32; 4], sink: &mut dyn FnMut(Run<'_>) -> Result<()>) -> Result<()> {
        let _ = window;
        self.read(sink)
    }
}

/// Opens `path` as a DEM: `format` forces a reader; otherwise the format is detected from the
/// content (magic bytes, PNG colour type and a sample of its pixels) and the extension; see
/// [`detect`].
///
/// A forced format whose reader cannot make sense of the content fails with an error naming the
/// file (e.g. forcing `terrain-rgb` on a grayscale PNG).
pub fn open(path: &Path, format: Option<DemFormat>) -> Result<Box<dyn DemSource>> {
    open_with(path, OpenOptions { format, allow_lossy: false })
}

/// How [`open_with`] opens a DEM.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OpenOptions {
    /// Forces a reader (otherwise detected, see [`detect`]).
    pub format: Option<DemFormat>,
    /// Accepts lossy-compressed sources (JPEG, lossy WebP, LERC with an error bound, JPEG 2000),
    /// refused by default with [`Error::Lossy`]: their heights carry the codec's errors.
    pub allow_lossy: bool,
}

/// [`open`] with options.
pub fn open_with(path: &Path, opts: OpenOptions) -> Result<Box<dyn DemSource>> {
    let format = match opts.format {
        Some(f) => f,
        None => detect(path)?,
    };
    match format {
        DemFormat::GeoTiff => geotiff::open(path, opts.allow_lossy),
        DemFormat::Gdal => open_gdal(path, opts.allow_lossy),
        DemFormat::Png | DemFormat::TerrainRgb | DemFormat::Terrarium => png::open(path, format),
        DemFormat::Exr => exr::open(path),
        DemFormat::Hgt => hgt::open(path),
        DemFormat::Asc => asc::open(path),
    }
}

#[cfg(feature = "gdal")]
fn open_gdal(path: &Path, allow_lossy: bool) -> Result<Box<dyn DemSource>> {
    gdal::open(path, allow_lossy)
}

#[cfg(not(feature = "gdal"))]
fn open_gdal(path: &Path, _allow_lossy: bool) -> Result<Box<dyn DemSource>> {
    Err(needs_gdal(path, "raster for this build"))
}

/// `what` of `path`, which only GDAL reads, refused by a build without it: what to do about it.
#[cfg(not(feature = "gdal"))]
fn needs_gdal(path: &Path, what: &str) -> Error {
    Error::Unsupported {
        path: path.to_path_buf(),
        what: format!("{what}: reading it needs GDAL: build relief with `--features gdal` (and Debian's libgdal-dev)"),
    }
}

/// Pixels of a GeoTIFF whose header the native reader read, decoded by GDAL (a compression the
/// `tiff` crate does not decode); here, so that neither reader names the other.
#[cfg(feature = "gdal")]
fn gdal_pixels(path: &Path, info: DemInfo) -> Result<Box<dyn DemSource>> {
    gdal::with_info(path, info)
}

/// Why the GeoTIFF at `path` is lossy by the native reader's check, if it is (`None` also when it
/// does not open: the read reports that).
#[cfg(feature = "gdal")]
fn tiff_lossy(path: &Path) -> Option<String> {
    match geotiff::open(path, false) {
        Err(Error::Lossy { what, .. }) => Some(what),
        _ => None,
    }
}

/// Extensions of the files a directory given as a mosaic contributes (any case).
const TILE_EXTENSIONS: [&str; 7] = ["tif", "tiff", "hgt", "asc", "png", "exr", "vrt"];

/// The tiles `inputs` name: files as given, directories as the DEM files directly inside them
/// (by extension, sorted by name). An error names a directory with none.
pub fn expand_inputs(inputs: &[std::path::PathBuf]) -> Result<Vec<std::path::PathBuf>> {
    let mut out = Vec::new();
    for p in inputs {
        if !p.is_dir() {
            out.push(p.clone());
            continue;
        }
        let mut files: Vec<std::path::PathBuf> = std::fs::read_dir(p)
            .at(p)?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|f| {
                f.is_file()
                    && f.extension()
                        .and_then(|e| e.to_str())
                        .is_some_and(|e| TILE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
            })
            .collect();
        if files.is_empty() {
            return Err(Error::bad_dem(p, format!("directory holds no DEM files (.{})", TILE_EXTENSIONS.join(", ."))));
        }
        files.sort();
        out.extend(files);
    }
    Ok(out)
}

/// Detects the format of `path` from its content and name.
///
/// Rules, in order:
/// - TIFF (`II*\0`, `MM\0*`) and BigTIFF (`II+\0`, `MM\0+`) → [`DemFormat::GeoTiff`];
/// - PNG signature → grayscale (with or without alpha) is [`DemFormat::Png`]; colour PNGs are
///   height encodings: a file name containing `terrarium` means [`DemFormat::Terrarium`], one
///   containing `terrain-rgb`, `terrain_rgb`, `terrainrgb` or `mapbox` means
///   [`DemFormat::TerrainRgb`]; otherwise the median red value of the opaque pixels of the first
///   64 rows decides: Terrain-RGB keeps R ≤ 4 for every height between −10 km and +10 km while
///   Terrarium keeps R within 88..167, so a median below 32 means Terrain-RGB, else Terrarium;
/// - OpenEXR magic `76 2f 31 01` → [`DemFormat::Exr`];
/// - text whose first token is `ncols` (any case) → [`DemFormat::Asc`];
/// - extension `.hgt` (any case), or a size of exactly 2·1201² or 2·3601² bytes →
///   [`DemFormat::Hgt`].
///
/// - extension `.vrt` or a `<VRTDataset` document → [`DemFormat::Gdal`]; with the `gdal`
///   feature, anything else GDAL opens as a raster too.
///
/// Anything else is [`Error::UnknownFormat`], with the first bytes and the extension as a hint.
pub fn detect(path: &Path) -> Result<DemFormat> {
    // The file is closed at the end of this block, before any reader opens it again.
    let (size, head) = {
        let mut file = File::open(path).at(path)?;
        let size = file.metadata().at(path)?.len();
        let mut head = Vec::with_capacity(512);
        (&mut file).take(512).read_to_end(&mut head).at(path)?;
        (size, head)
    };

    let extension = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);

    if head.starts_with(b"II*\0")
        || head.starts_with(b"MM\0*")
        || head.starts_with(b"II+\0")
        || head.starts_with(b"MM\0+")
    {
        return Ok(DemFormat::GeoTiff);
    }
    if head.starts_with(png::SIGNATURE) {
        return png::detect_kind(path);
    }
    if head.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        return Ok(DemFormat::Exr);
    }
    if asc::looks_like_asc(&head) {
        return Ok(DemFormat::Asc);
    }
    if extension.as_deref() == Some("hgt") || hgt::is_standard_size(size) {
        return Ok(DemFormat::Hgt);
    }
    // A GDAL virtual raster (XML), or anything else GDAL opens.
    if extension.as_deref() == Some("vrt") || head.trim_ascii_start().starts_with(b"<VRTDataset") {
        return Ok(DemFormat::Gdal);
    }
    #[cfg(feature = "gdal")]
    if gdal::opens(path) {
        return Ok(DemFormat::Gdal);
    }

    let hint = if head.is_empty() {
        "empty file".to_string()
    } else {
        let bytes: Vec<String> = head.iter().take(4).map(|b| format!("{b:02x}")).collect();
        let ext = match &extension {
            Some(e) => format!("extension .{e}"),
            None => "no extension".to_string(),
        };
        format!("first bytes {}, {ext}", bytes.join(" "))
    };
    Err(Error::UnknownFormat { path: path.to_path_buf(), hint })
}

/// The most samples a DEM may have (2^40): more is certainly a corrupt header, and would overflow
/// later arithmetic.
pub const MAX_SAMPLES: u64 = 1 << 40;

/// Longest run a reader emits at once; long rows are cut into several runs so that buffers stay
/// small whatever width a (possibly hostile) header claims.
const MAX_RUN: usize = 1 << 14;

/// Checks header dimensions: both non-zero, each fitting in `u32`, the product at most
/// [`MAX_SAMPLES`].
fn check_dimensions(path: &Path, width: u64, height: u64) -> Result<(u32, u32)> {
    if width == 0 || height == 0 {
        return Err(Error::bad_dem(path, format!("empty grid ({width} x {height})")));
    }
    let w = u32::try_from(width);
    let h = u32::try_from(height);
    match (w, h, width.checked_mul(height)) {
        (Ok(w), Ok(h), Some(n)) if n <= MAX_SAMPLES => Ok((w, h)),
        _ => Err(Error::bad_dem(path, format!("absurd dimensions {width} x {height} (more than 2^40 samples)"))),
    }
}

/// Error texts from dependencies may span lines; ours must not.
fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// An integer sample (as f64; exact up to 32 bits, rounded for 64-bit values) with nodata → NaN.
fn int_sample(v: f64, nodata: Option<f64>) -> f64 {
    if Some(v) == nodata {
        f64::NAN
    } else {
        v
    }
}

/// An f64 sample with nodata and non-finite values → NaN.
fn f64_sample(v: f64, nodata: Option<f64>) -> f64 {
    if Some(v) == nodata || !v.is_finite() {
        f64::NAN
    } else {
        v
    }
}

/// A float sample compared with nodata in f32, so that e.g. `-3.4028234663852886e+38` matches.
/// Huge sentinels (|nodata| ≥ 1e38) also match within a relative 1e-5, since some writers print
/// them with few digits (`-3.40282e+38` for `f32::MIN`).
fn f32_sample(v: f32, nodata: Option<f32>) -> f64 {
    let is_nodata = nodata.is_some_and(|nd| v == nd || (nd.abs() >= 1e38 && (v - nd).abs() <= nd.abs() * 1e-5));
    if is_nodata || !v.is_finite() {
        f64::NAN
    } else {
        f64::from(v)
    }
}

/// Collects converted samples and hands them to the sink in runs of at most [`MAX_RUN`].
struct RunBuffer {
    values: Vec<f64>,
}

impl RunBuffer {
    fn new() -> Self {
        RunBuffer { values: Vec::new() }
    }

    /// Emits `samples` as consecutive values of row `row` starting at column `x0`.
    fn emit(
        &mut self,
        row: u32,
        x0: u32,
        samples: impl Iterator<Item = f64>,
        sink: &mut dyn FnMut(Run<'_>) -> Result<()>,
    ) -> Result<()> {
        let mut x = x0;
        self.values.clear();
        for v in samples {
            self.values.push(v);
            if self.values.len() == MAX_RUN {
                sink(Run { row, x0: x, values: &self.values })?;
                x = x.saturating_add(MAX_RUN as u32);
                self.values.clear();
            }
        }
        if !self.values.is_empty() {
            sink(Run { row, x0: x, values: &self.values })?;
            self.values.clear();
        }
        Ok(())
    }
}
