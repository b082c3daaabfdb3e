//! OpenEXR reader: one channel (f16, f32 or u32) of the first layer at full resolution. With
//! several channels the first named `Y`, `Z`, `R`, `height` or `elevation` (any case, in that
//! order of preference) is read, else the first channel. Streamed one block (scan-line group or
//! tile) at a time with `exr`'s block API; blocks may come in any order. Deep data, sub-sampled
//! channels and multi-part files whose parts differ in size are refused.

use std::collections::HashSet;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use exr::block::reader::ChunksReader;
use exr::meta::attribute::SampleType;
use exr::meta::header::Header;
use exr::meta::BlockDescription;
use exr::prelude::f16;

use super::{check_dimensions, DemFormat, DemInfo, DemSource, Run, RunBuffer};
use crate::error::{Error, IoContext, Result};

/// The largest block (scan-line group or tile, all channels, uncompressed) read: `exr` sizes its
/// buffers from the header's block size, so a small file claiming huge blocks would otherwise
/// make it allocate gigabytes. 256 MiB is 32 lines of a 524,288-post-wide 4-channel f32 image.
const MAX_BLOCK_BYTES: usize = 256 << 20;

/// Channel names taken for heights, in order of preference.
const HEIGHT_CHANNELS: [&str; 5] = ["Y", "Z", "R", "height", "elevation"];

fn exr_error(path: &Path, e: exr::error::Error) -> Error {
    match e {
        exr::error::Error::Io(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
            Error::bad_dem(path, "truncated OpenEXR (unexpected end of file)")
        }
        exr::error::Error::Io(e) => Error::io(path, e),
        exr::error::Error::NotSupported(what) => {
            Error::Unsupported { path: path.to_path_buf(), what: format!("OpenEXR feature: {}", one_line(&what)) }
        }
        e => Error::bad_dem(path, format!("invalid OpenEXR: {}", one_line(&e.to_string()))),
    }
}

fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Starts reading the file's meta data.
fn start(path: &Path) -> Result<exr::block::reader::Reader<BufReader<File>>> {
    let file = BufReader::new(File::open(path).at(path)?);
    exr::block::read(file, false).map_err(|e| exr_error(path, e))
}

/// Which channel of the first layer holds the heights, after checking the file is readable.
fn choose_channel(path: &Path, headers: &[Header]) -> Result<usize> {
    let first = headers.first().ok_or_else(|| Error::bad_dem(path, "OpenEXR without any part"))?;
    if headers.iter().any(|h| h.deep) {
        return Err(Error::Unsupported { path: path.to_path_buf(), what: "deep OpenEXR data".into() });
    }
    if headers.iter().any(|h| h.layer_size != first.layer_size) {
        return Err(Error::Unsupported {
            path: path.to_path_buf(),
            what: "multi-part OpenEXR whose parts differ in size".into(),
        });
    }
    let channels = &first.channels.list;
    if channels.is_empty() {
        return Err(Error::bad_dem(path, "OpenEXR layer without channels"));
    }
    let index = HEIGHT_CHANNELS
        .iter()
        .find_map(|name| channels.iter().position(|c| c.name.eq_case_insensitive(name)))
        .unwrap_or(0);
    if channels.iter().any(|c| c.sampling.0 != 1 || c.sampling.1 != 1) {
        return Err(Error::Unsupported { path: path.to_path_buf(), what: "sub-sampled OpenEXR channels".into() });
    }
    if let Some(bytes) = headers.iter().map(block_bytes).find(|b| b.is_none_or(|b| b > MAX_BLOCK_BYTES)) {
        let size = bytes.map_or("more than 2^64".to_string(), |b| b.to_string());
        return Err(Error::Unsupported {
            path: path.to_path_buf(),
            what: format!("OpenEXR blocks of {size} bytes (at most {MAX_BLOCK_BYTES} are read)"),
        });
    }
    Ok(index)
}

/// Bytes of one uncompressed block of a part (all channels), what `exr` allocates per block;
/// `None` if that overflows.
fn block_bytes(header: &Header) -> Option<usize> {
    let (width, lines) = match &header.blocks {
        BlockDescription::Tiles(tiles) => (tiles.tile_size.0, tiles.tile_size.1),
        BlockDescription::ScanLines => (header.layer_size.0, header.compression.scan_lines_per_block()),
    };
    header.channels.bytes_per_pixel.checked_mul(width)?.checked_mul(lines)
}

struct Exr {
    path: PathBuf,
    info: DemInfo,
}

