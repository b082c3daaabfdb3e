//! The `.relief` terrain file: a 256-byte little-endian header, padded to one 4 KiB page, then the
//! vertex records in layout order, of which only the pages holding stored records are kept
//! (version 3: see "Stored pages" below).
//!
//! ```text
//! offset size  field
//!      0    8  magic "\x89RELIEF\n"
//!      8    4  version (3; versions 1 (no CRS fields at 184..232) and 2 (every page stored) are still read)
//!     12    4  header bytes (256)
//!     16    4  layout code (0 row-major, 1 tiled, 2 interleaved, 3 embedded, 4 hz)
//!     20    4  layout parameter (tile side for tiled, else 0)
//!     24    4  record format (1: z, error, radius as f32 metres)
//!     28    4  record bytes (12)
//!     32    4  n (grid side 2^n + 1)
//!     36    4  levels (2n)
//!     40    4  grid side (2^n + 1)
//!     44    4  flags (bit 0: spacing assumed, bit 1: source grid was geographic, bit 2: stored pages)
//!     48   16  valid window x0, y0, x1, y1 (u32 each, grid posts, half-open)
//!     64    4  source DEM format code
//!     68    4  pages of the page map (flag bit 2; else 0)                    [version 3]
//!     72    8  records (index-space size)
//!     80    8  vertices ((2^n + 1)²)
//!     88    8  payload offset (4096)
//!     96    8  payload bytes (records × record bytes, as read: pages left out count)
//!    104   16  spacing x, y in metres (f64)
//!    120   16  z scale, z offset (f64): the transform applied to the source values
//!    136   16  z min, z max over the valid window, metres (f64)
//!    152    8  nodata samples filled (u64)
//!    160   24  source centre latitude and post spacing x, y in degrees (f64; NaN if projected)
//!    184    4  CRS: EPSG code of the horizontal CRS (0: none named)          [version 2]
//!    188    2  CRS kind (0 unknown, 1 projected, 2 geographic)
//!    190    2  CRS horizontal unit (EPSG unit code; 0 not stated)
//!    192    4  CRS: EPSG code of the vertical CRS (0: none named)
//!    196    2  CRS vertical unit of the source heights (EPSG unit code; 0 not stated)
//!    198    2  CRS flags (bit 0: georeferenced, the fields 184..232 hold a CRS and placement)
//!    200   16  CRS coordinates of grid post (0, 0) (f64 x, y)
//!    216   16  CRS units from post to post, east and north (f64, positive)
//!    232    8  void mask offset (0: no mask; else a multiple of 4096 after the payload)
//!    240    8  payload checksum: XXH3-64 over the XXH3-64s of 786,432-byte payload blocks
//!    248    8  header checksum: XXH3-64 of bytes 0..248
//! ```
//! Records in unused slots of the index space are all zero bytes.
//!
//! **Stored pages** (flag bit 2, version 3). Only the vertices of [`Stored`] over the valid window
//! (the data and their DAG ancestors; ARCHITECTURE.md, "Padding that is never stored") have
//! records; the others (null vertices) are zero, and a 4 KiB page of the payload that holds no
//! stored record is left out of the file. The offsets above, and everything read through the
//! pager, are those of the file *as read*, with every page in place; on disk the header page is
//! followed by the page map (its page count at 68): an XXH3-64 of the bytes after it up to the end
//! of the runs, the number of runs, and per run the first payload page and the page count (u64
//! each), zero-padded to a page; then the stored payload pages in order, whole pages; then the void
//! mask. A sparse file must have a valid window starting at post (0, 0).
//!
//! Where the DEM had nodata, a
//! void mask follows the payload at its own page: an XXH3-64 of the bits, then one bit per post of
//! the valid window, row by row from the south, least significant bit first ([`VoidMask`]). The header checksum is verified
//! on every open (it is cheap); the payload checksum only on request ([`TerrainFile::verify_payload`]).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use bytemuck::{Pod, Zeroable};

