//! The meta-node file (El-Sana & Chiang 2000, §3.2): meta-node trees blocked into disk pages,
//! written by [`crate::metanode::blocking`] and read at run time through a [`Pager`] whose blocks
//! are the meta-nodes (any access: the map, reads, or the buffer pool).
//!
//! # Meta-node file (little-endian)
//! ```text
//! offset size  field
//!      0    8  magic "\x89RLFMNT\n"
//!      8    4  version (1)
//!     12    4  metric (0 length, 1 quadric)
//!     16    4  page bytes (a power of two; every block starts on a page)
//!     20    4  levels per meta-node (L)
//!     24    8  leaves, 32: nodes, 40: triangles, 48: base triangles
//!     56    8  meta-nodes, 64: root meta-nodes (ids 0..roots)
//!     72    8  holder bytes (the largest block)
//!     80    8  MNT offset (meta-node table: `meta-nodes` × 24-byte [`MntEntry`])
//!     88    8  base offset (base triangles: 12-byte leaf-DFS corner triples)
//!     96    8  DATA offset (page-aligned), 104: DATA bytes (to the end of the file)
//!    112   48  bounding box min x, y, z, max x, y, z (f64)
//!    160   88  reserved (0)
//!    248    8  header checksum: XXH3-64 of bytes 0..248
//! ```
//! A block: `node_count, coord_count, tri_count, 0` (u32 each), then `node_count` × 56-byte
//! [`MnNode`], `coord_count` × 12-byte positions (f32), `tri_count` × 12-byte triangles whose
//! corners are leaf DFS numbers (the leaves numbered in depth-first order, first child first, so a

use std::path::{Path, PathBuf};
use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use serde::Serialize;

use super::vdt::NONE;
use super::{corrupt, corrupt_at, read_header, section_end, Bounds, FileKind, Format, HeaderBytes, Problem};
use crate::error::Result;
use crate::pager::{Access, Block, Extent, ExtentTable, Pager};

pub const VERSION: u32 = 1;
/// The header region: the container's 256-byte block, then zeros up to the meta-node table.
pub const HEADER_BYTES: u64 = 4096;
pub const BLOCK_HEADER_BYTES: usize = 16;
/// Page sizes a meta-node file may have (powers of two).
pub const MIN_PAGE_BYTES: u32 = 512;
pub const MAX_PAGE_BYTES: u32 = 1 << 20;

/// One node in a block (56 bytes). References to other nodes are (meta-node, local index) pairs;
/// the ids are the VDT ids, kept for the implicit-dependency tests.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct MnNode {
    pub id: u32,
    /// The parent's id ([`NONE`] for roots): the collapse test compares neighbours' parent ids.
    pub parent_id: u32,
    pub parent_meta: u32,
    /// [`NONE`] for leaves.
    pub child_meta: [u32; 2],
    pub parent_local: u16,
    pub child_local: [u16; 2],
    /// Index into the block's coordinates.
    pub coord: u16,
    pub switch: f32,
    pub radius: f32,
    /// The parent's switch value and radius, so whether to collapse into the parent can be
    /// decided without its (possibly absent) meta-node. 0 for roots.
    pub parent_switch: f32,
    pub parent_radius: f32,
    pub dfs_lo: u32,
    pub leaves: u32,
    /// This node's triangles in the block's triangle list (those its split creates).
    pub tri_start: u16,
    pub tri_count: u16,
}

impl MnNode {
    pub fn is_leaf(&self) -> bool {
        self.child_meta[0] == NONE
    }

    pub fn is_root(&self) -> bool {
        self.parent_id == NONE
    }

    /// Whether leaf DFS number `d` lies under this node.
    #[inline]
    pub fn covers(&self, d: u32) -> bool {
        d.wrapping_sub(self.dfs_lo) < self.leaves
    }
}

/// One entry of the meta-node table (MNT): where a block is and how the meta-node tree links.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct MntEntry {
    /// From the start of the file; a multiple of the page size.
    pub offset: u64,
    pub bytes: u32,
    /// [`NONE`] for root meta-nodes.
    pub parent: u32,
    pub first_child: u32,
    pub child_count: u32,
}