pub(super) fn open(path: &Path) -> Result<Box<dyn DemSource>> {
    let reader = start(path)?;
    let headers = reader.headers();
    let channel = choose_channel(path, headers)?;
    let header = &headers[0];
    let size = header.layer_size;
    let (width, height) = check_dimensions(path, size.0 as u64, size.1 as u64)?;
    let description = &header.channels.list[channel];
    let kind = match description.sample_type {
        SampleType::F16 => "float16",
        SampleType::F32 => "float32",
        SampleType::U32 => "uint32",
    };
    let sample_type = format!("{kind} channel {}", description.name);
    let info =
        DemInfo { format: DemFormat::Exr, width, height, spacing: None, nodata: None, sample_type, georef: None };
    Ok(Box::new(Exr { path: path.to_path_buf(), info }))
}

impl DemSource for Exr {
    fn info(&self) -> &DemInfo {
        &self.info
    }

    fn read(&mut self, sink: &mut dyn FnMut(Run<'_>) -> Result<()>) -> Result<()> {
        let path = self.path.as_path();
        let reader = start(path)?;
        let channel = choose_channel(path, reader.headers())?;
        let header = &reader.headers()[0];
        if header.layer_size.0 != self.info.width as usize || header.layer_size.1 != self.info.height as usize {
            return Err(Error::bad_dem(path, "OpenEXR changed since it was opened"));
        }
        let channels = header.channels.list.clone();
        let sample_type = channels[channel].sample_type;

        let chunks = reader
            .filter_chunks(false, |_, tile, block| block.layer == 0 && tile.is_largest_resolution_level())
            .map_err(|e| exr_error(path, e))?;
        let mut blocks = chunks.sequential_decompressor(false);

        let (width, height) = (self.info.width as usize, self.info.height as usize);
        let mut seen = HashSet::new();
        let mut delivered = 0u64;
        let mut runs = RunBuffer::new();
        while let Some(block) = blocks.decompress_next_block() {
            let block = block.map_err(|e| exr_error(path, e))?;
            let (x, y) = (block.index.pixel_position.0, block.index.pixel_position.1);
            let (w, h) = (block.index.pixel_size.0, block.index.pixel_size.1);
            if x.checked_add(w).is_none_or(|e| e > width) || y.checked_add(h).is_none_or(|e| e > height) {
                return Err(Error::bad_dem(path, format!("OpenEXR block at ({x}, {y}) lies outside the image")));
            }
            if !seen.insert((x, y)) {
                return Err(Error::bad_dem(path, format!("OpenEXR block at ({x}, {y}) appears twice")));
            }
            // Each line of the block holds all samples of channel 0, then of channel 1, ….
            let line_bytes: Vec<usize> = channels.iter().map(|c| w * c.sample_type.bytes_per_sample()).collect();
            let stride: usize = line_bytes.iter().sum();
            let offset: usize = line_bytes[..channel].iter().sum();
            for line in 0..h {
                let start = line * stride + offset;
                let bytes = block
                    .data
                    .get(start..start + line_bytes[channel])
                    .ok_or_else(|| Error::bad_dem(path, "OpenEXR block shorter than its size"))?;
                let row = (y + line) as u32;
                let x0 = x as u32;
                match sample_type {
                    SampleType::F16 => runs.emit(
                        row,
                        x0,
                        bytes.chunks_exact(2).map(|b| finite(f16::from_ne_bytes([b[0], b[1]]).to_f64())),
                        sink,
                    )?,
                    SampleType::F32 => runs.emit(
                        row,
                        x0,
                        bytes.chunks_exact(4).map(|b| finite(f64::from(f32::from_ne_bytes([b[0], b[1], b[2], b[3]])))),
                        sink,
                    )?,
                    SampleType::U32 => runs.emit(
                        row,
                        x0,
                        bytes.chunks_exact(4).map(|b| f64::from(u32::from_ne_bytes([b[0], b[1], b[2], b[3]]))),
                        sink,
                    )?,
                }
            }
            delivered += (w * h) as u64;
        }
        let expected = u64::from(self.info.width) * u64::from(self.info.height);
        if delivered != expected {
            return Err(Error::bad_dem(path, format!("OpenEXR blocks cover {delivered} of {expected} samples")));
        }
        Ok(())
    }
}

/// Non-finite samples (NaN, ±inf) are nodata.
fn finite(v: f64) -> f64 {
    if v.is_finite() {
        v
    } else {
        f64::NAN
    }
}
