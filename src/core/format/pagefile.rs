//! The page file (Sajadi et al. 2009, §3, Figure 2), written by [`crate::diskpages::build`]: a triangle soup as a sequence of
//! self-contained fixed-size pages, each holding whole triangles and copies of the vertices they
//! use, with a directory (bounding box and normal cone per page) and the disk-page k-d tree
//! ([`crate::diskpages::kdtree`]) stored before the pages.
//!
//! # Page file (little-endian)
//! ```text
//! offset size  field
//!      0    8  magic "\x89RLFPGS\n"
//!      8    4  version (1)
//!     12    4  header bytes (256)
//!     16    4  page bytes (a power of two, 1 KiB to 1 MiB)
//!     20    4  layout (0 raster, 1 2-factor, 2 Hilbert)
//!     24    8  pages, 32: triangles, 40: vertex copies (Σ over pages), 48: source vertices
//!     56    8  directory offset (256): `pages` × 48-byte entries
//!     64    8  k-d nodes, 72: their offset (40 bytes each)
//!     80    8  k-d page references, 88: their offset (u32 page numbers)
//!     96    8  data offset (a multiple of the page size); the pages run to the end of the file
//!    104   48  bounding box min x, y, z, max x, y, z (f64, of the f32 positions)
//!    152    8  tables checksum: XXH3-64 of the directory, k-d nodes and references
//!    160   88  reserved (0)
//!    248    8  header checksum: XXH3-64 of bytes 0..248
//! ```
//! Directory entry (48 bytes): box min, max (f32 × 3 each), normal-cone axis (f32 × 3),
//! half-angle (f32 radians), triangles, vertices (u32 each).
//!
//! Page (`page bytes`, zero-padded): vertices (u16), triangles (u16), index bytes (u8: 1 when at
//! most 256 vertices, else 2), 3 reserved bytes; then per vertex 22 bytes: position (f32 × 3),
//! normal (i16 × 3, unit × 32767), colour (RGBA8); then per triangle three local indices
//! (u8, or u16 little-endian), counter-clockwise as in the input.
//!
//! Pages are filled greedily in layout order: a triangle goes into the current page when the page
//! still fits it with its new vertices, else the page is closed and a new one begun. Every
//! triangle is thus in exactly one page.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use serde::Serialize;

use super::{corrupt, corrupt_at, read_header, section_end, Bounds, FileKind, Format, HeaderBytes, Problem};
use crate::error::Result;
use crate::pager::{Access, Block, BlockBuf, FixedBlocks, Pager};

pub const VERSION: u32 = 1;
pub const HEADER_BYTES: usize = 256;
pub const MIN_PAGE_BYTES: u32 = 1024;
pub const MAX_PAGE_BYTES: u32 = 1 << 20;
pub const PAGE_HEADER_BYTES: usize = 8;
pub const VERTEX_BYTES: usize = 22;
pub const ENTRY_BYTES: usize = 48;
pub const KD_NODE_BYTES: usize = 40;
/// Colour of every vertex: the inputs (OFF, PLY, OBJ, terrains) carry none that we read.
pub const DEFAULT_COLOUR: [u8; 4] = [200, 200, 200, 255];

/// The order triangles are written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PageLayout {
    /// Input order.
    Raster,
    /// Hierarchical 2-factor order ([`crate::diskpages::two_factor`]).
    #[serde(rename = "2factor")]
    TwoFactor,
    /// 3D Hilbert order of centroids ([`crate::diskpages::hilbert`]).
    Hilbert,
}

impl PageLayout {
    pub const ALL: [PageLayout; 3] = [PageLayout::Raster, PageLayout::TwoFactor, PageLayout::Hilbert];

    pub fn name(self) -> &'static str {
        match self {
            PageLayout::Raster => "raster",
            PageLayout::TwoFactor => "2factor",
            PageLayout::Hilbert => "hilbert",
        }
    }

    pub fn from_name(name: &str) -> Option<PageLayout> {
        PageLayout::ALL.into_iter().find(|l| l.name() == name)
    }

    fn code(self) -> u32 {
        self as u32
    }

    fn from_code(code: u32) -> Option<PageLayout> {
        PageLayout::ALL.get(code as usize).copied()
    }
}

