//! The `.relief` terrain file: a 256-byte little-endian header, padded to one 4 KiB page, then the
//! vertex records in layout order.
//!
//! ```text
//! offset size  field
//!      0    8  magic "\x89RELIEF\n"
//!      8    4  version (1)
//!     12    4  header bytes (256)
//!     16    4  layout code (0 row-major, 1 tiled, 2 interleaved, 3 embedded, 4 hz)
//!     20    4  layout parameter (tile side for tiled, else 0)
//!     24    4  record format (1: z, error, radius as f32 metres)
//!     28    4  record bytes (12)
//!     32    4  n (grid side 2^n + 1)
//!     36    4  levels (2n)
//!     40    4  grid side (2^n + 1)
//!     44    4  flags (bit 0: spacing assumed, bit 1: source grid was geographic)
//!     48   16  valid window x0, y0, x1, y1 (u32 each, grid posts, half-open)
//!     64    4  source DEM format code
//!     68    4  reserved (0)
//!     72    8  records (index-space size)
//!     80    8  vertices ((2^n + 1)²)
//!     88    8  payload offset (4096)
//!     96    8  payload bytes (records × record bytes)
//!    104   16  spacing x, y in metres (f64)
//!    120   16  z scale, z offset (f64): the transform applied to the source values
//!    136   16  z min, z max over the valid window, metres (f64)
//!    152    8  nodata samples filled (u64)
//!    160   24  source centre latitude and post spacing x, y in degrees (f64; NaN if projected)
//!    184   56  reserved (0)
//!    240    8  payload checksum: XXH3-64 over the XXH3-64s of 786,432-byte payload blocks
//!    248    8  header checksum: XXH3-64 of bytes 0..248
//! ```
//! Records in unused slots of the index space are all zero bytes. The header checksum is verified
//! on every open (it is cheap); the payload checksum only on request ([`TerrainFile::verify_payload`]).

use std::fs::File;
use std::path::{Path, PathBuf};

use bytemuck::{Pod, Zeroable};
use memmap2::Mmap;

use crate::error::{Error, IoContext, Result};
use crate::layout::hierarchy::{Grid, MAX_N};
use crate::layout::{AnyLayout, Layout, LayoutKind};

pub const MAGIC: [u8; 8] = *b"\x89RELIEF\n";
pub const VERSION: u32 = 1;
pub const HEADER_BYTES: usize = 256;
/// Records start on this boundary (one page), so a record never shares a page with the header.
pub const PAYLOAD_OFFSET: u64 = 4096;
pub const RECORD_FORMAT_F32: u32 = 1;

/// One vertex record: height, nested object-space error and nested bounding-sphere radius, all in
/// metres. Stored little-endian; mapped in place.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Record {
    pub z: f32,
    pub error: f32,
    pub radius: f32,
}

pub const RECORD_BYTES: u32 = std::mem::size_of::<Record>() as u32;

pub const FLAG_SPACING_ASSUMED: u32 = 1;
pub const FLAG_GEOGRAPHIC: u32 = 2;

/// The decoded header.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    pub version: u32,
    pub layout: LayoutKind,
    pub layout_param: u32,
    pub record_format: u32,
    pub record_bytes: u32,
    pub n: u32,
    pub flags: u32,
    /// Valid window in grid posts: `[x0, y0, x1, y1)`; outside it is edge-replicated padding.
    pub valid_window: [u32; 4],
    pub source_format: u32,
    pub records: u64,
    pub payload_offset: u64,
    pub payload_bytes: u64,
    pub spacing_m: [f64; 2],
    pub z_scale: f64,
    pub z_offset: f64,
    pub z_min: f64,
    pub z_max: f64,
    pub nodata_filled: u64,
    /// Centre latitude of a geographic source grid (NaN if projected).
    pub source_centre_lat_deg: f64,
    /// Post spacing of a geographic source grid in degrees (NaN if projected).
    pub source_spacing_deg: [f64; 2],
    pub payload_checksum: u64,
}

pub(crate) fn put_u32(b: &mut [u8], at: usize, v: u32) {
    b[at..at + 4].copy_from_slice(&v.to_le_bytes());
}
pub(crate) fn put_u64(b: &mut [u8], at: usize, v: u64) {
    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
}
pub(crate) fn put_f64(b: &mut [u8], at: usize, v: f64) {
    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
}
pub(crate) fn get_u32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}
pub(crate) fn get_u64(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}
pub(crate) fn get_f64(b: &[u8], at: usize) -> f64 {
    f64::from_bits(get_u64(b, at))
}

impl Header {
    pub fn grid(&self) -> Grid {
        // Validated at decode time.
        Grid::new(self.n).expect("header n validated")
    }

    pub fn vertices(&self) -> u64 {
        self.grid().vertices()
    }

