//! GeoTIFF / TIFF reader: 8/16/32/64-bit signed and unsigned integers, 16/32/64-bit floats, in
//! strips or tiles, with any compression the `tiff` crate decodes (none, deflate, LZW, PackBits,
//! …). Multi-sample pixels contribute their first sample. Georeferencing comes from the
//! ModelPixelScale / ModelTiepoint / GeoKeyDirectory tags (or ModelTransformation): the post
//! spacing, the CRS's EPSG codes and units, and where the posts lie in it ([`Georef`]); nodata
//! from GDAL's `GDAL_NODATA` tag.
//!
//! The image is streamed one chunk (strip or tile) at a time.

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use tiff::decoder::{ChunkType, Decoder, DecodingResult};
use tiff::tags::Tag;
use tiff::{ColorType, TiffError};

use super::{check_dimensions, DemFormat, DemInfo, DemSource, Run, RunBuffer, SourceSpacing};
use crate::error::{Error, IoContext, Result};
use crate::georef::{unit, CrsKind, Georef};

/// The largest strip or tile read, in bytes: `tiff`'s own limit for a decoded chunk.
const MAX_CHUNK_BYTES: u128 = 256 << 20;

// GeoKey IDs and values (OGC GeoTIFF 1.1, §7.5 and Annex D).
const GT_MODEL_TYPE: u16 = 1024;
const GT_RASTER_TYPE: u16 = 1025;
const GEOGRAPHIC_TYPE: u16 = 2048;
const GEOG_ANGULAR_UNITS: u16 = 2054;
const PROJECTED_CS_TYPE: u16 = 3072;
const PROJ_LINEAR_UNITS: u16 = 3076;
const VERTICAL_CS_TYPE: u16 = 4096;
const VERTICAL_UNITS: u16 = 4099;
const MODEL_TYPE_PROJECTED: u16 = 1;
const MODEL_TYPE_GEOGRAPHIC: u16 = 2;
const RASTER_PIXEL_IS_POINT: u16 = 2;
const USER_DEFINED: u16 = 32767;

/// An open GeoTIFF.
struct GeoTiff {
    path: std::path::PathBuf,
    decoder: Decoder<BufReader<File>>,
    info: DemInfo,
}

/// Converts a `tiff` error into ours, naming the file.
fn tiff_error(path: &Path, e: TiffError) -> Error {
    match e {
        TiffError::IoError(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
            Error::bad_dem(path, "truncated TIFF (unexpected end of file)")
        }
        TiffError::IoError(e) => Error::io(path, e),
        TiffError::UnsupportedError(e) => {
            Error::Unsupported { path: path.to_path_buf(), what: format!("TIFF feature: {e}") }
        }
        e => Error::bad_dem(path, format!("invalid TIFF: {}", one_line(&e.to_string()))),
    }
}

/// Error texts from dependencies may span lines; ours must not.
fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

pub(super) fn open(path: &Path) -> Result<Box<dyn DemSource>> {
    let file = File::open(path).at(path)?;
    let mut decoder = Decoder::new(BufReader::new(file)).map_err(|e| tiff_error(path, e))?;
    let (width, height) = decoder.dimensions().map_err(|e| tiff_error(path, e))?;
    let (width, height) = check_dimensions(path, width.into(), height.into())?;

    let colour = decoder.colortype().map_err(|e| tiff_error(path, e))?;
    let bits = match colour {
        ColorType::Palette(_) => {
            return Err(Error::Unsupported {
                path: path.to_path_buf(),
                what: "palette TIFF (a DEM needs numeric samples)".into(),
            })
        }
        ColorType::Gray(b)
        | ColorType::RGB(b)
        | ColorType::GrayA(b)
        | ColorType::RGBA(b)
        | ColorType::CMYK(b)
        | ColorType::CMYKA(b)
        | ColorType::YCbCr(b)
        | ColorType::Lab(b)
        | ColorType::Multiband { bit_depth: b, .. } => b,
        other => {
            return Err(Error::Unsupported { path: path.to_path_buf(), what: format!("TIFF colour type {other:?}") })
        }
    };
    if !matches!(bits, 8 | 16 | 32 | 64) {
        return Err(Error::Unsupported {
            path: path.to_path_buf(),
            what: format!("TIFF with {bits} bits per sample (8, 16, 32 or 64 are read)"),
        });
    }
    let samples = colour.num_samples();
    // `tiff` bounds its decoded chunk by its own 256 MiB limit, but sizes some row buffers from
    // the chunk's width alone: a tiny file claiming a tile 2^31 posts wide made it allocate
    // gigabytes. No chunk (strip or tile, padding included) over that limit is read.
    let (chunk_w, chunk_h) = decoder.chunk_dimensions();
    let chunk_bytes = u128::from(chunk_w) * u128::from(chunk_h) * u128::from(samples) * u128::from(bits / 8);
    if chunk_bytes > MAX_CHUNK_BYTES {
        return Err(Error::Unsupported {
            path: path.to_path_buf(),
            what: format!(
                "TIFF chunks of {chunk_w} x {chunk_h} pixels ({chunk_bytes} bytes; at most {MAX_CHUNK_BYTES})"
            ),
        });
    }

    // The sample type is only known for sure from a decoded chunk's variant; the tags say it too.
    let sample_format = decoder
        .find_tag_unsigned_vec::<u16>(Tag::SampleFormat)
        .map_err(|e| tiff_error(path, e))?
        .and_then(|v| v.first().copied())
        .unwrap_or(1);
    let kind = match sample_format {
        1 => "uint",
        2 => "int",
        3 => "float",
        _ => "unknown",
    };
    let mut sample_type = format!("{kind}{bits}");
    if samples > 1 {
        sample_type.push_str(&format!(" (first of {samples} samples)"));
    }

    let nodata = read_nodata(path, &mut decoder)?;
    let (spacing, georef) = read_georef(path, &mut decoder, height)?;

    let info = DemInfo { format: DemFormat::GeoTiff, width, height, spacing, nodata, sample_type, georef };
    Ok(Box::new(GeoTiff { path: path.to_path_buf(), decoder, info }))
}