/// A page's size when it holds `vertices` and `triangles`.
pub fn page_size(vertices: usize, triangles: usize) -> usize {
    let index = if vertices <= 256 { 1 } else { 2 };
    PAGE_HEADER_BYTES + vertices * VERTEX_BYTES + triangles * 3 * index
}

/// `axis` of a leaf k-d node.
pub const LEAF: u32 = 3;

/// One node of the disk-page k-d tree ([`crate::diskpages::kdtree`]; 40 bytes on disk, little-endian).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct KdNode {
    /// Union of the boxes of the pages below.
    pub box_min: [f32; 3],
    pub box_max: [f32; 3],
    /// 0, 1, 2: the split axis of an inner node; [`LEAF`] for a leaf.
    pub axis: u32,
    /// The split plane's coordinate (inner nodes; informative).
    pub split: f32,
    /// Inner: the children's node indices. Leaf: first entry in the page-number list and count.
    pub a: u32,
    pub b: u32,
}

/// A page's bounding box and normal cone (a directory entry), as the fetch culls it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PageBounds {
    pub box_min: [f32; 3],
    pub box_max: [f32; 3],
    /// Unit axis of the normal cone.
    pub cone_axis: [f32; 3],
    /// Half-angle of the cone, radians (π or more: normals point every way, never culled).
    pub cone_half_angle_rad: f32,
}

/// The header of a page file.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PageHeader {
    pub page_bytes: u32,
    pub layout: PageLayout,
    pub pages: u64,
    pub triangles: u64,
    pub vertex_copies: u64,
    pub source_vertices: u64,
    pub kd_nodes: u64,
    pub kd_offset: u64,
    pub kd_refs: u64,
    pub refs_offset: u64,
    pub data_offset: u64,
    pub bounds: Bounds,
    pub tables_checksum: u64,
}

/// One page as stored: its vertex table and triangles, validated ([`PageView::parse`]).
#[derive(Clone, Copy, Debug)]
pub struct PageView<'a> {
    bytes: &'a [u8],
    vertices: usize,
    triangles: usize,
    index_bytes: usize,
}

impl<'a> PageView<'a> {
    /// Checks the counts against the page's size and every index against the vertex count.
    pub fn parse(bytes: &'a [u8]) -> std::result::Result<PageView<'a>, String> {
        if bytes.len() < PAGE_HEADER_BYTES {
            return Err(format!("page of {} bytes is shorter than its header", bytes.len()));
        }
        let vertices = u16::from_le_bytes([bytes[0], bytes[1]]) as usize;
        let triangles = u16::from_le_bytes([bytes[2], bytes[3]]) as usize;
        let index_bytes = bytes[4] as usize;
        let want = if vertices <= 256 { 1 } else { 2 };
        if index_bytes != want {
            return Err(format!("{index_bytes}-byte indices for {vertices} vertices"));
        }
        if triangles == 0 || page_size(vertices, triangles) > bytes.len() {
            return Err(format!("{vertices} vertices and {triangles} triangles do not fit {} bytes", bytes.len()));
        }
        let view = PageView { bytes, vertices, triangles, index_bytes };
        for t in 0..triangles {
            if let Some(&i) = view.triangle(t).iter().find(|&&i| i as usize >= vertices) {
                return Err(format!("triangle {t} uses vertex {i} of {vertices}"));
            }
        }
        Ok(view)
    }

    pub fn vertices(&self) -> usize {
        self.vertices
    }

    pub fn triangles(&self) -> usize {
        self.triangles
    }

    pub fn index_bytes(&self) -> usize {
        self.index_bytes
    }

    fn f32_at(&self, at: usize) -> f32 {
        f32::from_le_bytes(self.bytes[at..at + 4].try_into().expect("4 bytes"))
    }

    /// Position of local vertex `i` (f32, as the input rounded).
    pub fn position(&self, i: usize) -> [f32; 3] {
        let at = PAGE_HEADER_BYTES + i * VERTEX_BYTES;
        [self.f32_at(at), self.f32_at(at + 4), self.f32_at(at + 8)]
    }

    /// Unit normal of local vertex `i` (from its i16 encoding).
    pub fn normal(&self, i: usize) -> [f32; 3] {
        let at = PAGE_HEADER_BYTES + i * VERTEX_BYTES + 12;
        [0, 1, 2].map(|k| i16::from_le_bytes([self.bytes[at + 2 * k], self.bytes[at + 2 * k + 1]]) as f32 / 32767.0)
    }

    /// RGBA colour of local vertex `i`.
    pub fn colour(&self, i: usize) -> [u8; 4] {
        let at = PAGE_HEADER_BYTES + i * VERTEX_BYTES + 18;
        [self.bytes[at], self.bytes[at + 1], self.bytes[at + 2], self.bytes[at + 3]]
    }

    /// Local vertex indices of triangle `t`.
    pub fn triangle(&self, t: usize) -> [u16; 3] {
        let at = PAGE_HEADER_BYTES + self.vertices * VERTEX_BYTES + t * 3 * self.index_bytes;
        if self.index_bytes == 1 {
            [0, 1, 2].map(|k| self.bytes[at + k] as u16)
        } else {
            [0, 1, 2].map(|k| u16::from_le_bytes([self.bytes[at + 2 * k], self.bytes[at + 2 * k + 1]]))
        }
    }

    /// Appends the page's triangles as 3 positions each.
    pub fn append_triangles(&self, out: &mut Vec<[f32; 3]>) {
        out.reserve(3 * self.triangles);
        for t in 0..self.triangles {
            for i in self.triangle(t) {
                out.push(self.position(i as usize));
            }
        }
    }
}

impl Format for PageHeader {
    const KIND: FileKind = FileKind::Pages;