    /// Extent in metres `[width, height]` of the whole grid (posts span `side − 1` spacings).
    pub fn extent_m(&self) -> [f64; 2] {
        let spans = (self.grid().size() - 1) as f64;
        [spans * self.spacing_m[0], spans * self.spacing_m[1]]
    }

    /// The file's layout, rebuilt from the header.
    pub fn layout(&self) -> AnyLayout {
        AnyLayout::new(self.layout, self.grid(), self.layout_param, self.record_bytes).expect("header layout validated")
    }

    /// Encodes the header into its 256 bytes, computing the header checksum.
    pub fn encode(&self) -> [u8; HEADER_BYTES] {
        let mut b = [0u8; HEADER_BYTES];
        b[0..8].copy_from_slice(&MAGIC);
        put_u32(&mut b, 8, self.version);
        put_u32(&mut b, 12, HEADER_BYTES as u32);
        put_u32(&mut b, 16, self.layout as u32);
        put_u32(&mut b, 20, self.layout_param);
        put_u32(&mut b, 24, self.record_format);
        put_u32(&mut b, 28, self.record_bytes);
        put_u32(&mut b, 32, self.n);
        put_u32(&mut b, 36, 2 * self.n);
        put_u32(&mut b, 40, (1u32 << self.n) + 1);
        put_u32(&mut b, 44, self.flags);
        for (k, v) in self.valid_window.iter().enumerate() {
            put_u32(&mut b, 48 + 4 * k, *v);
        }
        put_u32(&mut b, 64, self.source_format);
        put_u64(&mut b, 72, self.records);
        put_u64(&mut b, 80, self.vertices());
        put_u64(&mut b, 88, self.payload_offset);
        put_u64(&mut b, 96, self.payload_bytes);
        put_f64(&mut b, 104, self.spacing_m[0]);
        put_f64(&mut b, 112, self.spacing_m[1]);
        put_f64(&mut b, 120, self.z_scale);
        put_f64(&mut b, 128, self.z_offset);
        put_f64(&mut b, 136, self.z_min);
        put_f64(&mut b, 144, self.z_max);
        put_u64(&mut b, 152, self.nodata_filled);
        put_f64(&mut b, 160, self.source_centre_lat_deg);
        put_f64(&mut b, 168, self.source_spacing_deg[0]);
        put_f64(&mut b, 176, self.source_spacing_deg[1]);
        put_u64(&mut b, 240, self.payload_checksum);
        let sum = xxhash_rust::xxh3::xxh3_64(&b[..248]);
        put_u64(&mut b, 248, sum);
        b
    }

