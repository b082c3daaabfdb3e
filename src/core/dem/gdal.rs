//! Rasters through GDAL (cargo feature `gdal`, over the system's libgdal): what the native readers
//! do not decode — GeoTIFFs compressed with LERC, LZMA, JPEG 2000, JPEG XL or WebP, and any other
//! raster GDAL opens (VRT mosaics, NetCDF, JPEG 2000, Erdas, …).
//!
//! Two uses: [`with_info`] decodes the pixels of a GeoTIFF whose header the native reader already
//! read (so a LERC copy gives the same [`DemInfo`], hence the same terrain file, as the original);
//! [`open`] reads header and pixels of anything else, its georeferencing from GDAL's geotransform
//! and spatial reference. Band 1 is read, in its own sample type, one window of whole blocks at a
//! time.

use std::path::{Path, PathBuf};

use gdal::raster::{GdalDataType, GdalType, RasterBand};
use gdal::{Dataset, Metadata};

use super::{
    check_dimensions, f32_sample, f64_sample, int_sample, one_line, DemFormat, DemInfo, DemSource, Run, RunBuffer,
    SourceSpacing,
};
use crate::error::{Error, Result};
use crate::georef::{unit, CrsKind, Georef};

/// Samples per window read (about 4 M, 32 MiB as f64).
const WINDOW_SAMPLES: usize = 1 << 22;

struct GdalSource {
    path: PathBuf,
    dataset: Dataset,
    info: DemInfo,
}

/// GDAL's error for `path`, in one line: a call that returned nothing gives GDAL's own message
/// (its last error), or says GDAL cannot read the file where there is none.
fn gdal_error(path: &Path, e: gdal::errors::GdalError) -> Error {
    match e {
        gdal::errors::GdalError::NullPointer { msg, .. } if msg.trim().is_empty() => {
            Error::bad_dem(path, "GDAL cannot read it as a raster")
        }
        gdal::errors::GdalError::NullPointer { msg, .. } => Error::bad_dem(path, format!("GDAL: {}", one_line(&msg))),
        e => Error::bad_dem(path, format!("GDAL: {}", one_line(&e.to_string()))),
    }
}

/// GDAL prints its errors and warnings on stderr by default; relief's errors are one line naming
/// the file, so GDAL's go through its last-error message into ours, and its printing is off.
fn quiet_gdal() {
    static QUIET: std::sync::Once = std::sync::Once::new();
    QUIET.call_once(|| gdal::config::set_error_handler(|_, _, _| {}));
}

fn open_dataset(path: &Path) -> Result<Dataset> {
    quiet_gdal();
    Dataset::open(path).map_err(|e| gdal_error(path, e))
}

/// The pixels of `path` through GDAL, with the header `info` the native reader made of it.
pub(super) fn with_info(path: &Path, info: DemInfo) -> Result<Box<dyn DemSource>> {
    let dataset = open_dataset(path)?;
    let (w, h) = dataset.raster_size();
    if (w as u64, h as u64) != (u64::from(info.width), u64::from(info.height)) {
        return Err(Error::bad_dem(
            path,
            format!("GDAL reads {w} x {h} pixels, the TIFF header says {} x {}", info.width, info.height),
        ));
    }
    Ok(Box::new(GdalSource { path: path.to_path_buf(), dataset, info }))
}

/// Whether GDAL opens `path` as a raster (used to detect formats the native readers lack).
pub(super) fn opens(path: &Path) -> bool {
    quiet_gdal();
    Dataset::open(path).is_ok_and(|d| d.raster_count() > 0)
}

/// Compression GDAL reports for `path`'s raster, if lossy (or possibly lossy) by its nature.
fn lossy_compression(dataset: &Dataset) -> Option<String> {
    let driver = dataset.driver().short_name();
    let compression = dataset.metadata_item("COMPRESSION", "IMAGE_STRUCTURE").unwrap_or_default().to_ascii_uppercase();
    let reversible = dataset.metadata_item("COMPRESSION_REVERSIBILITY", "IMAGE_STRUCTURE").unwrap_or_default();
    if reversible.eq_ignore_ascii_case("LOSSLESS") {
        return None;
    }
    if reversible.eq_ignore_ascii_case("LOSSY") {
        return Some(format!("{driver} data compressed lossily ({compression})"));
    }
    match (driver.as_str(), compression.as_str()) {
        ("JPEG", _) | (_, "JPEG") => Some("JPEG compression is lossy".into()),
        (_, "WEBP") => Some("WebP compression may be lossy".into()),
        ("JP2OpenJPEG" | "JP2KAK" | "JP2ECW" | "JP2MrSID", _) | (_, "JPEG2000") => {
            Some("JPEG 2000 compression may be lossy".into())
        }
        _ => None,
    }
}