    fn encode_fields(&self, h: &mut HeaderBytes) {
        h.put_u32(12, HEADER_BYTES as u32);
        h.put_u32(16, self.page_bytes);
        h.put_u32(20, self.layout.code());
        h.put_u64(24, self.pages);
        h.put_u64(32, self.triangles);
        h.put_u64(40, self.vertex_copies);
        h.put_u64(48, self.source_vertices);
        h.put_u64(56, HEADER_BYTES as u64);
        h.put_u64(64, self.kd_nodes);
        h.put_u64(72, self.kd_offset);
        h.put_u64(80, self.kd_refs);
        h.put_u64(88, self.refs_offset);
        h.put_u64(96, self.data_offset);
        h.put_f64x3(104, self.bounds.min);
        h.put_f64x3(128, self.bounds.max);
        h.put_u64(152, self.tables_checksum);
    }

    fn decode(b: &HeaderBytes, len: u64) -> std::result::Result<PageHeader, Problem> {
        let bad = |what: String| Problem::Corrupt(format!("header: {what}"));
        let layout = PageLayout::from_code(b.u32(20)).ok_or_else(|| bad(format!("unknown layout {}", b.u32(20))))?;
        let h = PageHeader {
            page_bytes: b.u32(16),
            layout,
            pages: b.u64(24),
            triangles: b.u64(32),
            vertex_copies: b.u64(40),
            source_vertices: b.u64(48),
            kd_nodes: b.u64(64),
            kd_offset: b.u64(72),
            kd_refs: b.u64(80),
            refs_offset: b.u64(88),
            data_offset: b.u64(96),
            bounds: Bounds { min: b.f64x3(104), max: b.f64x3(128) },
            tables_checksum: b.u64(152),
        };
        if b.u32(12) != HEADER_BYTES as u32 || b.u64(56) != HEADER_BYTES as u64 {
            return Err(bad("header size or directory offset is not 256".into()));
        }
        if !h.page_bytes.is_power_of_two() || !(MIN_PAGE_BYTES..=MAX_PAGE_BYTES).contains(&h.page_bytes) {
            return Err(bad(format!("page size {} is not a power of two from 1 KiB to 1 MiB", h.page_bytes)));
        }
        if h.pages == 0 || h.pages >= u32::MAX as u64 || h.triangles < h.pages || h.kd_nodes == 0 || h.kd_refs < h.pages
        {
            return Err(bad(format!(
                "{} pages, {} triangles, {} k-d nodes, {} references",
                h.pages, h.triangles, h.kd_nodes, h.kd_refs
            )));
        }
        let kd_at = section_end(HEADER_BYTES as u64, h.pages, ENTRY_BYTES as u64, "the directory")?;
        let refs_at = section_end(h.kd_offset, h.kd_nodes, KD_NODE_BYTES as u64, "the k-d tree")?;
        let tables_end = section_end(h.refs_offset, h.kd_refs, 4, "the page references")?;
        let data_end = section_end(h.data_offset, h.pages, h.page_bytes as u64, "the pages")?;
        let ordered = kd_at == h.kd_offset
            && refs_at == h.refs_offset
            && tables_end <= h.data_offset
            && h.data_offset.is_multiple_of(h.page_bytes as u64);
        if !ordered {
            return Err(bad("section offsets are inconsistent".into()));
        }
        if data_end != len {
            return Err(Problem::Truncated { expected: data_end, found: len });
        }
        if !(0..3)
            .all(|k| h.bounds.min[k].is_finite() && h.bounds.max[k].is_finite() && h.bounds.min[k] <= h.bounds.max[k])
        {
            return Err(bad("bounding box is not finite and ordered".into()));
        }
        Ok(h)
    }
}

/// An open page file: header, directory and k-d tree in memory (validated), the pages read
/// through the file's [`Pager`] (whose block `p` is page `p`).
pub struct PageFile {
    path: PathBuf,
    header: PageHeader,
    directory: Vec<PageBounds>,
    counts: Vec<(u32, u32)>,
    nodes: Vec<KdNode>,
    refs: Vec<u32>,
    pager: Pager,
}

impl PageFile {
    /// Opens a page file, memory-mapped (see [`Self::open_with`]).
    pub fn open(path: &Path) -> Result<PageFile> {
        PageFile::open_with(path, Access::Map)
    }