use super::{read_header, FileKind, Format, HeaderBytes, Problem};
use crate::error::{Error, Result};
use crate::georef::{CrsKind, Georef};
use crate::layout::hierarchy::{Grid, MAX_N};
use crate::layout::{AnyLayout, Layout, LayoutKind, Stored};
use crate::pager::sparse::{PageMap, SparseFile, PAGE_BYTES};
use crate::pager::{source, Access, FixedBlocks, Pager};

pub const VERSION: u32 = 3;
/// The oldest version this build reads (version 1 has no CRS: its bytes 184..232 are zero).
pub const OLDEST_VERSION: u32 = 1;
pub const HEADER_BYTES: usize = super::HEADER_BYTES;
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
/// Only the [`Stored`] vertices have records, and pages without one are left out (version 3).
pub const FLAG_STORED_PAGES: u32 = 4;

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
    /// The source's CRS and the grid's placement in it, where the source said (version 2).
    pub georef: Option<Georef>,
    /// Where the void mask starts (0: the file has none; every post was data).
    pub void_mask_offset: u64,
    /// Pages of the page map after the header page (flag [`FLAG_STORED_PAGES`]; else 0).
    pub page_map_pages: u32,
    pub payload_checksum: u64,
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

    /// Bytes of the void mask's bits: one per post of the valid window.
    pub fn void_mask_bits_bytes(&self) -> u64 {
        let [x0, y0, x1, y1] = self.valid_window;
        ((x1 - x0) as u64 * (y1 - y0) as u64).div_ceil(8)
    }

    /// Where the void mask would start: the first page after the payload.
    pub fn void_mask_start(&self) -> u64 {
        (self.payload_offset + self.payload_bytes).next_multiple_of(4096)
    }

    /// Whether only the [`Stored`] vertices have records (and pages without one are left out).
    pub fn stores_pages(&self) -> bool {
        self.flags & FLAG_STORED_PAGES != 0
    }

    /// The vertices that have records: the data and their ancestors, or every vertex in files
    /// without [`FLAG_STORED_PAGES`].
    pub fn stored(&self) -> Stored {
        if self.stores_pages() {
            Stored::new(self.grid(), self.valid_window[2], self.valid_window[3])
        } else {
            Stored::all(self.grid())
        }
    }

    /// The post whose height `(x, y)` has: itself, or in a file with stored pages its nearest post
    /// of the valid window (the padding's heights, which are not stored, replicate the edge).
    #[inline]
    pub fn data_post(&self, x: u32, y: u32) -> (u32, u32) {
        if self.stores_pages() {
            (x.min(self.valid_window[2] - 1), y.min(self.valid_window[3] - 1))
        } else {
            (x, y)
        }
    }

    /// The file's exact length as read (every page in place; see [`Self::stores_pages`]).
    pub fn file_len(&self) -> u64 {
        match self.void_mask_offset {
            0 => self.payload_offset + self.payload_bytes,
            at => at + 8 + self.void_mask_bits_bytes(),
        }
    }

    /// The file's layout, rebuilt from the header.
    pub fn layout(&self) -> AnyLayout {
        AnyLayout::new(self.layout, self.grid(), self.layout_param, self.record_bytes).expect("header layout validated")
    }
}

impl Format for Header {
    const KIND: FileKind = FileKind::Terrain;