/// GDAL_NODATA is an ASCII number; an unparsable one is ignored rather than fatal.
fn read_nodata(path: &Path, decoder: &mut Decoder<BufReader<File>>) -> Result<Option<f64>> {
    let Some(value) = decoder.find_tag(Tag::GdalNodata).map_err(|e| tiff_error(path, e))? else {
        return Ok(None);
    };
    let text = match value.into_string() {
        Ok(t) => t,
        Err(_) => return Ok(None),
    };
    Ok(text.trim_matches(|c: char| c == '\0' || c.is_whitespace()).parse::<f64>().ok())
}

/// Reads the post spacing, the CRS and the posts' placement from the GeoTIFF tags (see the
/// module doc).
fn read_georef(
    path: &Path,
    decoder: &mut Decoder<BufReader<File>>,
    height: u32,
) -> Result<(Option<SourceSpacing>, Option<Georef>)> {
    let find_f64s = |decoder: &mut Decoder<BufReader<File>>, tag: Tag| -> Result<Option<Vec<f64>>> {
        match decoder.find_tag(tag).map_err(|e| tiff_error(path, e))? {
            Some(v) => Ok(v.into_f64_vec().ok()),
            None => Ok(None),
        }
    };
    let scale = find_f64s(decoder, Tag::ModelPixelScaleTag)?;
    let tie = find_f64s(decoder, Tag::ModelTiepointTag)?;
    let transform = find_f64s(decoder, Tag::ModelTransformationTag)?;
    let keys = match decoder.find_tag(Tag::GeoKeyDirectoryTag).map_err(|e| tiff_error(path, e))? {
        Some(v) => v.into_u16_vec().unwrap_or_default(),
        None => Vec::new(),
    };

    // The raster → model map as X = x0 + i·sx, Y = y0 − j·sy for raster coordinates (i, j),
    // whose pixel (c, r) spans [c, c + 1) × [r, r + 1) (PixelIsArea) or sits at (c, r)
    // (PixelIsPoint).
    let (sx, sy, x0, y0) = match (scale.as_deref(), transform.as_deref()) {
        (Some([sx, sy, ..]), _) => match tie.as_deref() {
            Some([i, j, _, x, y, ..]) => (*sx, *sy, x - i * sx, y + j * sy),
            _ => (*sx, *sy, f64::NAN, f64::NAN),
        },
        // A transformation without rotation or shear: X = m0·i + m3, Y = m5·j + m7.
        (_, Some(m)) if m.len() >= 8 && m[1] == 0.0 && m[4] == 0.0 => (m[0], -m[5], m[3], m[7]),
        _ => return Ok((None, None)),
    };
    if !(sx.is_finite() && sy.is_finite() && sx != 0.0 && sy != 0.0) {
        return Ok((None, None));
    }
    let (sx_abs, sy_abs) = (sx.abs(), sy.abs());
    // Posts are pixel centres for PixelIsArea.
    let centre = if geo_key(&keys, GT_RASTER_TYPE) == Some(RASTER_PIXEL_IS_POINT) { 0.0 } else { 0.5 };
    let code = |key: u16| geo_key(&keys, key).filter(|&c| c != 0 && c != USER_DEFINED).map(u32::from);
    let model_type = geo_key(&keys, GT_MODEL_TYPE);
    let (projected_cs, geographic_cs) = (code(PROJECTED_CS_TYPE), code(GEOGRAPHIC_TYPE));
    let kind = match model_type {
        Some(MODEL_TYPE_GEOGRAPHIC) => CrsKind::Geographic,
        Some(MODEL_TYPE_PROJECTED) => CrsKind::Projected,
        None if projected_cs.is_some() => CrsKind::Projected,
        None if geographic_cs.is_some() => CrsKind::Geographic,
        _ => CrsKind::Unknown,
    };
    let (epsg, unit) = match kind {
        CrsKind::Geographic => (geographic_cs.unwrap_or(0), geo_key(&keys, GEOG_ANGULAR_UNITS).unwrap_or(unit::DEGREE)),
        // Files that name the CRS by code often leave the unit out (GDAL writes them so): the
        // code implies it.
        CrsKind::Projected => {
            let implied = projected_cs.map_or(0, unit::of_projected);
            (projected_cs.unwrap_or(0), geo_key(&keys, PROJ_LINEAR_UNITS).unwrap_or(implied))
        }
        CrsKind::Unknown => (0, geo_key(&keys, PROJ_LINEAR_UNITS).unwrap_or(0)),
    };
    let last_row = f64::from(height) - 1.0;
    let georef = Georef {
        kind,
        epsg,
        unit,
        vertical_epsg: code(VERTICAL_CS_TYPE).unwrap_or(0),
        vertical_unit: geo_key(&keys, VERTICAL_UNITS)
            .or_else(|| code(VERTICAL_CS_TYPE).map(unit::of_vertical))
            .unwrap_or(0),
        // Grid post (0, 0) is the pixel of column 0 in the last (southernmost) row.
        origin: [x0 + centre * sx, y0 - (last_row + centre) * sy],
        step: [sx, sy],
    };
    // Only a north-up, east-right grid is placed (as relief reads it, row 0 north).
    let georef = georef.is_valid().then_some(georef);

    let spacing = if kind == CrsKind::Geographic {
        // The centre row's latitude (the tie point's row, if any, as the file gives it).
        let centre_lat_deg = y0 - sy * f64::from(height) / 2.0;
        let centre_lat_deg = if centre_lat_deg.is_finite() { centre_lat_deg } else { 0.0 };
        Some(SourceSpacing::Degrees { x: sx_abs, y: sy_abs, centre_lat_deg })
    } else {
        let metres = unit::metres(unit).unwrap_or(1.0);
        Some(SourceSpacing::Metres { x: sx_abs * metres, y: sy_abs * metres })
    };
    Ok((spacing, georef))
}