pub const NODE_BYTES: usize = std::mem::size_of::<MnNode>();
pub const COORD_BYTES: usize = 12;
pub const TRI_BYTES: usize = 12;
/// A validated, zero-copy view of one block.
#[derive(Clone, Copy, Debug)]
pub struct BlockView<'a> {
    pub nodes: &'a [MnNode],
    pub coords: &'a [[f32; 3]],
    pub tris: &'a [[u32; 3]],
}

impl<'a> BlockView<'a> {
    /// Checks the counts against the length and every local reference against the counts.
    /// `bytes` must be 4-byte aligned (mapped pages and `u32` buffers are).
    pub fn parse(bytes: &'a [u8], metanodes: u32) -> std::result::Result<BlockView<'a>, String> {
        if bytes.len() < BLOCK_HEADER_BYTES {
            return Err(format!("block of {} bytes is shorter than its header", bytes.len()));
        }
        let count = |k: usize| {
            u32::from_le_bytes([bytes[4 * k], bytes[4 * k + 1], bytes[4 * k + 2], bytes[4 * k + 3]]) as usize
        };
        let (n, c, t) = (count(0), count(1), count(2));
        let need = BLOCK_HEADER_BYTES + n * NODE_BYTES + c * COORD_BYTES + t * TRI_BYTES;
        if need > bytes.len() || n == 0 {
            return Err(format!(
                "block counts ({n} nodes, {c} coordinates, {t} triangles) do not fit its {} bytes",
                bytes.len()
            ));
        }
        let body = &bytes[BLOCK_HEADER_BYTES..need];
        let (nb, rest) = body.split_at(n * NODE_BYTES);
        let (cb, tb) = rest.split_at(c * COORD_BYTES);
        let cast = |what: &str, e: bytemuck::PodCastError| format!("block {what}: {e:?}");
        let nodes: &[MnNode] = bytemuck::try_cast_slice(nb).map_err(|e| cast("nodes", e))?;
        let coords: &[[f32; 3]] = bytemuck::try_cast_slice(cb).map_err(|e| cast("coordinates", e))?;
        let tris: &[[u32; 3]] = bytemuck::try_cast_slice(tb).map_err(|e| cast("triangles", e))?;
        for (k, v) in nodes.iter().enumerate() {
            let tri_end = v.tri_start as usize + v.tri_count as usize;
            let refs_ok = (v.parent_id == NONE || v.parent_meta < metanodes)
                && (v.child_meta[0] == NONE) == (v.child_meta[1] == NONE)
                && (v.child_meta[0] == NONE || (v.child_meta[0] < metanodes && v.child_meta[1] < metanodes));
            if (v.coord as usize) >= c || tri_end > t || !refs_ok || v.leaves == 0 {
                return Err(format!("block node {k} (id {}) has references out of range", v.id));
            }
        }
        Ok(BlockView { nodes, coords, tris })
    }

    pub fn position(&self, node: &MnNode) -> [f32; 3] {
        self.coords[node.coord as usize]
    }

    pub fn triangles_of(&self, node: &MnNode) -> &'a [[u32; 3]] {
        // In usize: the two u16 fields of a node from another view could sum past u16::MAX.
        &self.tris[node.tri_start as usize..node.tri_start as usize + node.tri_count as usize]
    }
}

/// The decoded header.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MetaHeader {
    pub metric: u32,
    pub page_bytes: u32,
    pub levels_per_node: u32,
    pub leaves: u64,
    pub nodes: u64,
    pub triangles: u64,
    pub base_triangles: u64,
    pub metanodes: u64,
    pub root_metanodes: u64,
    pub holder_bytes: u64,
    pub mnt_offset: u64,
    pub base_offset: u64,
    pub data_offset: u64,
    pub data_bytes: u64,
    pub bounds: Bounds,
}

impl Format for MetaHeader {
    const KIND: FileKind = FileKind::MetaNode;

    fn encode_fields(&self, h: &mut HeaderBytes) {
        h.put_u32(12, self.metric);
        h.put_u32(16, self.page_bytes);
        h.put_u32(20, self.levels_per_node);
        h.put_u64(24, self.leaves);
        h.put_u64(32, self.nodes);
        h.put_u64(40, self.triangles);
        h.put_u64(48, self.base_triangles);
        h.put_u64(56, self.metanodes);
        h.put_u64(64, self.root_metanodes);
        h.put_u64(72, self.holder_bytes);
        h.put_u64(80, self.mnt_offset);
        h.put_u64(88, self.base_offset);
        h.put_u64(96, self.data_offset);
        h.put_u64(104, self.data_bytes);
        h.put_f64x3(112, self.bounds.min);
        h.put_f64x3(136, self.bounds.max);
    }