/// The files GDAL reads for `dataset` (itself, and a VRT's sources).
fn source_files(dataset: &Dataset) -> Vec<PathBuf> {
    use std::os::unix::ffi::OsStrExt;
    // SAFETY: GDALGetFileList returns null or a null-terminated list of NUL-terminated strings
    // that the caller owns; each is copied before the list is freed with CSLDestroy.
    unsafe {
        let list = gdal_sys::GDALGetFileList(dataset.c_dataset());
        if list.is_null() {
            return Vec::new();
        }
        let mut files = Vec::new();
        let mut k = 0;
        while !(*list.add(k)).is_null() {
            let name = std::ffi::CStr::from_ptr(*list.add(k));
            files.push(PathBuf::from(std::ffi::OsStr::from_bytes(name.to_bytes())));
            k += 1;
        }
        gdal_sys::CSLDestroy(list);
        files
    }
}

/// Why a source file of a dataset is lossy, if it is: a TIFF by the native check (the codec, LERC's
/// stated error, WebP's mode), anything else by what GDAL reports. A source that does not open
/// is left to the read to report.
fn lossy_source(source: &Path) -> Option<String> {
    if matches!(super::detect(source), Ok(DemFormat::GeoTiff)) {
        return super::tiff_lossy(source);
    }
    open_dataset(source).ok().and_then(|d| lossy_compression(&d))
}

/// Opens any raster GDAL reads: band 1, georeferenced from the geotransform and the CRS.
pub(super) fn open(path: &Path, allow_lossy: bool) -> Result<Box<dyn DemSource>> {
    let dataset = open_dataset(path)?;
    if dataset.raster_count() == 0 {
        return Err(Error::bad_dem(path, "GDAL finds no raster band in it"));
    }
    if !allow_lossy {
        if let Some(what) = lossy_compression(&dataset) {
            return Err(Error::Lossy { path: path.to_path_buf(), what });
        }
        // A VRT (or any dataset over other files) is as lossy as its sources.
        for source in source_files(&dataset).into_iter().filter(|f| f.as_path() != path) {
            if let Some(what) = lossy_source(&source) {
                return Err(Error::Lossy {
                    path: path.to_path_buf(),
                    what: format!("its source {}: {what}", source.display()),
                });
            }
        }
    }
    let (w, h) = dataset.raster_size();
    let (width, height) = check_dimensions(path, w as u64, h as u64)?;
    let (sample_type, nodata) = {
        let band = dataset.rasterband(1).map_err(|e| gdal_error(path, e))?;
        (band.band_type().name(), band.no_data_value())
    };
    let (spacing, georef) = match dataset.geo_transform() {
        Ok(t) => georeference(&dataset, t, height),
        Err(_) => (None, None),
    };
    let info = DemInfo { format: DemFormat::Gdal, width, height, spacing, nodata, sample_type, georef };
    Ok(Box::new(GdalSource { path: path.to_path_buf(), dataset, info }))
}