    fn encode_fields(&self, h: &mut HeaderBytes) {
        h.put_u32(8, self.version);
        h.put_u32(12, HEADER_BYTES as u32);
        h.put_u32(16, self.layout as u32);
        h.put_u32(20, self.layout_param);
        h.put_u32(24, self.record_format);
        h.put_u32(28, self.record_bytes);
        h.put_u32(32, self.n);
        h.put_u32(36, 2 * self.n);
        h.put_u32(40, (1u32 << self.n) + 1);
        h.put_u32(44, self.flags);
        for (k, v) in self.valid_window.iter().enumerate() {
            h.put_u32(48 + 4 * k, *v);
        }
        h.put_u32(64, self.source_format);
        h.put_u64(72, self.records);
        h.put_u64(80, self.vertices());
        h.put_u64(88, self.payload_offset);
        h.put_u64(96, self.payload_bytes);
        h.put_f64(104, self.spacing_m[0]);
        h.put_f64(112, self.spacing_m[1]);
        h.put_f64(120, self.z_scale);
        h.put_f64(128, self.z_offset);
        h.put_f64(136, self.z_min);
        h.put_f64(144, self.z_max);
        h.put_u64(152, self.nodata_filled);
        h.put_f64(160, self.source_centre_lat_deg);
        h.put_f64(168, self.source_spacing_deg[0]);
        h.put_f64(176, self.source_spacing_deg[1]);
        if let Some(g) = &self.georef {
            h.put_u32(184, g.epsg);
            h.put_u32(188, g.kind as u32 | u32::from(g.unit) << 16);
            h.put_u32(192, g.vertical_epsg);
            h.put_u32(196, u32::from(g.vertical_unit) | 1 << 16);
            h.put_f64(200, g.origin[0]);
            h.put_f64(208, g.origin[1]);
            h.put_f64(216, g.step[0]);
            h.put_f64(224, g.step[1]);
        }
        h.put_u32(68, self.page_map_pages);
        h.put_u64(232, self.void_mask_offset);
        h.put_u64(240, self.payload_checksum);
    }