    fn decode(b: &HeaderBytes, len: u64) -> std::result::Result<MetaHeader, Problem> {
        let bad = |what: String| Problem::Corrupt(format!("header: {what}"));
        let h = MetaHeader {
            metric: b.u32(12),
            page_bytes: b.u32(16),
            levels_per_node: b.u32(20),
            leaves: b.u64(24),
            nodes: b.u64(32),
            triangles: b.u64(40),
            base_triangles: b.u64(48),
            metanodes: b.u64(56),
            root_metanodes: b.u64(64),
            holder_bytes: b.u64(72),
            mnt_offset: b.u64(80),
            base_offset: b.u64(88),
            data_offset: b.u64(96),
            data_bytes: b.u64(104),
            bounds: Bounds { min: b.f64x3(112), max: b.f64x3(136) },
        };
        if !h.page_bytes.is_power_of_two() || !(MIN_PAGE_BYTES..=MAX_PAGE_BYTES).contains(&h.page_bytes) {
            return Err(bad(format!("page size {} is not a power of two from 512 bytes to 1 MiB", h.page_bytes)));
        }
        if h.metanodes == 0
            || h.root_metanodes == 0
            || h.root_metanodes > h.metanodes
            || h.metanodes > u32::MAX as u64 / 2
        {
            return Err(bad(format!("{} meta-nodes with {} roots", h.metanodes, h.root_metanodes)));
        }
        if h.leaves == 0 || h.leaves > h.nodes || h.nodes >= NONE as u64 || h.base_triangles > h.triangles {
            return Err(bad(format!(
                "{} leaves, {} nodes, {} triangles ({} base)",
                h.leaves, h.nodes, h.triangles, h.base_triangles
            )));
        }
        let mnt_end = section_end(h.mnt_offset, h.metanodes, MNT_ENTRY_BYTES, "the meta-node table")?;
        let base_end = section_end(h.base_offset, h.base_triangles, TRI_BYTES as u64, "the base triangles")?;
        let data_end = section_end(h.data_offset, 1, h.data_bytes, "DATA")?;
        let ordered = h.mnt_offset == HEADER_BYTES
            && mnt_end == h.base_offset
            && base_end <= h.data_offset
            && h.data_offset.is_multiple_of(h.page_bytes as u64);
        if !ordered || h.holder_bytes > u32::MAX as u64 {
            return Err(bad("section offsets are inconsistent".into()));
        }
        if data_end != len {
            return Err(Problem::Truncated { expected: data_end, found: len });
        }
        Ok(h)
    }
}

/// Bytes of a meta-node table entry.
pub const MNT_ENTRY_BYTES: u64 = std::mem::size_of::<MntEntry>() as u64;

/// An open meta-node file: the header, the meta-node table and the base triangles in memory, the
/// blocks read through the file's [`Pager`] (whose block `m` is meta-node `m`).
pub struct MetaNodeFile {
    path: PathBuf,
    header: MetaHeader,
    mnt: Vec<MntEntry>,
    base: Vec<[u32; 3]>,
    pager: Pager,
}

impl MetaNodeFile {
    /// Opens a meta-node file, memory-mapped (see [`Self::open_with`]).
    pub fn open(path: &Path) -> Result<MetaNodeFile> {
        MetaNodeFile::open_with(path, Access::Map)
    }

    /// Opens and validates a meta-node file to be read with `access`: magic, version, header
    /// checksum, section sizes against the file length, and every table entry (offsets inside
    /// DATA, sizes within the holder size, tree links in range). Blocks are validated when read
    /// ([`BlockView::parse`]).
    pub fn open_with(path: &Path, access: Access) -> Result<MetaNodeFile> {
        MetaNodeFile::open_on(path, access, None)
    }

    /// [`Self::open_with`], the file served through an emulated device when `device` is given
    /// ([`crate::pager::device`]).
    pub fn open_on(
        path: &Path,
        access: Access,
        device: Option<crate::pager::device::DeviceSpec>,
    ) -> Result<MetaNodeFile> {
        MetaNodeFile::open_io(path, access, device, crate::pager::PoolIo::default())
    }

