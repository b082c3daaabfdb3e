//! PNG reader, streamed one row at a time with the `png` crate: grayscale 8/16-bit heights
//! (optionally with alpha, where alpha 0 means nodata), and the two RGB height encodings,
//! Mapbox Terrain-RGB and Terrarium (8-bit RGB or RGBA; alpha 0 means nodata). A `tRNS` chunk is
//! honoured: pixels of the transparent colour are nodata. Palette and interlaced PNGs are not
//! read.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use png::{BitDepth, ColorType, DecodingError, Transformations};

use super::{check_dimensions, DemFormat, DemInfo, DemSource, Run, RunBuffer};
use crate::error::{Error, IoContext, Result};

/// The eight bytes every PNG starts with.
pub(super) const SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";

/// Rows sampled by [`detect_kind`] to tell Terrain-RGB from Terrarium.
const DETECT_ROWS: u32 = 64;

/// Red values below this median mean Terrain-RGB (see [`super::detect`]).
const TERRAIN_RGB_MAX_RED: u8 = 32;

fn png_error(path: &Path, e: DecodingError) -> Error {
    match e {
        DecodingError::IoError(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
            Error::bad_dem(path, "truncated PNG (unexpected end of file)")
        }
        DecodingError::IoError(e) => Error::io(path, e),
        DecodingError::LimitsExceeded => Error::bad_dem(path, "PNG exceeds the decoder's limits"),
        e => Error::bad_dem(path, format!("invalid PNG: {}", one_line(&e.to_string()))),
    }
}

fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Opens the file for row streaming. `EXPAND` turns a `tRNS` chunk into an alpha channel and
/// low-bit grayscale into 8 bits; 16-bit samples stay 16-bit (big-endian byte pairs).
fn start(path: &Path) -> Result<png::Reader<BufReader<File>>> {
    let file = File::open(path).at(path)?;
    let mut decoder = png::Decoder::new(BufReader::new(file));
    decoder.set_transformations(Transformations::EXPAND);
    decoder.set_ignore_text_chunk(true);
    let reader = decoder.read_info().map_err(|e| png_error(path, e))?;
    let info = reader.info();
    if info.color_type == ColorType::Indexed {
        return Err(Error::Unsupported {
            path: path.to_path_buf(),
            what: "palette PNG (heights need grayscale or Terrain-RGB/Terrarium RGB)".into(),
        });
    }
    if info.interlaced {
        return Err(Error::Unsupported {
            path: path.to_path_buf(),
            what: "interlaced (Adam7) PNG; save it without interlacing".into(),
        });
    }
    Ok(reader)
}

/// Chooses among [`DemFormat::Png`], [`DemFormat::TerrainRgb`] and [`DemFormat::Terrarium`] for a
/// PNG file, by colour type, file name and pixel content (the rule is documented on
/// [`super::detect`]). A colour PNG without any opaque pixel in its first rows counts as
/// Terrain-RGB.
pub(super) fn detect_kind(path: &Path) -> Result<DemFormat> {
    let mut reader = start(path)?;
    let (colour, depth) = reader.output_color_type();
    match colour {
        ColorType::Grayscale | ColorType::GrayscaleAlpha => return Ok(DemFormat::Png),
        ColorType::Rgb | ColorType::Rgba => {}
        ColorType::Indexed => return Err(Error::Unsupported { path: path.to_path_buf(), what: "palette PNG".into() }),
    }
    if depth != BitDepth::Eight {
        return Err(Error::Unsupported {
            path: path.to_path_buf(),
            what: "16-bit colour PNG (Terrain-RGB and Terrarium are 8-bit RGB)".into(),
        });
    }

    let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    if name.contains("terrarium") {
        return Ok(DemFormat::Terrarium);
    }
    if ["terrain-rgb", "terrain_rgb", "terrainrgb", "mapbox"].iter().any(|h| name.contains(h)) {
        return Ok(DemFormat::TerrainRgb);
    }

    let channels = colour.samples();
    let mut red_counts = [0u64; 256];
    let mut rows = 0;
    while rows < DETECT_ROWS {
        let Some(row) = reader.next_row().map_err(|e| png_error(path, e))? else {
            break;
        };
        for px in row.data().chunks_exact(channels) {
            if channels == 3 || px[3] != 0 {
                red_counts[usize::from(px[0])] += 1;
            }
        }
        rows += 1;
    }
    let total: u64 = red_counts.iter().sum();
    if total == 0 {
        return Ok(DemFormat::TerrainRgb);
    }
    // The median: the first red value at which the cumulative count reaches half.
    let mut seen = 0;
    let mut median = 0u8;
    for (red, &count) in red_counts.iter().enumerate() {
        seen += count;
        if 2 * seen >= total {
            median = red as u8;
            break;
        }
    }
    Ok(if median < TERRAIN_RGB_MAX_RED { DemFormat::TerrainRgb } else { DemFormat::Terrarium })
}

/// How one output row of the decoder turns into heights.
#[derive(Clone, Copy, Debug)]
enum Layout {
    /// Grayscale, `bytes` per sample (1 or 2), `alpha`: a second sample follows.
    Gray { bytes: usize, alpha: bool },
    /// 8-bit RGB (3) or RGBA (4) samples per pixel in one of the height encodings.
    Rgb { channels: usize, terrarium: bool },
}