/// Spacing and placement from a north-up geotransform (`X = t0 + c·t1`, `Y = t3 + r·t5`, pixel
/// corners; posts are the pixel centres) and the dataset's CRS.
fn georeference(dataset: &Dataset, t: [f64; 6], height: u32) -> (Option<SourceSpacing>, Option<Georef>) {
    let (sx, sy) = (t[1], -t[5]);
    if t[2] != 0.0 || t[4] != 0.0 || !(sx.is_finite() && sy.is_finite() && sx > 0.0 && sy > 0.0) {
        return (None, None);
    }
    let srs = dataset.spatial_ref().ok();
    let authority = |key: &str| -> u32 {
        let Some(srs) = &srs else { return 0 };
        let Ok(key) = std::ffi::CString::new(key) else { return 0 };
        // SAFETY: the handle lives as long as `srs`; GDAL returns a pointer into the SRS, or null.
        let code = unsafe { gdal_sys::OSRGetAuthorityCode(srs.to_c_hsrs(), key.as_ptr()) };
        if code.is_null() {
            return 0;
        }
        // SAFETY: non-null, NUL-terminated, owned by the SRS and copied at once.
        unsafe { std::ffi::CStr::from_ptr(code) }.to_str().ok().and_then(|s| s.parse().ok()).unwrap_or(0)
    };
    let (kind, epsg, unit) = match &srs {
        Some(s) if s.is_projected() => {
            let epsg = authority("PROJCS");
            let metres = s.linear_units();
            let unit = match epsg {
                0 => unit_of_metres(metres),
                code => match unit::of_projected(code) {
                    0 => unit_of_metres(metres),
                    u => u,
                },
            };
            (CrsKind::Projected, epsg, unit)
        }
        Some(s) if s.is_geographic() => (CrsKind::Geographic, authority("GEOGCS"), unit::DEGREE),
        _ => (CrsKind::Unknown, 0, 0),
    };
    let vertical_epsg = authority("VERT_CS");
    let last_row = f64::from(height) - 1.0;
    let georef = Georef {
        kind,
        epsg,
        unit,
        vertical_epsg,
        vertical_unit: if vertical_epsg == 0 { 0 } else { unit::of_vertical(vertical_epsg) },
        origin: [t[0] + 0.5 * sx, t[3] - (last_row + 0.5) * sy],
        step: [sx, sy],
    };
    let georef = georef.is_valid().then_some(georef);
    let centre_lat_deg = t[3] - sy * f64::from(height) / 2.0;
    (Some(SourceSpacing::from_step(kind, unit, [sx, sy], centre_lat_deg)), georef)
}

/// The EPSG unit code of a linear unit given in metres (0 when it is none of the usual ones).
fn unit_of_metres(metres: f64) -> u16 {
    [unit::METRE, unit::FOOT, unit::US_SURVEY_FOOT]
        .into_iter()
        .find(|&u| unit::metres(u).is_some_and(|m| (m - metres).abs() < 1e-9))
        .unwrap_or(0)
}

impl GdalSource {
    /// Streams band 1 read as `T`, each sample converted by `convert` (nodata → NaN).
    fn stream<T: Copy + GdalType + Default>(
        &self,
        band: &RasterBand<'_>,
        convert: impl Fn(T) -> f64,
        sink: &mut dyn FnMut(Run<'_>) -> Result<()>,
    ) -> Result<()> {
        let (width, height) = (self.info.width as usize, self.info.height as usize);
        let (bw, bh) = band.block_size();
        let (bw, bh) = (bw.clamp(1, width), bh.clamp(1, height));
        // Windows of whole blocks: as wide as the raster where a row of blocks fits the budget.
        let window_w = if width * bh <= WINDOW_SAMPLES { width } else { (WINDOW_SAMPLES / bh / bw).max(1) * bw };
        let window_w = window_w.min(width);
        let window_h = ((WINDOW_SAMPLES / window_w / bh).max(1) * bh).min(height);
        let mut buffer = vec![T::default(); window_w * window_h];
        let mut runs = RunBuffer::new();
        for y0 in (0..height).step_by(window_h) {
            let h = window_h.min(height - y0);
            for x0 in (0..width).step_by(window_w) {
                let w = window_w.min(width - x0);
                let buf = &mut buffer[..w * h];
                band.read_into_slice((x0 as isize, y0 as isize), (w, h), (w, h), buf, None)
                    .map_err(|e| gdal_error(&self.path, e))?;
                for (r, row) in buf.chunks_exact(w).enumerate() {
                    runs.emit((y0 + r) as u32, x0 as u32, row.iter().map(|&s| convert(s)), sink)?;
                }
            }
        }
        Ok(())
    }
}

impl DemSource for GdalSource {
    fn info(&self) -> &DemInfo {
        &self.info
    }