    /// [`Self::open_on`], a pool's I/O issued as `io` says (threads, coalesced requests).
    pub fn open_io(
        path: &Path,
        access: Access,
        device: Option<crate::pager::device::DeviceSpec>,
        io: crate::pager::PoolIo,
    ) -> Result<MetaNodeFile> {
        let source = crate::pager::open_on(path, access.source_kind(), device)?;
        let header: MetaHeader = read_header(&*source)?;
        let bad = |what: String| corrupt(path, FileKind::MetaNode, what);
        let mut table = vec![0u8; (header.metanodes * MNT_ENTRY_BYTES) as usize];
        source.read_at(header.mnt_offset, &mut table)?;
        let mnt: Vec<MntEntry> =
            table.chunks_exact(MNT_ENTRY_BYTES as usize).map(bytemuck::pod_read_unaligned).collect();
        let page = header.page_bytes as u64;
        let metas = header.metanodes as u32;
        for (m, e) in mnt.iter().enumerate() {
            let in_data = e.offset >= header.data_offset
                && e.offset % page == 0
                && e.offset
                    .checked_add(e.bytes as u64)
                    .is_some_and(|end| end <= header.data_offset + header.data_bytes);
            let root = (m as u64) < header.root_metanodes;
            let links = (root == (e.parent == NONE))
                && (root || e.parent < m as u32)
                && e.first_child as u64 + e.child_count as u64 <= metas as u64
                && (e.child_count == 0 || e.first_child > m as u32);
            if !in_data || e.bytes as u64 > header.holder_bytes || e.bytes < BLOCK_HEADER_BYTES as u32 || !links {
                return Err(bad(format!("meta-node table entry {m} is inconsistent")));
            }
        }
        let mut base_bytes = vec![0u8; header.base_triangles as usize * TRI_BYTES];
        source.read_at(header.base_offset, &mut base_bytes)?;
        let base = base_bytes.chunks_exact(TRI_BYTES).map(bytemuck::pod_read_unaligned).collect();
        let extents = ExtentTable {
            extents: mnt.iter().map(|e| Extent { offset: e.offset, bytes: e.bytes as u64 }).collect(),
            page_bytes: header.page_bytes as u64,
        };
        let pager = Pager::with_io(source, Arc::new(extents), access, io)?;
        Ok(MetaNodeFile { path: path.to_path_buf(), header, mnt, base, pager })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The pager the blocks are read through (block `m` is meta-node `m`).
    pub fn pager(&self) -> &Pager {
        &self.pager
    }

    /// No readahead, for the map and for `pread`: a cold flight then reads exactly the pages it
    /// touches, so the accesses are compared on the same I/O.
    pub fn advise_random(&self) -> Result<()> {
        self.pager.advise_random()
    }

    /// Readahead off and the file out of the OS page cache, after the open (see
    /// [`Pager::start_cold`]): the next reads come from storage, each page once.
    pub fn start_cold(&self) -> Result<()> {
        self.pager.start_cold()
    }

    pub fn header(&self) -> &MetaHeader {
        &self.header
    }

    pub fn mnt(&self) -> &[MntEntry] {
        &self.mnt
    }

    /// The base triangles (m(t) = none), corners as leaf DFS numbers.
    pub fn base_triangles(&self) -> &[[u32; 3]] {
        &self.base
    }

    /// Block `m`'s bytes, now (see [`Pager::block`]).
    pub fn block(&self, m: u32) -> Result<Block<'_>> {
        self.pager.block(m)
    }

    /// Pages of block `m` (what reading it costs).
    pub fn block_pages(&self, m: u32) -> u64 {
        (self.mnt[m as usize].bytes as u64).div_ceil(self.header.page_bytes as u64)
    }

    /// The bytes of the whole tree on disk (DATA + MNT).
    pub fn tree_bytes(&self) -> u64 {
        self.header.data_bytes + self.mnt.len() as u64 * MNT_ENTRY_BYTES
    }
}

/// Parses block `m`'s bytes, turning a malformed block into an error naming the file.
pub fn parse_block<'b>(file: &MetaNodeFile, m: u32, bytes: &'b [u8]) -> Result<BlockView<'b>> {
    let offset = file.pager().extent(m).map_or(0, |e| e.offset);
    BlockView::parse(bytes, file.header().metanodes as u32)
        .map_err(|problem| corrupt_at(file.path(), FileKind::MetaNode, offset, format!("meta-node {m}: {problem}")))
}