    /// Decodes and validates a header: magic, version, checksum, and every field's consistency
    /// with the others. `file_len` is checked against the payload size.
    pub fn decode(path: &Path, b: &[u8], file_len: u64) -> Result<Header> {
        let bad = |problem: String| Error::BadHeader { path: path.to_path_buf(), problem };
        if b.len() < 8 || b[0..8] != MAGIC {
            return Err(Error::BadMagic { path: path.to_path_buf() });
        }
        if b.len() < 12 {
            return Err(Error::Truncated { path: path.into(), expected: PAYLOAD_OFFSET, found: file_len });
        }
        let version = get_u32(b, 8);
        if version != VERSION {
            return Err(Error::BadVersion { path: path.into(), found: version, supported: VERSION });
        }
        if b.len() < HEADER_BYTES {
            return Err(Error::Truncated { path: path.into(), expected: PAYLOAD_OFFSET, found: file_len });
        }
        let stored = get_u64(b, 248);
        let computed = xxhash_rust::xxh3::xxh3_64(&b[..248]);
        if stored != computed {
            return Err(Error::Checksum { path: path.into(), which: "header", stored, computed });
        }
        if get_u32(b, 12) as usize != HEADER_BYTES {
            return Err(bad(format!("header size {} (expected {HEADER_BYTES})", get_u32(b, 12))));
        }
        let layout = LayoutKind::from_code(get_u32(b, 16))
            .ok_or_else(|| bad(format!("unknown layout code {}", get_u32(b, 16))))?;
        let n = get_u32(b, 32);
        let grid = Grid::new(n).ok_or_else(|| bad(format!("grid exponent n = {n} outside 1..={MAX_N}")))?;
        if get_u32(b, 36) != 2 * n || get_u32(b, 40) != grid.size() {
            return Err(bad(format!("levels {} / side {} disagree with n = {n}", get_u32(b, 36), get_u32(b, 40))));
        }
        let h = Header {
            version,
            layout,
            layout_param: get_u32(b, 20),
            record_format: get_u32(b, 24),
            record_bytes: get_u32(b, 28),
            n,
            flags: get_u32(b, 44),
            valid_window: [get_u32(b, 48), get_u32(b, 52), get_u32(b, 56), get_u32(b, 60)],
            source_format: get_u32(b, 64),
            records: get_u64(b, 72),
            payload_offset: get_u64(b, 88),
            payload_bytes: get_u64(b, 96),
            spacing_m: [get_f64(b, 104), get_f64(b, 112)],
            z_scale: get_f64(b, 120),
            z_offset: get_f64(b, 128),
            z_min: get_f64(b, 136),
            z_max: get_f64(b, 144),
            nodata_filled: get_u64(b, 152),
            source_centre_lat_deg: get_f64(b, 160),
            source_spacing_deg: [get_f64(b, 168), get_f64(b, 176)],
            payload_checksum: get_u64(b, 240),
        };
        if h.record_format != RECORD_FORMAT_F32 || h.record_bytes != RECORD_BYTES {
            return Err(bad(format!("unknown record format {} of {} bytes", h.record_format, h.record_bytes)));
        }
        let layout = AnyLayout::new(layout, grid, h.layout_param, h.record_bytes).map_err(bad)?;
        if h.records != layout.records() {
            return Err(bad(format!(
                "{} records, but a {} layout of a {}² grid has {}",
                h.records,
                h.layout,
                grid.size(),
                layout.records()
            )));
        }
        if get_u64(b, 80) != grid.vertices() {
            return Err(bad(format!("vertex count {} (expected {})", get_u64(b, 80), grid.vertices())));
        }
        if h.payload_offset != PAYLOAD_OFFSET {
            return Err(bad(format!("payload offset {} (expected {PAYLOAD_OFFSET})", h.payload_offset)));
        }
        let want_bytes = h.records.checked_mul(h.record_bytes as u64);
        if want_bytes != Some(h.payload_bytes) {
            return Err(bad(format!("payload size {} does not match {} records", h.payload_bytes, h.records)));
        }
        let [x0, y0, x1, y1] = h.valid_window;
        if !(x0 < x1 && y0 < y1 && x1 <= grid.size() && y1 <= grid.size()) {
            return Err(bad(format!("valid window {:?} outside the {}² grid", h.valid_window, grid.size())));
        }
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(h.spacing_m[0]) || !positive(h.spacing_m[1]) {
            return Err(bad(format!("post spacing {:?} m is not positive", h.spacing_m)));
        }
        if !(h.z_min.is_finite() && h.z_max.is_finite() && h.z_min <= h.z_max) {
            return Err(bad(format!("height range {}..{} is not finite", h.z_min, h.z_max)));
        }
        let expected = h.payload_offset + h.payload_bytes;
        if file_len != expected {
            return Err(Error::Truncated { path: path.into(), expected, found: file_len });
        }
        Ok(h)
    }
}

/// An open, validated terrain file, mapped read-only.
pub struct TerrainFile {
    path: PathBuf,
    header: Header,
    layout: AnyLayout,
    // Keeps the file open for the map's lifetime (and documents what is mapped).
    _file: File,
    map: Mmap,
}