    fn read(&mut self, sink: &mut dyn FnMut(Run<'_>) -> Result<()>) -> Result<()> {
        let band = self.dataset.rasterband(1).map_err(|e| gdal_error(&self.path, e))?;
        let nodata = self.info.nodata;
        let nd32 = nodata.map(|n| n as f32);
        // The native reader's conversions, so that both readers give the same heights.
        match band.band_type() {
            GdalDataType::UInt8 => self.stream::<u8>(&band, |s| int_sample(s.into(), nodata), sink),
            GdalDataType::UInt16 => self.stream::<u16>(&band, |s| int_sample(s.into(), nodata), sink),
            GdalDataType::Int16 => self.stream::<i16>(&band, |s| int_sample(s.into(), nodata), sink),
            GdalDataType::UInt32 => self.stream::<u32>(&band, |s| int_sample(s.into(), nodata), sink),
            GdalDataType::Int32 => self.stream::<i32>(&band, |s| int_sample(s.into(), nodata), sink),
            GdalDataType::Float32 => self.stream::<f32>(&band, |s| f32_sample(s, nd32), sink),
            // 64-bit integers and anything wider are read as f64, as the native reader does.
            _ => self.stream::<f64>(&band, |s| f64_sample(s, nodata), sink),
        }
    }
}

/// An image through GDAL (a GeoTIFF orthophoto, a COG, JPEG 2000, …): bands 1–3 as RGB (one
/// band: grey), 8-bit (other types are clipped to 0..255), RGBA row-major from the top; and its
/// placement where it is north up: (x of the upper-left pixel's centre, pixel width, y of that
/// centre, pixel height), in its CRS units.
pub fn read_rgba(path: &Path) -> Result<RgbaRaster> {
    let reader = RgbaReader::open(path)?;
    let (w, h) = (reader.width as usize, reader.height as usize);
    if (w as u64) * (h as u64) > 1 << 30 {
        return Err(Error::bad_dem(path, format!("{w} x {h} pixels: over 2^30 pixels to hold whole")));
    }
    let mut rgba = vec![[255u8; 4]; w * h];
    reader.read_rows(0, &mut rgba)?;
    Ok(RgbaRaster { width: w as u32, height: h as u32, rgba: rgba.into_flattened(), placement: reader.placement })
}

/// An image through GDAL read a band of rows at a time (what [`read_rgba`] reads whole), for
/// images larger than memory.
pub struct RgbaReader {
    path: std::path::PathBuf,
    dataset: Dataset,
    bands: usize,
    pub width: u32,
    pub height: u32,
    /// As [`RgbaRaster::placement`].
    pub placement: Option<[f64; 4]>,
}

impl RgbaReader {
    pub fn open(path: &Path) -> Result<RgbaReader> {
        let dataset = open_dataset(path)?;
        let bands = dataset.raster_count();
        if bands == 0 {
            return Err(Error::bad_dem(path, "GDAL finds no raster band in it"));
        }
        let (w, h) = dataset.raster_size();
        if w == 0 || h == 0 || w > u32::MAX as usize || h > u32::MAX as usize {
            return Err(Error::bad_dem(path, format!("{w} x {h} pixels")));
        }
        let placement = dataset
            .geo_transform()
            .ok()
            .filter(|t| t[2] == 0.0 && t[4] == 0.0 && t[1] > 0.0 && t[5] < 0.0)
            .map(|t| [t[0] + 0.5 * t[1], t[1], t[3] + 0.5 * t[5], -t[5]]);
        Ok(RgbaReader { path: path.into(), dataset, bands, width: w as u32, height: h as u32, placement })
    }

    /// Rows `y0 ..` (as many as `out` holds whole rows of) as RGBA, alpha 255.
    pub fn read_rows(&self, y0: u32, out: &mut [[u8; 4]]) -> Result<()> {
        let w = self.width as usize;
        let rows = out.len() / w;
        if rows == 0 || y0 as usize + rows > self.height as usize {
            return Err(Error::bad_dem(&self.path, format!("rows {y0}..{} of {}", y0 as usize + rows, self.height)));
        }
        let mut plane = vec![0u8; w * rows];
        for c in 0..3 {
            let band = self
                .dataset
                .rasterband(if self.bands >= 3 { c + 1 } else { 1 })
                .map_err(|e| gdal_error(&self.path, e))?;
            band.read_into_slice((0, y0 as isize), (w, rows), (w, rows), &mut plane, None)
                .map_err(|e| gdal_error(&self.path, e))?;
            for (px, v) in out.iter_mut().zip(&plane) {
                px[c] = *v;
                px[3] = 255;
            }
        }
        Ok(())
    }
}

/// What [`read_rgba`] reads.
pub struct RgbaRaster {
    pub width: u32,
    pub height: u32,
    /// RGBA, row-major from the top.
    pub rgba: Vec<u8>,
    /// (x of the upper-left pixel's centre, pixel width, y of that centre, pixel height), where
    /// the raster is north up.
    pub placement: Option<[f64; 4]>,
}