    /// Opens and validates a page file to be read with `access`: magic, version, header
    /// checksum, section sizes against the file's length, the tables' checksum, every directory
    /// entry and k-d node. Pages are validated when decoded ([`PageView::parse`]).
    pub fn open_with(path: &Path, access: Access) -> Result<PageFile> {
        PageFile::open_on(path, access, None)
    }

    /// [`Self::open_with`], the file served through an emulated device when `device` is given
    /// ([`crate::pager::device`]).
    pub fn open_on(path: &Path, access: Access, device: Option<crate::pager::device::DeviceSpec>) -> Result<PageFile> {
        let source = crate::pager::open_on(path, access.source_kind(), device)?;
        let header: PageHeader = read_header(&*source)?;
        let bad = |what: String| corrupt(path, FileKind::Pages, what);
        let mut tables = vec![0u8; (header.refs_offset + header.kd_refs * 4) as usize - HEADER_BYTES];
        source.read_at(HEADER_BYTES as u64, &mut tables)?;
        let computed = xxhash_rust::xxh3::xxh3_64(&tables);
        if computed != header.tables_checksum {
            return Err(super::file_error(
                path,
                FileKind::Pages,
                Problem::Checksum { which: "tables", stored: header.tables_checksum, computed },
            ));
        }
        // Offsets below are into `tables`, which starts after the header block.
        let f = |at: usize| f32::from_le_bytes(tables[at..at + 4].try_into().expect("4 bytes"));
        let u = |at: usize| u32::from_le_bytes(tables[at..at + 4].try_into().expect("4 bytes"));
        let mut directory = Vec::with_capacity(header.pages as usize);
        let mut counts = Vec::with_capacity(header.pages as usize);
        let mut triangles = 0u64;
        for p in 0..header.pages as usize {
            let at = p * ENTRY_BYTES;
            let e = PageBounds {
                box_min: [f(at), f(at + 4), f(at + 8)],
                box_max: [f(at + 12), f(at + 16), f(at + 20)],
                cone_axis: [f(at + 24), f(at + 28), f(at + 32)],
                cone_half_angle_rad: f(at + 36),
            };
            let (tris, verts) = (u(at + 40), u(at + 44));
            let ok = (0..3)
                .all(|k| e.box_min[k].is_finite() && e.box_max[k].is_finite() && e.box_min[k] <= e.box_max[k])
                && e.cone_axis.iter().all(|c| c.is_finite())
                && (0.0..=4.0).contains(&e.cone_half_angle_rad)
                && tris > 0
                && page_size(verts as usize, tris as usize) <= header.page_bytes as usize;
            if !ok {
                return Err(bad(format!("directory entry {p} is inconsistent")));
            }
            triangles += tris as u64;
            directory.push(e);
            counts.push((tris, verts));
        }
        if triangles != header.triangles {
            return Err(bad(format!("the directory holds {triangles} triangles, the header {}", header.triangles)));
        }
        let kd_at = header.kd_offset as usize - HEADER_BYTES;
        let nodes: Vec<KdNode> = tables[kd_at..kd_at + header.kd_nodes as usize * KD_NODE_BYTES]
            .chunks_exact(KD_NODE_BYTES)
            .map(bytemuck::pod_read_unaligned)
            .collect();
        let refs_at = header.refs_offset as usize - HEADER_BYTES;
        let refs: Vec<u32> = tables[refs_at..refs_at + header.kd_refs as usize * 4]
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect();
        if let Some(r) = refs.iter().find(|&&r| r as u64 >= header.pages) {
            return Err(bad(format!("the k-d tree names page {r} of {}", header.pages)));
        }
        for (i, n) in nodes.iter().enumerate() {
            let ok = match n.axis {
                LEAF => n.a as u64 + n.b as u64 <= refs.len() as u64,
                0..=2 => {
                    (n.a as usize) > i
                        && (n.b as usize) > i
                        && (n.a as usize) < nodes.len()
                        && (n.b as usize) < nodes.len()
                }
                _ => false,
            };
            if !ok {
                return Err(bad(format!("k-d node {i} is inconsistent")));
            }
        }
        let table = FixedBlocks {
            first: header.data_offset,
            block_bytes: header.page_bytes as u64,
            end: header.data_offset + header.pages * header.page_bytes as u64,
            page_bytes: header.page_bytes as u64,
        };
        let pager = Pager::new(source, Arc::new(table), access)?;
        Ok(PageFile { path: path.to_path_buf(), header, directory, counts, nodes, refs, pager })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn header(&self) -> &PageHeader {
        &self.header
    }

    /// The pager the pages are read through (block `p` is page `p`).
    pub fn pager(&self) -> &Pager {
        &self.pager
    }

    /// Bounding box and normal cone of every page.
    pub fn directory(&self) -> &[PageBounds] {
        &self.directory
    }

    /// (triangles, vertices) of every page.
    pub fn counts(&self) -> &[(u32, u32)] {
        &self.counts
    }

    pub fn kd_nodes(&self) -> &[KdNode] {
        &self.nodes
    }

    pub fn kd_refs(&self) -> &[u32] {
        &self.refs
    }

    pub fn page_bytes(&self) -> usize {
        self.header.page_bytes as usize
    }

    /// Page `p`'s bytes, now (see [`Pager::block`]).
    pub fn page(&self, p: u32) -> Result<Block<'_>> {
        self.pager.block(p)
    }

