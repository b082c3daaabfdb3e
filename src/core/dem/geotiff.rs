//! GeoTIFF / TIFF reader: 8/16/32/64-bit signed and unsigned integers, 16/32/64-bit floats, in
//! strips or tiles, with any compression the `tiff` crate decodes (none, deflate, LZW, ZSTD,
//! PackBits, JPEG; horizontal and floating-point predictors too). Multi-sample pixels contribute
//! their first sample. Georeferencing comes from the ModelPixelScale / ModelTiepoint /
//! GeoKeyDirectory tags (or ModelTransformation): the post spacing, the CRS's EPSG codes and
//! units, and where the posts lie in it ([`Georef`]); nodata from GDAL's `GDAL_NODATA` tag.
//!
//! The image is streamed one chunk (strip or tile) at a time. Compressions the `tiff` crate does
//! not decode (LERC, LZMA, WebP, JPEG 2000, JPEG XL) are decoded by GDAL where relief is built
//! with the `gdal` feature, the header still read here; without it they are refused with one line
//! naming the file and the compression. Lossy ones (JPEG, lossy WebP, LERC with a non-zero error
//! bound, JPEG 2000) are refused unless allowed ([`super::OpenOptions`]).

use std::fs::File;
use std::io::BufReader;
use std::path::Path;

use tiff::decoder::{ChunkType, Decoder, DecodingResult};
use tiff::tags::Tag;
use tiff::{ColorType, TiffError};

use super::{
    check_dimensions, f32_sample, f64_sample, int_sample, one_line, DemFormat, DemInfo, DemSource, Run, RunBuffer,
    SourceSpacing,
};
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

const COMPRESSION_NONE: u16 = 1;
/// TIFF compressions the `tiff` crate decodes: none, LZW, deflate (both codes), PackBits, JPEG,
/// ZSTD (its `zstd` feature).
const NATIVE_COMPRESSIONS: [u16; 7] = [COMPRESSION_NONE, 5, 8, 32946, 32773, 7, 50000];

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

pub(super) fn open(path: &Path, allow_lossy: bool) -> Result<Box<dyn DemSource>> {
    let file = File::open(path).at(path)?;
    let mut decoder = Decoder::new(BufReader::new(file)).map_err(|e| tiff_error(path, e))?;
    let (width, height) = decoder.dimensions().map_err(|e| tiff_error(path, e))?;
    let (width, height) = check_dimensions(path, width.into(), height.into())?;
    let compression = decoder
        .find_tag(Tag::Compression)
        .map_err(|e| tiff_error(path, e))?
        .and_then(|v| v.into_u16().ok())
        .unwrap_or(COMPRESSION_NONE);
    let native = NATIVE_COMPRESSIONS.contains(&compression);
    #[cfg(not(feature = "gdal"))]
    if !native {
        return Err(super::needs_gdal(path, &format!("TIFF compression {}", lossy::name(compression))));
    }
    if !allow_lossy {
        if let Some(what) = lossy::reason(path, &mut decoder, compression)? {
            return Err(Error::Lossy { path: path.to_path_buf(), what });
        }
    }

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
    // Pixels GDAL decodes, under the header read here (so copies give the same terrain file).
    #[cfg(feature = "gdal")]
    if !native {
        return super::gdal_pixels(path, info);
    }
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

    // The centre row's latitude (the tie point's row, if any, as the file gives it).
    let centre_lat_deg = y0 - sy * f64::from(height) / 2.0;
    Ok((Some(SourceSpacing::from_step(kind, unit, [sx, sy], centre_lat_deg)), georef))
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
                DecodingResult::F64(v) => geometry.emit(v, |s| f64_sample(s, nodata), &mut runs, sink)?,
            }
        }
        Ok(())
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

/// Which TIFF compressions lose height information, read from the tags and the first chunk.
mod lossy {
    use std::fs::File;
    use std::io::{BufReader, Read, Seek, SeekFrom};
    use std::path::Path;

    use tiff::decoder::Decoder;
    use tiff::tags::Tag;

    use super::tiff_error;
    use crate::error::{IoContext, Result};

    const OLD_JPEG: u16 = 6;
    const JPEG: u16 = 7;
    const JPEG2000: u16 = 34712;
    const LERC: u16 = 34887;
    const WEBP: u16 = 50001;
    const JPEGXL: u16 = 50002;
    #[cfg(not(feature = "gdal"))]
    const LZMA: u16 = 34925;
    /// GDAL's LercParameters tag: [LERC version, extra compression (0 none, 1 deflate, 2 zstd)].
    const LERC_PARAMETERS: u16 = 50674;

    /// The compression's name, for messages.
    #[cfg(not(feature = "gdal"))]
    pub(super) fn name(code: u16) -> String {
        match code {
            OLD_JPEG | JPEG => "JPEG".into(),
            JPEG2000 => "JPEG 2000".into(),
            LERC => "LERC".into(),
            WEBP => "WebP".into(),
            JPEGXL => "JPEG XL".into(),
            LZMA => "LZMA".into(),
            c => format!("code {c}"),
        }
    }