/// Looks up a SHORT-valued key stored inline in a GeoKeyDirectory (header of 4 shorts, then
/// entries `[key, location, count, value]`; location 0 means the value is inline).
fn geo_key(keys: &[u16], wanted: u16) -> Option<u16> {
    let count = usize::from(*keys.get(3)?);
    keys.get(4..)?.chunks_exact(4).take(count).find(|e| e[0] == wanted && e[1] == 0).map(|e| e[3])
}

impl DemSource for GeoTiff {
    fn info(&self) -> &DemInfo {
        &self.info
    }

    fn read(&mut self, sink: &mut dyn FnMut(Run<'_>) -> Result<()>) -> Result<()> {
        let path = self.path.as_path();
        let (width, height) = (self.info.width, self.info.height);
        let (chunk_w, chunk_h) = self.decoder.chunk_dimensions();
        if chunk_w == 0 || chunk_h == 0 {
            return Err(Error::bad_dem(path, "TIFF chunks of zero size"));
        }
        let across = width.div_ceil(chunk_w);
        let down = height.div_ceil(chunk_h);
        let chunk_count = match self.decoder.get_chunk_type() {
            ChunkType::Strip => down,
            ChunkType::Tile => across.checked_mul(down).ok_or_else(|| Error::bad_dem(path, "too many TIFF tiles"))?,
        };
        let across = match self.decoder.get_chunk_type() {
            ChunkType::Strip => 1,
            ChunkType::Tile => across,
        };
        let nodata = self.info.nodata;
        let mut runs = RunBuffer::new();

        // Chunks 0..chunk_count hold the first sample plane (planar configuration 2) or every
        // sample (configuration 1); either way the first sample of each pixel is all we need.
        for chunk in 0..chunk_count {
            let x0 = (chunk % across) * chunk_w;
            let y0 = (chunk / across) * chunk_h;
            // The data dimensions exclude the padding of right and bottom edge chunks.
            let data_w = chunk_w.min(width - x0);
            let data_h = chunk_h.min(height - y0);
            let data = self.decoder.read_chunk(chunk).map_err(|e| tiff_error(path, e))?;
            let pixels = data_w as usize * data_h as usize;
            let len = decoded_len(&data);
            if pixels == 0 || !len.is_multiple_of(pixels) || len < pixels {
                return Err(Error::bad_dem(
                    path,
                    format!("TIFF chunk {chunk} decoded to {len} samples for {data_w} x {data_h} pixels"),
                ));
            }
            let spp = len / pixels;
            let geometry = ChunkGeometry { x0, y0, data_w, data_h, spp };
            match &data {
                DecodingResult::U8(v) => geometry.emit(v, |s| int_sample(s.into(), nodata), &mut runs, sink)?,
                DecodingResult::U16(v) => geometry.emit(v, |s| int_sample(s.into(), nodata), &mut runs, sink)?,
                DecodingResult::U32(v) => geometry.emit(v, |s| int_sample(s.into(), nodata), &mut runs, sink)?,
                DecodingResult::U64(v) => geometry.emit(v, |s| int_sample(s as f64, nodata), &mut runs, sink)?,
                DecodingResult::I8(v) => geometry.emit(v, |s| int_sample(s.into(), nodata), &mut runs, sink)?,
                DecodingResult::I16(v) => geometry.emit(v, |s| int_sample(s.into(), nodata), &mut runs, sink)?,
                DecodingResult::I32(v) => geometry.emit(v, |s| int_sample(s.into(), nodata), &mut runs, sink)?,
                DecodingResult::I64(v) => geometry.emit(v, |s| int_sample(s as f64, nodata), &mut runs, sink)?,
                DecodingResult::F16(v) => {
                    let nd = nodata.map(|n| n as f32);
                    geometry.emit(v, |s| f32_sample(s.to_f32(), nd), &mut runs, sink)?
                }
                DecodingResult::F32(v) => {
                    let nd = nodata.map(|n| n as f32);
                    geometry.emit(v, |s| f32_sample(s, nd), &mut runs, sink)?
                }
                DecodingResult::F64(v) => geometry.emit(
                    v,
                    |s| {
                        if Some(s) == nodata || !s.is_finite() {
                            f64::NAN
                        } else {
                            s
                        }
                    },
                    &mut runs,
                    sink,
                )?,
            }
        }
        Ok(())
    }
}

/// An integer sample (as f64; exact up to 32 bits, rounded for 64-bit values) with nodata → NaN.
fn int_sample(v: f64, nodata: Option<f64>) -> f64 {
    if Some(v) == nodata {
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

fn decoded_len(data: &DecodingResult) -> usize {
    match data {
        DecodingResult::U8(v) => v.len(),
        DecodingResult::U16(v) => v.len(),
        DecodingResult::U32(v) => v.len(),
        DecodingResult::U64(v) => v.len(),
        DecodingResult::F16(v) => v.len(),
        DecodingResult::F32(v) => v.len(),
        DecodingResult::F64(v) => v.len(),
        DecodingResult::I8(v) => v.len(),
        DecodingResult::I16(v) => v.len(),
        DecodingResult::I32(v) => v.len(),
        DecodingResult::I64(v) => v.len(),
    }
}

/// Where a decoded chunk lies in the image and how its samples are laid out: `data_h` rows of
/// `data_w` pixels of `spp` interleaved samples.
struct ChunkGeometry {
    x0: u32,
    y0: u32,
    data_w: u32,
    data_h: u32,
    spp: usize,
}

impl ChunkGeometry {
    fn emit<T: Copy>(
        &self,
        data: &[T],
        convert: impl Fn(T) -> f64,
        runs: &mut RunBuffer,
        sink: &mut dyn FnMut(Run<'_>) -> Result<()>,
    ) -> Result<()> {
        let row_len = self.data_w as usize * self.spp;
        for (r, row) in data.chunks_exact(row_len).take(self.data_h as usize).enumerate() {
            let samples = row.iter().step_by(self.spp).map(|&s| convert(s));
            runs.emit(self.y0 + r as u32, self.x0, samples, sink)?;
        }
        Ok(())
    }
}
