//! SRTM `.hgt` reader: a square grid of big-endian `i16` heights in metres, row 0 north, void
//! −32768. The side follows from the file size (2·s² bytes: 1201 for 3″ tiles, 3601 for 1″ tiles,
//! any other square accepted too). A name like `N47E008.hgt` gives the south-west corner and
//! hence the spacing in degrees. Streamed one row at a time.

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use super::{check_dimensions, DemFormat, DemInfo, DemSource, Run, RunBuffer, SourceSpacing};
use crate::error::{Error, IoContext, Result};
use crate::georef::{unit, CrsKind, Georef};

/// Value of a void (missing) post.
const VOID: i16 = -32768;

/// Whether `size` is that of a standard 3″ (1201²) or 1″ (3601²) tile.
pub(super) fn is_standard_size(size: u64) -> bool {
    size == 2 * 1201 * 1201 || size == 2 * 3601 * 3601
}

/// The side `s` of a square tile of `size` = 2·s² bytes, if there is one (s ≥ 2).
fn side_for_size(size: u64) -> Option<u64> {
    if !size.is_multiple_of(2) {
        return None;
    }
    let posts = size / 2;
    let mut s = (posts as f64).sqrt() as u64;
    // Correct the float estimate by ±1.
    while s.checked_mul(s).is_some_and(|sq| sq > posts) {
        s -= 1;
    }
    while (s + 1).checked_mul(s + 1).is_some_and(|sq| sq <= posts) {
        s += 1;
    }
    (s >= 2 && s * s == posts).then_some(s)
}

/// Parses `N47E008`-style tile names (any case, extension ignored) into the south-west corner
/// `(lat, lon)` in degrees.
fn parse_tile_name(path: &Path) -> Option<(f64, f64)> {
    let stem = path.file_stem()?.to_str()?.to_ascii_uppercase();
    let b = stem.as_bytes();
    if b.len() != 7 || !b.is_ascii() {
        return None;
    }
    let lat_sign = match b[0] {
        b'N' => 1.0,
        b'S' => -1.0,
        _ => return None,
    };
    let lon_sign = match b[3] {
        b'E' => 1.0,
        b'W' => -1.0,
        _ => return None,
    };
    let lat: u32 = stem.get(1..3)?.parse().ok()?;
    let lon: u32 = stem.get(4..7)?.parse().ok()?;
    if lat > 90 || lon > 180 {
        return None;
    }
    Some((lat_sign * f64::from(lat), lon_sign * f64::from(lon)))
}

struct Hgt {
    path: PathBuf,
    info: DemInfo,
}

pub(super) fn open(path: &Path) -> Result<Box<dyn DemSource>> {
    let size = std::fs::metadata(path).at(path)?.len();
    let side = side_for_size(size).ok_or_else(|| {
        Error::bad_dem(path, format!("size {size} bytes is not that of a square .hgt tile (2·1201² or 2·3601²)"))
    })?;
    let (width, height) = check_dimensions(path, side, side)?;
    let corner = parse_tile_name(path);
    let step = 1.0 / (side - 1) as f64;
    let spacing = corner.map(|(lat, _lon)| SourceSpacing::Degrees { x: step, y: step, centre_lat_deg: lat + 0.5 });
    // SRTM tiles are WGS 84 longitude and latitude with EGM96 heights in metres, their posts on
    // whole degrees at the tile's corners (the south-west one named by the file).
    let georef = corner.map(|(lat, lon)| Georef {
        kind: CrsKind::Geographic,
        epsg: 4326,
        unit: unit::DEGREE,
        vertical_epsg: 5773,
        vertical_unit: unit::METRE,
        origin: [lon, lat],
        step: [step, step],
    });
    let info = DemInfo {
        format: DemFormat::Hgt,
        width,
        height,
        spacing,
        nodata: Some(f64::from(VOID)),
        sample_type: "int16 big-endian".into(),
        georef,
    };
    Ok(Box::new(Hgt { path: path.to_path_buf(), info }))
}

impl DemSource for Hgt {
    fn info(&self) -> &DemInfo {
        &self.info
    }

    fn read(&mut self, sink: &mut dyn FnMut(Run<'_>) -> Result<()>) -> Result<()> {
        let path = self.path.as_path();
        let mut file = BufReader::new(File::open(path).at(path)?);
        let mut row = vec![0u8; 2 * self.info.width as usize];
        let mut runs = RunBuffer::new();
        for y in 0..self.info.height {
            file.read_exact(&mut row).map_err(|e| {
                if e.kind() == std::io::ErrorKind::UnexpectedEof {
                    Error::bad_dem(path, format!("truncated .hgt: ends in row {y}"))
                } else {
                    Error::io(path, e)
                }
            })?;
            let samples = row.chunks_exact(2).map(|b| match i16::from_be_bytes([b[0], b[1]]) {
                VOID => f64::NAN,
                h => f64::from(h),
            });
            runs.emit(y, 0, samples, sink)?;
        }
        Ok(())
    }
}