    /// Why a TIFF compressed with `code` is lossy, or `None` when it is not.
    pub(super) fn reason(path: &Path, decoder: &mut Decoder<BufReader<File>>, code: u16) -> Result<Option<String>> {
        Ok(match code {
            OLD_JPEG | JPEG => Some("JPEG compression is lossy".into()),
            JPEG2000 => Some("JPEG 2000 compression may be lossy (the TIFF does not say)".into()),
            JPEGXL => Some("JPEG XL compression may be lossy (the TIFF does not say)".into()),
            WEBP => {
                // A lossless WebP bitstream is a RIFF whose first chunk is `VP8L`.
                let head = first_chunk(path, decoder, 16)?;
                (head.get(12..16) != Some(b"VP8L")).then(|| "lossy WebP compression".into())
            }
            LERC => lerc(path, decoder)?,
            _ => None,
        })
    }

    /// LERC is lossless when its blobs' maximum error is 0 (floats) or at most 0.5 (integers):
    /// read from the first blob's header.
    fn lerc(path: &Path, decoder: &mut Decoder<BufReader<File>>) -> Result<Option<String>> {
        let extra = decoder
            .find_tag(Tag::Unknown(LERC_PARAMETERS))
            .map_err(|e| tiff_error(path, e))?
            .and_then(|v| v.into_u32_vec().ok())
            .and_then(|v| v.get(1).copied())
            .unwrap_or(0);
        // A ZSTD block (at most 128 KiB) must be whole to be decoded: 1 MiB holds the first.
        let raw = first_chunk(path, decoder, 1 << 20)?;
        let blob = match extra {
            0 => raw,
            1 => {
                let mut out = Vec::new();
                // A truncated inflate still yields the header bytes it got to.
                let _ = flate2::read::ZlibDecoder::new(raw.as_slice()).take(64).read_to_end(&mut out);
                out
            }
            #[cfg(feature = "gdal")]
            2 => {
                let mut out = Vec::new();
                if let Ok(d) = ruzstd::decoding::StreamingDecoder::new(raw.as_slice()) {
                    let _ = d.take(64).read_to_end(&mut out);
                }
                out
            }
            _ => Vec::new(),
        };
        Ok(match lerc2_max_error(&blob) {
            Some((max_error, integer)) if max_error == 0.0 || (integer && max_error <= 0.5) => None,
            Some((max_error, _)) => Some(format!("LERC compression with a maximum error of {max_error} is lossy")),
            None => Some("LERC compression may be lossy (its first blob's header is not one relief reads)".into()),
        })
    }

    /// `(maxZError, integer data)` from a Lerc2 blob header (versions 2 to 4): the key `Lerc2 `,
    /// the version, a checksum (version ≥ 3), the sizes (with the depth from version 4), the data
    /// type, then maxZError as a little-endian f64.
    pub(super) fn lerc2_max_error(blob: &[u8]) -> Option<(f64, bool)> {
        let rest = blob.strip_prefix(b"Lerc2 ")?;
        let int = |at: usize| rest.get(at..at + 4).map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]));
        let version = int(0)?;
        let ints = match version {
            2 => 5,
            3 => 5,
            4 => 6,
            _ => return None,
        };
        let data_type_at = 4 + if version >= 3 { 4 } else { 0 } + 4 * ints;
        let data_type = int(data_type_at)?;
        let e = rest.get(data_type_at + 4..data_type_at + 12)?;
        let max_error = f64::from_le_bytes(e.try_into().ok()?);
        // Types 0..=5 are (u)int8/16/32; 6 and 7 are float and double.
        Some((max_error, (0..=5).contains(&data_type)))
    }

    /// Up to `limit` raw (still compressed) bytes of the image's first strip or tile.
    fn first_chunk(path: &Path, decoder: &mut Decoder<BufReader<File>>, limit: u64) -> Result<Vec<u8>> {
        let first = |decoder: &mut Decoder<BufReader<File>>, tag: Tag| -> Result<Option<u64>> {
            Ok(decoder
                .find_tag(tag)
                .map_err(|e| tiff_error(path, e))?
                .and_then(|v| v.into_u64_vec().ok())
                .and_then(|v| v.first().copied()))
        };
        let offset = match first(decoder, Tag::TileOffsets)? {
            Some(o) => Some(o),
            None => first(decoder, Tag::StripOffsets)?,
        };
        let count = match first(decoder, Tag::TileByteCounts)? {
            Some(c) => Some(c),
            None => first(decoder, Tag::StripByteCounts)?,
        };
        let (Some(offset), Some(count)) = (offset, count) else { return Ok(Vec::new()) };
        let mut file = File::open(path).at(path)?;
        file.seek(SeekFrom::Start(offset)).at(path)?;
        let mut out = Vec::new();
        file.take(count.min(limit)).read_to_end(&mut out).at(path)?;
        Ok(out)
    }
}