    /// Checks every field's consistency with the others, and `file_len` against the payload.
    fn decode(b: &HeaderBytes, file_len: u64) -> std::result::Result<Header, Problem> {
        let bad = |what: String| Problem::Corrupt(format!("header: {what}"));
        if b.u32(12) as usize != HEADER_BYTES {
            return Err(bad(format!("header size {} (expected {HEADER_BYTES})", b.u32(12))));
        }
        let layout =
            LayoutKind::from_code(b.u32(16)).ok_or_else(|| bad(format!("unknown layout code {}", b.u32(16))))?;
        let n = b.u32(32);
        let grid = Grid::new(n).ok_or_else(|| bad(format!("grid exponent n = {n} outside 1..={MAX_N}")))?;
        if b.u32(36) != 2 * n || b.u32(40) != grid.size() {
            return Err(bad(format!("levels {} / side {} disagree with n = {n}", b.u32(36), b.u32(40))));
        }
        let h = Header {
            version: b.u32(8),
            layout,
            layout_param: b.u32(20),
            record_format: b.u32(24),
            record_bytes: b.u32(28),
            n,
            flags: b.u32(44),
            valid_window: [b.u32(48), b.u32(52), b.u32(56), b.u32(60)],
            source_format: b.u32(64),
            records: b.u64(72),
            payload_offset: b.u64(88),
            payload_bytes: b.u64(96),
            spacing_m: [b.f64(104), b.f64(112)],
            z_scale: b.f64(120),
            z_offset: b.f64(128),
            z_min: b.f64(136),
            z_max: b.f64(144),
            nodata_filled: b.u64(152),
            source_centre_lat_deg: b.f64(160),
            source_spacing_deg: [b.f64(168), b.f64(176)],
            georef: decode_georef(b).map_err(bad)?,
            void_mask_offset: b.u64(232),
            page_map_pages: b.u32(68),
            payload_checksum: b.u64(240),
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
        if b.u64(80) != grid.vertices() {
            return Err(bad(format!("vertex count {} (expected {})", b.u64(80), grid.vertices())));
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
        if h.void_mask_offset != 0 && h.void_mask_offset != h.void_mask_start() {
            return Err(bad(format!(
                "void mask offset {} (expected {}, the page after the payload)",
                h.void_mask_offset,
                h.void_mask_start()
            )));
        }
        if h.stores_pages() {
            if h.version < 3 || h.page_map_pages == 0 || x0 != 0 || y0 != 0 {
                return Err(bad(format!(
                    "stored pages (flag 4) need version 3, a page map and a window from (0, 0): version {}, {} map pages, window {:?}",
                    h.version, h.page_map_pages, h.valid_window
                )));
            }
            // The exact length is checked against the page map when the file is opened.
            let least = PAYLOAD_OFFSET * (1 + h.page_map_pages as u64);
            if file_len < least {
                return Err(Problem::Truncated { expected: least, found: file_len });
            }
            return Ok(h);
        }
        if h.page_map_pages != 0 {
            return Err(bad(format!("{} page map pages without stored pages (flag 4)", h.page_map_pages)));
        }
        let expected = h.file_len();
        if file_len != expected {
            return Err(Problem::Truncated { expected, found: file_len });
        }
        Ok(h)
    }
}

/// The CRS fields (bytes 184..232), present when flag bit 0 at 198 is set (never in version 1,
/// whose bytes there are zero).
fn decode_georef(b: &HeaderBytes) -> std::result::Result<Option<Georef>, String> {
    let flags = b.u32(196) >> 16;
    if flags & 1 == 0 {
        return Ok(None);
    }
    let code = (b.u32(188) & 0xffff) as u16;
    let kind = CrsKind::from_code(code).ok_or_else(|| format!("unknown CRS kind {code}"))?;
    let g = Georef {
        kind,
        epsg: b.u32(184),
        unit: (b.u32(188) >> 16) as u16,
        vertical_epsg: b.u32(192),
        vertical_unit: (b.u32(196) & 0xffff) as u16,
        origin: [b.f64(200), b.f64(208)],
        step: [b.f64(216), b.f64(224)],
    };
    if !g.is_valid() {
        return Err(format!("CRS placement origin {:?}, step {:?} is not finite and positive", g.origin, g.step));
    }
    Ok(Some(g))
}

/// Records per pager block: 1,024 records are 12 KiB, three 4 KiB pages, so a block holds whole
/// records and starts on a page.
pub const RECORDS_PER_BLOCK: u64 = 1024;

/// An open, validated terrain file, read through its [`Pager`].
pub struct TerrainFile {
    path: PathBuf,
    header: Header,
    layout: AnyLayout,
    pager: Pager,
    page_map: Option<PageMap>,
}

impl TerrainFile {
    /// Opens and validates a terrain file, memory-mapped (see [`Self::open_with`]).
    pub fn open(path: &Path) -> Result<TerrainFile> {
        TerrainFile::open_with(path, Access::Map)
    }

    /// Opens and validates a terrain file (magic, version, header checksum, field consistency and
    /// the exact file size) to be read with `access`. The pager's blocks are runs of
    /// [`RECORDS_PER_BLOCK`] records. The payload checksum is not checked here (see
    /// [`Self::verify_payload`]).
    ///
    /// A remote location (`http(s)://`, `s3://`) cannot be mapped: map access reads it instead.
    pub fn open_with(path: &Path, access: Access) -> Result<TerrainFile> {
        TerrainFile::open_on(path, access, None)
    }

    /// [`Self::open_with`], the file served through an emulated device when `device` is given
    /// ([`crate::pager::device`]).
    pub fn open_on(
        path: &Path,
        access: Access,
        device: Option<crate::pager::device::DeviceSpec>,
    ) -> Result<TerrainFile> {
        let source = crate::pager::open_on(path, access.source_kind(), device)?;
        TerrainFile::from_source(path, source, access)
    }

    #[cfg(feature = "native")]
    /// A remote terrain file (`http(s)://`, `s3://`) read as `options` say (cache, requests in
    /// flight), with read or pool access.
    pub fn open_remote(
        location: &str,
        options: crate::pager::remote::RemoteOptions,
        access: Access,
    ) -> Result<TerrainFile> {
        let source = Arc::new(crate::pager::remote::RemoteFile::open(location, options)?);
        TerrainFile::from_source(Path::new(location), source, access)
    }

    /// A terrain file over an opened `source` (named `path` in errors), validated as
    /// [`Self::open_with`] validates.
    pub fn from_source(path: &Path, source: Arc<dyn source::Source>, access: Access) -> Result<TerrainFile> {
        let header: Header = read_header(&*source)?;
        let (source, page_map) = if header.stores_pages() {
            let map = read_page_map(path, &*source, &header)?;
            (Arc::new(SparseFile::new(source, map.clone())?) as Arc<dyn source::Source>, Some(map))
        } else {
            (source, None)
        };
        let table = FixedBlocks {
            first: header.payload_offset,
            block_bytes: RECORDS_PER_BLOCK * RECORD_BYTES as u64,
            end: header.payload_offset + header.payload_bytes,
            page_bytes: 4096,
        };
        let pager = Pager::new(source, Arc::new(table), access)?;
        let layout = header.layout();
        Ok(TerrainFile { path: path.to_path_buf(), header, layout, pager, page_map })
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

    /// Bytes the file takes (pages left out do not count; see [`Header::stores_pages`]).
    pub fn stored_bytes(&self) -> u64 {
        match &self.page_map {
            Some(m) => PAYLOAD_OFFSET * (1 + self.header.page_map_pages as u64) + stored_tail(m, &self.header),
            None => self.header.file_len(),
        }
    }

    /// Where payload pages are left out, which are stored where (pages of the file as read).
    /// (The file's own table, as read at open; the pager reads through it in
    /// [`crate::pager::sparse`].)
    pub fn page_map(&self) -> Option<&PageMap> {
        self.page_map.as_ref()
    }

    /// Whether the records come over a network (see [`Pager::network`] for what they cost).
    pub fn is_remote(&self) -> bool {
        self.pager.is_remote()
    }

    /// The pager the records are read through.
    pub fn pager(&self) -> &Pager {
        &self.pager
    }

    /// The payload as raw bytes, where the file is mapped.
    pub fn mapped_payload(&self) -> Option<&[u8]> {
        let start = self.header.payload_offset as usize;
        self.pager.mapped().map(|m| &m[start..start + self.header.payload_bytes as usize])
    }

    /// All record slots in layout order (unused slots are zero), where the file is mapped.
    pub fn mapped_records(&self) -> Option<&[Record]> {
        // Page-aligned start and a size that is a multiple of the record size (validated).
        self.mapped_payload().map(bytemuck::cast_slice)
    }

    /// Every record slot in layout order: the map itself when the file is mapped, else read
    /// whole into memory through the pager (for whole-file passes such as `verify`).
    pub fn records(&self) -> Result<std::borrow::Cow<'_, [Record]>> {
        if let Some(r) = self.mapped_records() {
            return Ok(std::borrow::Cow::Borrowed(r));
        }
        let mut all = Vec::with_capacity(self.header.records as usize);
        self.for_each_chunk(|_, chunk| {
            all.extend_from_slice(chunk);
            Ok(())
        })?;
        Ok(std::borrow::Cow::Owned(all))
    }

    /// Record slot `index` (layout order), through the pager.
    pub fn record(&self, index: u64) -> Result<Record> {
        if index >= self.header.records {
            return Err(Error::InvalidArgument(format!(
                "{}: record {index} of {}",
                self.path.display(),
                self.header.records
            )));
        }
        if let Some(r) = self.mapped_records() {
            return Ok(r[index as usize]);
        }
        let block = self.pager.block((index / RECORDS_PER_BLOCK) as u32)?;
        let at = (index % RECORDS_PER_BLOCK) as usize * RECORD_BYTES as usize;
        Ok(bytemuck::pod_read_unaligned(&block[at..at + RECORD_BYTES as usize]))
    }

    /// The record of grid position `(x, y)` (all zero for a null vertex, see [`Stored`]).
    pub fn record_at(&self, x: u32, y: u32) -> Result<Record> {
        self.record(self.layout.index(x, y))
    }

    /// The height of grid post `(x, y)`, padding included ([`Header::data_post`]).
    pub fn height_at(&self, x: u32, y: u32) -> Result<f32> {
        let (x, y) = self.header.data_post(x, y);
        Ok(self.record_at(x, y)?.z)
    }

    /// Calls `f` with every record slot in layout order, in chunks: `(index of the chunk's first
    /// record, records)`. A mapped file hands out the map; otherwise the pager's blocks.
    pub fn for_each_chunk(&self, mut f: impl FnMut(u64, &[Record]) -> Result<()>) -> Result<()> {
        if let Some(r) = self.mapped_records() {
            for (k, chunk) in r.chunks(CHECKSUM_BLOCK_BYTES / RECORD_BYTES as usize).enumerate() {
                f((k * CHECKSUM_BLOCK_BYTES / RECORD_BYTES as usize) as u64, chunk)?;
            }
            return Ok(());
        }
        let mut records = Vec::new();
        for id in 0..self.pager.table().blocks() {
            let block = self.pager.block(id)?;
            records.clear();
            records.extend(block.chunks_exact(RECORD_BYTES as usize).map(bytemuck::pod_read_unaligned::<Record>));
            f(id as u64 * RECORDS_PER_BLOCK, &records)?;
        }
        Ok(())
    }

    /// Asks the kernel not to read ahead around faults or reads (`MADV_RANDOM`,
    /// `POSIX_FADV_RANDOM`), so fault counts reflect the pages actually touched.
    pub fn advise_random(&self) -> Result<()> {
        self.pager.advise_random()
    }

    /// Readahead off and the file out of the OS page cache, after the open (see
    /// [`Pager::start_cold`]): the next reads come from storage, each page once.
    pub fn start_cold(&self) -> Result<()> {
        self.pager.start_cold()
    }

    /// Which posts of the DEM were nodata (read from the file each call; `None` when none were).
    pub fn void_mask(&self) -> Result<Option<VoidMask>> {
        let h = &self.header;
        if h.void_mask_offset == 0 {
            return Ok(None);
        }
        let mut bytes = vec![0u8; 8 + h.void_mask_bits_bytes() as usize];
        self.pager.read_range(h.void_mask_offset, &mut bytes)?;
        let stored = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes"));
        bytes.drain(..8);
        Ok(Some(VoidMask { window: h.valid_window, bits: bytes, stored_checksum: stored }))
    }

    /// Recomputes the payload checksum (and the void mask's) and compares with the stored ones.
    pub fn verify_payload(&self) -> Result<()> {
        if let Some(mask) = self.void_mask()? {
            let computed = mask.checksum();
            if computed != mask.stored_checksum {
                return Err(super::file_error(
                    &self.path,
                    FileKind::Terrain,
                    Problem::Checksum { which: "void mask", stored: mask.stored_checksum, computed },
                ));
            }
        }
        let computed = match self.mapped_payload() {
            Some(p) => payload_checksum(p),
            None => {
                let mut hashes = Vec::new();
                let mut buf = vec![0u8; CHECKSUM_BLOCK_BYTES];
                let (start, len) = (self.header.payload_offset, self.header.payload_bytes);
                let mut at = 0u64;
                while at < len {
                    let n = (len - at).min(CHECKSUM_BLOCK_BYTES as u64) as usize;
                    self.pager.read_range(start + at, &mut buf[..n])?;
                    hashes.push(block_hash(&buf[..n]));
                    at += n as u64;
                }
                combine_block_hashes(&hashes)
            }
        };
        if computed != self.header.payload_checksum {
            return Err(super::file_error(
                &self.path,
                FileKind::Terrain,
                Problem::Checksum { which: "payload", stored: self.header.payload_checksum, computed },
            ));
        }
        Ok(())
    }
}

/// The physical bytes after the page map: the stored pages and the void mask.
fn stored_tail(map: &PageMap, h: &Header) -> u64 {
    // Every run but the header page's is stored whole, except that the void mask ends the file.
    let mask = if h.void_mask_offset == 0 { 0 } else { 8 + h.void_mask_bits_bytes() };
    let mask_pages = mask.div_ceil(PAGE_BYTES);
    (map.stored_pages() - 1 - mask_pages) * PAGE_BYTES + mask
}

/// Reads and checks the page map of a file with stored pages, and returns the map of the whole
/// file as read: its header page, the stored payload runs and the void mask.
fn read_page_map(path: &Path, source: &dyn source::Source, h: &Header) -> Result<PageMap> {
    let corrupt =
        |what: String| super::file_error(path, FileKind::Terrain, Problem::Corrupt(format!("page map: {what}")));
    let map_pages = h.page_map_pages as u64;
    let mut bytes = vec![0u8; (map_pages * PAGE_BYTES) as usize];
    source.read_at(PAGE_BYTES, &mut bytes)?;
    let word = |k: usize| u64::from_le_bytes(bytes[8 * k..8 * k + 8].try_into().expect("8 bytes"));
    let count = word(1);
    let max_runs = (bytes.len() as u64 - 16) / 16;
    if count > max_runs {
        return Err(corrupt(format!("{count} runs do not fit its {map_pages} pages")));
    }
    let end = 16 + 16 * count as usize;
    let computed = xxhash_rust::xxh3::xxh3_64(&bytes[8..end]);
    if computed != word(0) {
        return Err(super::file_error(
            path,
            FileKind::Terrain,
            Problem::Checksum { which: "page map", stored: word(0), computed },
        ));
    }
    let payload_pages = h.payload_bytes.div_ceil(PAGE_BYTES);
    let mut runs = vec![(0, 0, 1)];
    let mut physical = 1 + map_pages;
    let mut next = 0u64;
    for k in 0..count as usize {
        let (first, pages) = (word(2 + 2 * k), word(3 + 2 * k));
        if pages == 0 || first < next || first.checked_add(pages).is_none_or(|e| e > payload_pages) {
            return Err(corrupt(format!(
                "run {k} (pages {first} + {pages}) is empty, out of order or past the payload's {payload_pages} pages"
            )));
        }
        runs.push((1 + first, physical, pages));
        physical += pages;
        next = first + pages;
    }
    if h.void_mask_offset != 0 {
        let pages = (8 + h.void_mask_bits_bytes()).div_ceil(PAGE_BYTES);
        runs.push((h.void_mask_offset / PAGE_BYTES, physical, pages));
    }
    let map = PageMap::new(runs, h.file_len()).ok_or_else(|| corrupt("runs overlap or pass the end".into()))?;
    let expected = PAGE_BYTES * (1 + map_pages) + stored_tail(&map, h);
    if source.len() != expected {
        return Err(super::file_error(path, FileKind::Terrain, Problem::Truncated { expected, found: source.len() }));
    }
    Ok(map)
}

/// The page map's bytes for payload runs `(first page, pages)`: checksum, count, runs, padded to
/// whole pages.
pub fn encode_page_map(runs: &[(u64, u64)]) -> Vec<u8> {
    let mut bytes = vec![0u8; 16];
    bytes[8..16].copy_from_slice(&(runs.len() as u64).to_le_bytes());
    for &(first, pages) in runs {
        bytes.extend_from_slice(&first.to_le_bytes());
        bytes.extend_from_slice(&pages.to_le_bytes());
    }
    let checksum = xxhash_rust::xxh3::xxh3_64(&bytes[8..]);
    bytes[..8].copy_from_slice(&checksum.to_le_bytes());
    bytes.resize(bytes.len().next_multiple_of(PAGE_BYTES as usize), 0);
    bytes
}

/// Which posts of a terrain's valid window were nodata in the DEM (their heights in the records
/// are filled in, for the hierarchy): one bit per post, row by row from the south (grid row
/// `y0`), least significant bit first.
#[derive(Clone, Debug, PartialEq)]
pub struct VoidMask {
    /// The valid window `[x0, y0, x1, y1)` the bits cover, grid posts.
    pub window: [u32; 4],
    /// `ceil(w·h / 8)` bytes; bits past `w·h` are zero.
    pub bits: Vec<u8>,
    stored_checksum: u64,
}

impl VoidMask {
    /// An all-data mask over `window`.
    pub fn new(window: [u32; 4]) -> VoidMask {
        let [x0, y0, x1, y1] = window;
        let bytes = ((x1 - x0) as u64 * (y1 - y0) as u64).div_ceil(8) as usize;
        VoidMask { window, bits: vec![0; bytes], stored_checksum: 0 }
    }

    fn bit(&self, x: u32, y: u32) -> Option<usize> {
        let [x0, y0, x1, y1] = self.window;
        if x < x0 || y < y0 || x >= x1 || y >= y1 {
            return None;
        }
        Some((y - y0) as usize * (x1 - x0) as usize + (x - x0) as usize)
    }

    /// Marks grid post `(x, y)` void (outside the window: ignored).
    pub fn set(&mut self, x: u32, y: u32) {
        if let Some(i) = self.bit(x, y) {
            self.bits[i / 8] |= 1 << (i % 8);
        }
    }

    /// Whether grid post `(x, y)` was nodata (padding outside the window is not).
    pub fn is_void(&self, x: u32, y: u32) -> bool {
        self.bit(x, y).is_some_and(|i| self.bits[i / 8] >> (i % 8) & 1 == 1)
    }

    /// Void posts.
    pub fn count(&self) -> u64 {
        self.bits.iter().map(|b| b.count_ones() as u64).sum()
    }

    /// XXH3-64 of the bits, as stored before them.
    pub fn checksum(&self) -> u64 {
        xxhash_rust::xxh3::xxh3_64(&self.bits)
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
            georef: None,
            void_mask_offset: 0,
            page_map_pages: 0,
            payload_checksum: 0x0123_4567_89ab_cdef,
        }
    }

    fn file_len(h: &Header) -> u64 {
        h.payload_offset + h.payload_bytes
    }

    fn decode(b: &[u8], len: u64) -> Result<Header> {
        super::super::decode_header(Path::new("t.relief"), b, len)
    }

    #[test]
    fn header_round_trips() {
        let h = sample_header();
        let b = h.encode().0;
        let d = decode(&b, file_len(&h)).unwrap();
        assert_eq!(d.encode().0, b);
        assert_eq!(d.records, 81);
        assert_eq!(d.extent_m(), [200.0, 200.0]);
    }

    #[test]
    fn header_rejects_damage() {
        let h = sample_header();
        let b = h.encode().0;
        let problem = |r: Result<Header>| match r {
            Err(Error::File { kind: FileKind::Terrain, problem, .. }) => problem,
            other => panic!("{other:?}"),
        };
        let mut m = b;
        m[0] = b'X';
        assert_eq!(problem(decode(&m, 0)), Problem::BadMagic);
        let mut m = b;
        m[8] = 9;
        assert_eq!(problem(decode(&m, 0)), Problem::Version { found: 9, oldest: OLDEST_VERSION, supported: VERSION });
        let mut m = b;
        m[100] ^= 1;
        assert!(matches!(problem(decode(&m, file_len(&h))), Problem::Checksum { which: "header", .. }));
        assert!(matches!(problem(decode(&b, file_len(&h) - 1)), Problem::Truncated { .. }));
        assert!(matches!(problem(decode(&b[..100], 100)), Problem::Truncated { .. }));
        // A consistent checksum over inconsistent fields is still rejected.
        let mut bad = h.clone();
        bad.records += 1;
        let e = decode(&bad.encode().0, file_len(&h)).unwrap_err();
        assert!(e.to_string().contains("records"), "{e}");
        let mut bad = h.clone();
        bad.valid_window = [0, 0, 10, 9];
        assert!(decode(&bad.encode().0, file_len(&h)).is_err());
        let mut bad = h.clone();
        bad.spacing_m = [0.0, 1.0];
        assert!(decode(&bad.encode().0, file_len(&bad)).is_err());
        // A void mask must start on the page after the payload, and the file must hold it.
        let mut masked = h.clone();
        masked.void_mask_offset = masked.void_mask_start();
        assert_eq!(masked.file_len(), 8192 + 8 + 8, "7 x 9 posts are 63 bits");
        assert!(decode(&masked.encode().0, masked.file_len()).is_ok());
        assert!(matches!(problem(decode(&masked.encode().0, file_len(&h))), Problem::Truncated { .. }));
        masked.void_mask_offset += 4096;
        let e = decode(&masked.encode().0, masked.file_len()).unwrap_err();
        assert!(e.to_string().contains("void mask offset"), "{e}");
    }

    #[test]
    fn void_mask_bits_are_posts_of_the_window() {
        let mut m = VoidMask::new([2, 3, 7, 6]);
        assert_eq!(m.bits.len(), 2, "5 x 3 posts");
        m.set(2, 3);
        m.set(6, 5);
        m.set(7, 5); // outside: ignored
        m.set(1, 4);
        assert_eq!(m.count(), 2);
        assert!(m.is_void(2, 3) && m.is_void(6, 5));
        assert!(!m.is_void(3, 3) && !m.is_void(7, 5) && !m.is_void(0, 0));
        assert_eq!(m.bits, [0b0000_0001, 0b0100_0000]);
    }
}