impl Layout {
    fn bytes_per_pixel(self) -> usize {
        match self {
            Layout::Gray { bytes, alpha } => bytes * if alpha { 2 } else { 1 },
            Layout::Rgb { channels, .. } => channels,
        }
    }

    fn height(self, px: &[u8]) -> f64 {
        match self {
            Layout::Gray { bytes: 1, alpha } => {
                if alpha && px[1] == 0 {
                    f64::NAN
                } else {
                    f64::from(px[0])
                }
            }
            Layout::Gray { alpha, .. } => {
                if alpha && px[2] == 0 && px[3] == 0 {
                    f64::NAN
                } else {
                    f64::from(u16::from_be_bytes([px[0], px[1]]))
                }
            }
            Layout::Rgb { channels, terrarium } => {
                if channels == 4 && px[3] == 0 {
                    return f64::NAN;
                }
                let (r, g, b) = (f64::from(px[0]), f64::from(px[1]), f64::from(px[2]));
                if terrarium {
                    r * 256.0 + g + b / 256.0 - 32768.0
                } else {
                    (r * 65536.0 + g * 256.0 + b) * 0.1 - 10000.0
                }
            }
        }
    }
}

/// Works out how to read the decoder's output as `format`, or says why it cannot be.
fn layout_for(path: &Path, format: DemFormat, colour: ColorType, depth: BitDepth) -> Result<Layout> {
    let bytes = match depth {
        BitDepth::Eight => 1,
        BitDepth::Sixteen => 2,
        other => return Err(Error::Unsupported { path: path.to_path_buf(), what: format!("PNG bit depth {other:?}") }),
    };
    let gray = matches!(colour, ColorType::Grayscale | ColorType::GrayscaleAlpha);
    match format {
        DemFormat::Png if gray => Ok(Layout::Gray { bytes, alpha: colour == ColorType::GrayscaleAlpha }),
        DemFormat::Png => Err(Error::bad_dem(
            path,
            "colour PNG cannot be read as a grayscale height PNG (use terrain-rgb or terrarium)",
        )),
        DemFormat::TerrainRgb | DemFormat::Terrarium if gray => Err(Error::bad_dem(
            path,
            format!("grayscale PNG cannot be read as {format} (which needs 8-bit RGB or RGBA)"),
        )),
        DemFormat::TerrainRgb | DemFormat::Terrarium if bytes == 2 => Err(Error::Unsupported {
            path: path.to_path_buf(),
            what: format!("16-bit colour PNG as {format} (which is 8-bit RGB or RGBA)"),
        }),
        DemFormat::TerrainRgb | DemFormat::Terrarium => {
            Ok(Layout::Rgb { channels: colour.samples(), terrarium: format == DemFormat::Terrarium })
        }
        _ => Err(Error::bad_dem(path, format!("a PNG cannot be read as {format}"))),
    }
}

/// A PNG opened for streaming.
struct PngSource {
    path: PathBuf,
    info: DemInfo,
}

pub(super) fn open(path: &Path, format: DemFormat) -> Result<Box<dyn DemSource>> {
    let reader = start(path)?;
    let (width, height) = (reader.info().width, reader.info().height);
    let (width, height) = check_dimensions(path, width.into(), height.into())?;
    let (colour, depth) = reader.output_color_type();
    let layout = layout_for(path, format, colour, depth)?;
    let sample_type = match layout {
        Layout::Gray { bytes, alpha } => {
            format!("uint{} gray{}", bytes * 8, if alpha { "+alpha" } else { "" })
        }
        Layout::Rgb { channels: 3, .. } => "uint8 rgb".to_string(),
        Layout::Rgb { .. } => "uint8 rgba".to_string(),
    };
    let info = DemInfo { format, width, height, spacing: None, nodata: None, sample_type, georef: None };
    Ok(Box::new(PngSource { path: path.to_path_buf(), info }))
}

impl DemSource for PngSource {
    fn info(&self) -> &DemInfo {
        &self.info
    }

    fn read(&mut self, sink: &mut dyn FnMut(Run<'_>) -> Result<()>) -> Result<()> {
        let path = self.path.as_path();
        let mut reader = start(path)?;
        let (colour, depth) = reader.output_color_type();
        let layout = layout_for(path, self.info.format, colour, depth)?;
        if (reader.info().width, reader.info().height) != (self.info.width, self.info.height) {
            return Err(Error::bad_dem(path, "PNG changed since it was opened"));
        }
        let bpp = layout.bytes_per_pixel();
        let row_bytes = self.info.width as usize * bpp;
        let mut runs = RunBuffer::new();
        for y in 0..self.info.height {
            let row = reader
                .next_row()
                .map_err(|e| png_error(path, e))?
                .ok_or_else(|| Error::bad_dem(path, format!("PNG ends after {y} rows")))?;
            let data = row.data();
            if data.len() < row_bytes {
                return Err(Error::bad_dem(path, format!("PNG row {y} is too short")));
            }
            let samples = data[..row_bytes].chunks_exact(bpp).map(|px| layout.height(px));
            runs.emit(y, 0, samples, sink)?;
        }
        // Checks the rest of the image data (checksums, trailing chunks).
        reader.finish().map_err(|e| png_error(path, e))
    }
}