impl TerrainFile {
    /// Opens and validates a terrain file: magic, version, header checksum, field consistency and
    /// the exact file size. The payload checksum is not checked here (see [`Self::verify_payload`]).
    pub fn open(path: &Path) -> Result<TerrainFile> {
        let file = File::open(path).at(path)?;
        let file_len = file.metadata().at(path)?.len();
        let mut head = vec![0u8; (HEADER_BYTES as u64).min(file_len) as usize];
        {
            use std::io::Read;
            (&file).read_exact(&mut head).at(path)?;
        }
        let header = Header::decode(path, &head, file_len)?;
        let map = crate::pager::source::map_read_only(path, &file, file_len)?;
        let layout = header.layout();
        Ok(TerrainFile { path: path.to_path_buf(), header, layout, _file: file, map })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn header(&self) -> &Header {
        &self.header
    }

    pub fn layout(&self) -> &AnyLayout {
        &self.layout
    }

    pub fn grid(&self) -> Grid {
        self.header.grid()
    }

    /// The payload as raw bytes.
    pub fn payload(&self) -> &[u8] {
        let start = self.header.payload_offset as usize;
        &self.map[start..start + self.header.payload_bytes as usize]
    }

    /// All record slots in layout order (unused slots are zero).
    pub fn records(&self) -> &[Record] {
        // Page-aligned start and a size that is a multiple of the record size (validated).
        bytemuck::cast_slice(self.payload())
    }

    /// Asks the kernel not to read ahead around faults in the mapping (`madvise(MADV_RANDOM)`),
    /// so fault counts reflect the pages actually touched.
    pub fn advise_random(&self) -> Result<()> {
        self.map.advise(memmap2::Advice::Random).at(&self.path)
    }

    /// The record of grid position `(x, y)`.
    pub fn record_at(&self, x: u32, y: u32) -> Record {
        self.records()[self.layout.index(x, y) as usize]
    }

    /// Recomputes the payload checksum and compares it with the header's.
    pub fn verify_payload(&self) -> Result<()> {
        let computed = payload_checksum(self.payload());
        if computed != self.header.payload_checksum {
            return Err(Error::Checksum {
                path: self.path.clone(),
                which: "payload",
                stored: self.header.payload_checksum,
                computed,
            });
        }
        Ok(())
    }
}

/// The payload is checksummed in blocks of this many bytes (65,536 records of 12 bytes), so the
/// checksum can be computed in parallel, and block by block while the payload is written.
pub const CHECKSUM_BLOCK_BYTES: usize = 65_536 * RECORD_BYTES as usize;

/// Hash of one checksum block.
pub fn block_hash(block: &[u8]) -> u64 {
    xxhash_rust::xxh3::xxh3_64(block)
}

/// Combines per-block hashes (in block order) into the payload checksum: XXH3-64 of their
/// little-endian bytes.
pub fn combine_block_hashes(hashes: &[u64]) -> u64 {
    let bytes: Vec<u8> = hashes.iter().flat_map(|h| h.to_le_bytes()).collect();
    xxhash_rust::xxh3::xxh3_64(&bytes)
}

/// The payload checksum: XXH3-64 of each [`CHECKSUM_BLOCK_BYTES`] block (the last may be
/// shorter), combined with [`combine_block_hashes`]. Computed in parallel.
pub fn payload_checksum(payload: &[u8]) -> u64 {
    use rayon::prelude::*;
    let hashes: Vec<u64> = payload.par_chunks(CHECKSUM_BLOCK_BYTES).map(block_hash).collect();
    combine_block_hashes(&hashes)
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn sample_header() -> Header {
        let grid = Grid::new(3).unwrap();
        let layout = AnyLayout::new(LayoutKind::RowMajor, grid, 0, RECORD_BYTES).unwrap();
        Header {
            version: VERSION,
            layout: LayoutKind::RowMajor,
            layout_param: 0,
            record_format: RECORD_FORMAT_F32,
            record_bytes: RECORD_BYTES,
            n: 3,
            flags: 0,
            valid_window: [0, 0, 7, 9],
            source_format: 0,
            records: layout.records(),
            payload_offset: PAYLOAD_OFFSET,
            payload_bytes: layout.records() * RECORD_BYTES as u64,
            spacing_m: [25.0, 25.0],
            z_scale: 1.0,
            z_offset: 0.0,
            z_min: 393.0,
            z_max: 870.0,
            nodata_filled: 2,
            source_centre_lat_deg: f64::NAN,
            source_spacing_deg: [f64::NAN, f64::NAN],
            payload_checksum: 0x0123_4567_89ab_cdef,
        }
    }

    fn file_len(h: &Header) -> u64 {
        h.payload_offset + h.payload_bytes
    }

    #[test]
    fn header_round_trips() {
        let h = sample_header();
        let b = h.encode();
        let d = Header::decode(Path::new("t.relief"), &b, file_len(&h)).unwrap();
        assert_eq!(d.encode(), b);
        assert_eq!(d.records, 81);
        assert_eq!(d.extent_m(), [200.0, 200.0]);
    }

    #[test]
    fn header_rejects_damage() {
        let h = sample_header();
        let p = Path::new("t.relief");
        let b = h.encode();
        let mut m = b;
        m[0] = b'X';
        assert!(matches!(Header::decode(p, &m, 0), Err(Error::BadMagic { .. })));
        let mut m = b;
        m[8] = 9;
        assert!(matches!(Header::decode(p, &m, 0), Err(Error::BadVersion { found: 9, .. })));
        let mut m = b;
        m[100] ^= 1;
        assert!(matches!(Header::decode(p, &m, file_len(&h)), Err(Error::Checksum { which: "header", .. })));
        assert!(matches!(Header::decode(p, &b, file_len(&h) - 1), Err(Error::Truncated { .. })));
        assert!(matches!(Header::decode(p, &b[..100], 100), Err(Error::Truncated { .. })));
        // A consistent checksum over inconsistent fields is still rejected.
        let mut bad = h.clone();
        bad.records += 1;
        let e = Header::decode(p, &bad.encode(), file_len(&h)).unwrap_err();
        assert!(e.to_string().contains("records"), "{e}");
        let mut bad = h.clone();
        bad.valid_window = [0, 0, 10, 9];
        assert!(Header::decode(p, &bad.encode(), file_len(&h)).is_err());
        let mut bad = h;
        bad.spacing_m = [0.0, 1.0];
        assert!(Header::decode(p, &bad.encode(), file_len(&bad)).is_err());
    }
}