    /// Calls `f` with pages `first .. first + count` in order (one `pread` for the run with read
    /// access) and returns the time the reads took (see [`Pager::for_run`]).
    pub fn for_run(
        &self,
        first: u32,
        count: u32,
        buf: &mut BlockBuf,
        f: impl FnMut(u32, &[u8]) -> Result<()>,
    ) -> Result<std::time::Duration> {
        self.pager.for_run(first, count, buf, f)
    }

    /// Decodes a page's bytes; a damaged page is an error naming the file and the page.
    pub fn decode<'a>(&self, p: u32, bytes: &'a [u8]) -> Result<PageView<'a>> {
        let offset = self.pager.extent(p).map_or(0, |e| e.offset);
        let bad = |what: String| corrupt_at(&self.path, FileKind::Pages, offset, format!("page {p}: {what}"));
        let view = PageView::parse(bytes).map_err(bad)?;
        let (tris, verts) = self.counts.get(p as usize).copied().unwrap_or_default();
        if (view.triangles() as u32, view.vertices() as u32) != (tris, verts) {
            return Err(bad("counts differ from the directory".into()));
        }
        Ok(view)
    }

    /// Drops the file from the OS page cache (see [`Pager::evict`]).
    pub fn evict_from_page_cache(&self) -> Result<()> {
        self.pager.evict()
    }

    /// No readahead for the map and for `pread` (a cold flight reads exactly its pages).
    pub fn advise_random(&self) -> Result<()> {
        self.pager.advise_random()
    }

    /// Readahead off and the file out of the OS page cache, after the open (see
    /// [`Pager::start_cold`]): the next reads come from storage, each page once.
    pub fn start_cold(&self) -> Result<()> {
        self.pager.start_cold()
    }
}
