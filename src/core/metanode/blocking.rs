//! Meta-node trees (El-Sana & Chiang 2000, §3.2): the view-dependence forest blocked top-down,
//! at most L levels at a time, into meta-nodes that fit a disk page, each holding its nodes, the
//! coordinates they use (only the block's distinct leaf positions: a parent sits at its first
//! child's position) and its local triangle list (the triangles that each node's split creates).
//!
//! Blocking: meta-nodes are formed breadth-first. A meta-node starts from a group of subtree roots
//! (several small sibling subtrees share one meta-node, so forests of tiny trees do not waste a
//! page each), takes their nodes level by level for up to L levels while the block still fits the
//! page, and hands what is left (the frontier) to child meta-nodes, again grouped. Meta-node ids
//! follow the breadth-first order, so the root meta-nodes come first and each meta-node's
//! children are contiguous.
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
//! node's leaves are the interval `dfs_lo .. dfs_lo + leaves`).

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

use bytemuck::{Pod, Zeroable};
use memmap2::Mmap;
use serde::Serialize;

use super::{VdtNode, VdtTriangle, NONE};
use crate::error::{Error, IoContext, Result};
use crate::format::terrain::{get_u32, get_u64, put_f64, put_u32, put_u64};
use crate::mesh::Bounds;

pub const MAGIC: [u8; 8] = *b"\x89RLFMNT\n";
pub const VERSION: u32 = 1;
pub const HEADER_BYTES: u64 = 4096;
pub const BLOCK_HEADER_BYTES: usize = 16;

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

/// How to block the forest.
#[derive(Clone, Copy, Debug)]
pub struct BlockingOptions {
    /// L: at most this many levels of the binary tree per meta-node.
    pub levels_per_node: u32,
    /// Blocks are filled up to this size and start on page boundaries.
    pub page_bytes: u32,
}

impl Default for BlockingOptions {
    fn default() -> Self {
        BlockingOptions { levels_per_node: 6, page_bytes: 4096 }
    }
}

/// Figures of a written meta-node file.
#[derive(Clone, Debug, Default, Serialize)]
pub struct MetaNodeReport {
    pub metanodes: u64,
    pub root_metanodes: u64,
    /// Table 1's MNT: the meta-node table.
    pub mnt_bytes: u64,
    /// Table 1's DATA: the page-aligned blocks (and the base triangles).
    pub data_bytes: u64,
    pub file_bytes: u64,
    pub holder_bytes: u64,
    pub nodes_per_metanode_mean: f64,
    pub fill_mean: f64,
    pub build_ms: f64,
}

/// The forest to block: the VDT file's sections.
pub struct Forest<'a> {
    pub nodes: &'a [VdtNode],
    /// Grouped by m(t) (node ranges), then the base triangles.
    pub triangles: &'a [VdtTriangle],
    pub base_triangles: usize,
    pub leaves: u32,
    pub metric: u32,
    pub bounds: Bounds,
}

const NODE_BYTES: usize = std::mem::size_of::<MnNode>();
const COORD_BYTES: usize = 12;
const TRI_BYTES: usize = 12;

/// Builds and writes the meta-node file at `out` (atomically).
pub fn write_metanode_file(forest: &Forest<'_>, options: BlockingOptions, out: &Path) -> Result<MetaNodeReport> {
    let started = std::time::Instant::now();
    validate_options(options)?;
    let plan = plan(forest, options, out)?;
    let page = options.page_bytes as u64;
    let mnt_offset = HEADER_BYTES;
    let mnt_bytes = plan.metas.len() as u64 * std::mem::size_of::<MntEntry>() as u64;
    let base_offset = mnt_offset + mnt_bytes;
    let base_bytes = forest.base_triangles as u64 * TRI_BYTES as u64;
    let data_offset = (base_offset + base_bytes).div_ceil(page) * page;
    let mut entries = Vec::with_capacity(plan.metas.len());
    let mut at = data_offset;
    for m in &plan.metas {
        entries.push(MntEntry {
            offset: at,
            bytes: m.bytes as u32,
            parent: m.parent,
            first_child: m.first_child,
            child_count: m.child_count,
        });
        at += (m.bytes as u64).div_ceil(page) * page;
    }
    let data_bytes = at - data_offset;
    let holder_bytes = plan.metas.iter().map(|m| m.bytes).max().unwrap_or(0) as u64;
    let roots = plan.metas.iter().take_while(|m| m.parent == NONE).count() as u64;

    let mut header = vec![0u8; HEADER_BYTES as usize];
    header[0..8].copy_from_slice(&MAGIC);
    put_u32(&mut header, 8, VERSION);
    put_u32(&mut header, 12, forest.metric);
    put_u32(&mut header, 16, options.page_bytes);
    put_u32(&mut header, 20, options.levels_per_node);
    put_u64(&mut header, 24, forest.leaves as u64);
    put_u64(&mut header, 32, forest.nodes.len() as u64);
    put_u64(&mut header, 40, forest.triangles.len() as u64);
    put_u64(&mut header, 48, forest.base_triangles as u64);
    put_u64(&mut header, 56, plan.metas.len() as u64);
    put_u64(&mut header, 64, roots);
    put_u64(&mut header, 72, holder_bytes);
    put_u64(&mut header, 80, mnt_offset);
    put_u64(&mut header, 88, base_offset);
    put_u64(&mut header, 96, data_offset);
    put_u64(&mut header, 104, data_bytes);
    for k in 0..3 {
        put_f64(&mut header, 112 + 8 * k, forest.bounds.min[k]);
        put_f64(&mut header, 136 + 8 * k, forest.bounds.max[k]);
    }
    let sum = xxhash_rust::xxh3::xxh3_64(&header[..248]);
    put_u64(&mut header, 248, sum);

    let base = &forest.triangles[forest.triangles.len() - forest.base_triangles..];
    crate::sys::atomic_file::write(out, |w| {
        w.write_all(&header)?;
        w.write_all(bytemuck::cast_slice(&entries))?;
        for t in base {
            let d = t.corners.map(|c| plan.dfs_lo[c as usize]);
            w.write_all(bytemuck::cast_slice(&d))?;
        }
        let pad = (data_offset - base_offset - base_bytes) as usize;
        w.write_all(&vec![0u8; pad])?;
        let mut block = Vec::with_capacity(holder_bytes as usize);
        for (m, meta) in plan.metas.iter().enumerate() {
            encode_block(forest, &plan, m as u32, &mut block);
            debug_assert_eq!(block.len(), meta.bytes);
            w.write_all(&block)?;
            let padded = block.len().div_ceil(page as usize) * page as usize;
            w.write_all(&vec![0u8; padded - block.len()])?;
        }
        Ok(())
    })?;
    let nodes = forest.nodes.len() as f64;
    let metas = plan.metas.len().max(1) as f64;
    Ok(MetaNodeReport {
        metanodes: plan.metas.len() as u64,
        root_metanodes: roots,
        mnt_bytes,
        data_bytes: data_bytes + base_bytes,
        file_bytes: data_offset + data_bytes,
        holder_bytes,
        nodes_per_metanode_mean: nodes / metas,
        fill_mean: plan.metas.iter().map(|m| m.bytes as f64).sum::<f64>() / metas / options.page_bytes as f64,
        build_ms: started.elapsed().as_secs_f64() * 1e3,
    })
}

fn validate_options(o: BlockingOptions) -> Result<()> {
    if !(1..=16).contains(&o.levels_per_node) {
        return Err(Error::InvalidArgument(format!("levels per meta-node must be 1 to 16, got {}", o.levels_per_node)));
    }
    if !o.page_bytes.is_power_of_two() || o.page_bytes < 512 {
        return Err(Error::InvalidArgument(format!(
            "page size must be a power of two of at least 512 bytes, got {}",
            o.page_bytes
        )));
    }
    Ok(())
}

struct PlannedMeta {
    parent: u32,
    first_child: u32,
    child_count: u32,
    /// Range into `Plan::order`.
    start: usize,
    len: usize,
    bytes: usize,
}

/// Where every node goes: per node its meta-node and local index, the leaf DFS numbering, and
/// per meta-node its node list.
struct Plan {
    metas: Vec<PlannedMeta>,
    /// Nodes in block order, meta-node after meta-node.
    order: Vec<u32>,
    meta_of: Vec<u32>,
    local_of: Vec<u16>,
    dfs_lo: Vec<u32>,
}

fn plan(forest: &Forest<'_>, options: BlockingOptions, out: &Path) -> Result<Plan> {
    let nodes = forest.nodes;
    let n = nodes.len();
    let bad = |problem: String| Error::BadMesh { path: out.to_path_buf(), problem };
    if (forest.leaves as usize) > n || forest.base_triangles > forest.triangles.len() {
        return Err(bad("inconsistent forest: leaf or triangle counts out of range".into()));
    }
    // Check the links once, so the traversals below can index freely.
    let mut roots = Vec::new();
    for (id, v) in nodes.iter().enumerate() {
        let leaf = (id as u32) < forest.leaves;
        if leaf != (v.children[0] == NONE) || (v.children[0] == NONE) != (v.children[1] == NONE) {
            return Err(bad(format!("node {id}: leaf/children mismatch")));
        }
        if !leaf {
            for c in v.children {
                if c as usize >= id || nodes[c as usize].parent != id as u32 {
                    return Err(bad(format!("node {id}: child {c} does not link back")));
                }
            }
            let end = v.tri_start as u64 + v.tri_count as u64;
            if end > (forest.triangles.len() - forest.base_triangles) as u64 {
                return Err(bad(format!("node {id}: triangle range out of bounds")));
            }
        }
        if v.parent == NONE {
            roots.push(id as u32);
        } else if v.parent as usize >= n || v.parent as usize <= id {
            return Err(bad(format!("node {id}: parent {} out of order", v.parent)));
        }
    }
    if let Some(t) = forest.triangles.iter().find(|t| t.corners.iter().any(|&c| c >= forest.leaves)) {
        return Err(bad(format!("triangle {:?}: corner is not a leaf", t.corners)));
    }
    // Leaf DFS numbering, first child first: a node's leaves are one interval.
    let mut dfs_lo = vec![0u32; n];
    let mut next_leaf = 0u32;
    let mut stack = Vec::new();
    for &r in &roots {
        stack.push(r);
        while let Some(v) = stack.pop() {
            dfs_lo[v as usize] = next_leaf;
            let node = &nodes[v as usize];
            if node.children[0] == NONE {
                next_leaf += 1;
            } else {
                stack.push(node.children[1]);
                stack.push(node.children[0]);
            }
        }
    }
    if next_leaf != forest.leaves {
        return Err(bad(format!("forest covers {next_leaf} of {} leaves", forest.leaves)));
    }

    let page = options.page_bytes as usize;
    let levels = options.levels_per_node;
    // Bytes of a group root's first L levels (capped at a page), for packing sibling subtrees:
    // counted, since view-dependence trees are far from balanced.
    let estimate = |v: u32| -> usize {
        let mut bytes = 0;
        let mut level = vec![v];
        for _ in 0..levels {
            let mut next = Vec::new();
            for &u in &level {
                let node = &nodes[u as usize];
                bytes += NODE_BYTES + COORD_BYTES / 2 + TRI_BYTES * node.tri_count as usize;
                if node.children[0] != NONE {
                    next.extend(node.children);
                }
            }
            if bytes >= page || next.is_empty() {
                break;
            }
            level = next;
        }
        bytes.min(page)
    };
    let group = |frontier: &[u32]| -> Vec<Vec<u32>> {
        let mut groups: Vec<Vec<u32>> = Vec::new();
        let mut size = usize::MAX;
        for &v in frontier {
            let e = estimate(v);
            if size.saturating_add(e) > page - BLOCK_HEADER_BYTES {
                groups.push(Vec::new());
                size = 0;
            }
            size += e;
            groups.last_mut().expect("pushed above").push(v);
        }
        groups
    };

    let mut metas: Vec<PlannedMeta> = Vec::new();
    let mut order = Vec::with_capacity(n);
    let mut meta_of = vec![NONE; n];
    let mut local_of = vec![0u16; n];
    let mut queue: std::collections::VecDeque<(u32, Vec<u32>)> = group(&roots).into_iter().map(|g| (NONE, g)).collect();
    let mut coords = std::collections::HashSet::new();
    while let Some((parent, group_roots)) = queue.pop_front() {
        let m = metas.len() as u32;
        let start = order.len();
        let mut bytes = BLOCK_HEADER_BYTES;
        coords.clear();
        let mut frontier = Vec::new();
        let mut level = group_roots;
        for depth in 0..levels {
            let mut next = Vec::new();
            for v in level {
                let node = &nodes[v as usize];
                let key = node.position.map(f32::to_bits);
                let cost = NODE_BYTES
                    + if coords.contains(&key) { 0 } else { COORD_BYTES }
                    + TRI_BYTES * node.tri_count as usize;
                // Group roots always go in (the grouping sized them to fit), so a meta-node's
                // children hold exactly the children of its nodes.
                if depth > 0 && (bytes + cost > page || order.len() - start >= u16::MAX as usize) {
                    frontier.push(v);
                    continue;
                }
                coords.insert(key);
                bytes += cost;
                meta_of[v as usize] = m;
                local_of[v as usize] = (order.len() - start) as u16;
                order.push(v);
                if node.children[0] != NONE {
                    if depth + 1 < levels {
                        next.extend(node.children);
                    } else {
                        frontier.extend(node.children);
                    }
                }
            }
            level = next;
        }
        frontier.extend(level);
        let first_child = (metas.len() + 1 + queue.len()) as u32;
        let children = group(&frontier);
        let child_count = children.len() as u32;
        for g in children {
            queue.push_back((m, g));
        }
        metas.push(PlannedMeta { parent, first_child, child_count, start, len: order.len() - start, bytes });
    }
    // The byte count above may overcount shared coordinates of later duplicates; recompute exactly.
    let mut plan = Plan { metas, order, meta_of, local_of, dfs_lo };
    let mut scratch = Vec::new();
    for m in 0..plan.metas.len() {
        encode_block(forest, &plan, m as u32, &mut scratch);
        plan.metas[m].bytes = scratch.len();
    }
    Ok(plan)
}

/// Encodes meta-node `m`'s block into `out` (cleared first).
fn encode_block(forest: &Forest<'_>, plan: &Plan, m: u32, out: &mut Vec<u8>) {
    let nodes = forest.nodes;
    let meta = &plan.metas[m as usize];
    let members = &plan.order[meta.start..meta.start + meta.len];
    let mut coords: Vec<[f32; 3]> = Vec::new();
    let mut coord_index = std::collections::HashMap::new();
    let mut records = Vec::with_capacity(members.len());
    let mut tris: Vec<[u32; 3]> = Vec::new();
    for &v in members {
        let node = &nodes[v as usize];
        let key = node.position.map(f32::to_bits);
        let coord = *coord_index.entry(key).or_insert_with(|| {
            coords.push(node.position);
            (coords.len() - 1) as u16
        });
        let (parent_meta, parent_local, parent_switch, parent_radius) = if node.parent == NONE {
            (NONE, 0, 0.0, 0.0)
        } else {
            let p = &nodes[node.parent as usize];
            (plan.meta_of[node.parent as usize], plan.local_of[node.parent as usize], p.switch, p.radius)
        };
        let (child_meta, child_local) = if node.children[0] == NONE {
            ([NONE; 2], [0; 2])
        } else {
            (node.children.map(|c| plan.meta_of[c as usize]), node.children.map(|c| plan.local_of[c as usize]))
        };
        let tri_start = tris.len() as u16;
        let range = node.tri_start as usize..node.tri_start as usize + node.tri_count as usize;
        if node.children[0] != NONE {
            for t in &forest.triangles[range] {
                tris.push(t.corners.map(|c| plan.dfs_lo[c as usize]));
            }
        }
        records.push(MnNode {
            id: v,
            parent_id: node.parent,
            parent_meta,
            child_meta,
            parent_local,
            child_local,
            coord,
            switch: node.switch,
            radius: node.radius,
            parent_switch,
            parent_radius,
            dfs_lo: plan.dfs_lo[v as usize],
            leaves: node.leaves,
            tri_start,
            tri_count: tris.len() as u16 - tri_start,
        });
    }
    out.clear();
    for x in [records.len() as u32, coords.len() as u32, tris.len() as u32, 0] {
        out.extend_from_slice(&x.to_le_bytes());
    }
    out.extend_from_slice(bytemuck::cast_slice(&records));
    out.extend_from_slice(bytemuck::cast_slice(&coords));
    out.extend_from_slice(bytemuck::cast_slice(&tris));
}

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

/// An open meta-node file: the header and meta-node table in memory, the blocks mapped.
pub struct MetaNodeFile {
    path: PathBuf,
    file: File,
    map: Mmap,
    header: MetaHeader,
    mnt: Vec<MntEntry>,
}

impl MetaNodeFile {
    /// Opens and validates a meta-node file: magic, version, header checksum, section sizes
    /// against the file length, and every table entry (offsets inside DATA, sizes within the
    /// holder size, tree links in range). Blocks are validated when read ([`BlockView::parse`]).
    pub fn open(path: &Path) -> Result<MetaNodeFile> {
        let file = File::open(path).at(path)?;
        let len = file.metadata().at(path)?.len();
        let map = crate::pager::source::map_read_only(path, &file, len)?;
        let header = decode_header(path, &map, len)?;
        let bad = |problem: String| Error::BadHeader { path: path.to_path_buf(), problem };
        let mnt_bytes = header.metanodes as usize * std::mem::size_of::<MntEntry>();
        let mnt_slice = &map[header.mnt_offset as usize..header.mnt_offset as usize + mnt_bytes];
        let mnt: Vec<MntEntry> = mnt_slice.chunks_exact(24).map(bytemuck::pod_read_unaligned).collect();
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
        Ok(MetaNodeFile { path: path.to_path_buf(), file, map, header, mnt })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// No readahead, for the map and for `pread`: a cold flight then reads exactly the pages it
    /// touches, so Virt and Ext are compared on the same I/O.
    pub fn advise_random(&self) -> Result<()> {
        use std::os::fd::AsRawFd;
        self.map.advise(memmap2::Advice::Random).at(&self.path)?;
        // SAFETY: posix_fadvise only reads the descriptor, which `self.file` keeps open.
        let rc = unsafe { libc::posix_fadvise(self.file.as_raw_fd(), 0, 0, libc::POSIX_FADV_RANDOM) };
        if rc != 0 {
            return Err(Error::io(&self.path, std::io::Error::from_raw_os_error(rc)));
        }
        Ok(())
    }

    pub fn header(&self) -> &MetaHeader {
        &self.header
    }

    pub fn mnt(&self) -> &[MntEntry] {
        &self.mnt
    }

    /// The base triangles (m(t) = none), corners as leaf DFS numbers.
    pub fn base_triangles(&self) -> &[[u32; 3]] {
        let at = self.header.base_offset as usize;
        bytemuck::cast_slice(&self.map[at..at + self.header.base_triangles as usize * TRI_BYTES])
    }

    /// Block `m` through the map (the "Virt" path: the OS pages it in).
    pub fn mapped_block(&self, m: u32) -> &[u8] {
        let e = &self.mnt[m as usize];
        &self.map[e.offset as usize..e.offset as usize + e.bytes as usize]
    }

    /// Reads block `m` with `pread` into `buf` (the "Ext" path), resized to the block's words.
    pub fn read_block(&self, m: u32, buf: &mut Vec<u32>) -> Result<()> {
        use std::os::unix::fs::FileExt;
        let e =
            self.mnt.get(m as usize).ok_or_else(|| Error::InvalidArgument(format!("meta-node {m} out of range")))?;
        buf.clear();
        buf.resize((e.bytes as usize).div_ceil(4), 0);
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(buf.as_mut_slice());
        self.file.read_exact_at(&mut bytes[..e.bytes as usize], e.offset).at(&self.path)
    }

    /// Pages of block `m` (what reading it costs).
    pub fn block_pages(&self, m: u32) -> u64 {
        (self.mnt[m as usize].bytes as u64).div_ceil(self.header.page_bytes as u64)
    }

    /// The bytes of the whole tree on disk (DATA + MNT).
    pub fn tree_bytes(&self) -> u64 {
        self.header.data_bytes + self.mnt.len() as u64 * 24
    }
}

fn decode_header(path: &Path, b: &[u8], len: u64) -> Result<MetaHeader> {
    let bad = |problem: String| Error::BadHeader { path: path.to_path_buf(), problem };
    if b.len() < 8 || b[0..8] != MAGIC {
        return Err(Error::BadMagic { path: path.to_path_buf() });
    }
    if b.len() < HEADER_BYTES as usize {
        return Err(Error::Truncated { path: path.into(), expected: HEADER_BYTES, found: len });
    }
    let version = get_u32(b, 8);
    if version != VERSION {
        return Err(Error::BadVersion { path: path.into(), found: version, supported: VERSION });
    }
    let stored = get_u64(b, 248);
    let computed = xxhash_rust::xxh3::xxh3_64(&b[..248]);
    if stored != computed {
        return Err(Error::Checksum { path: path.into(), which: "header", stored, computed });
    }
    let f = |at| f64::from_bits(get_u64(b, at));
    let h = MetaHeader {
        metric: get_u32(b, 12),
        page_bytes: get_u32(b, 16),
        levels_per_node: get_u32(b, 20),
        leaves: get_u64(b, 24),
        nodes: get_u64(b, 32),
        triangles: get_u64(b, 40),
        base_triangles: get_u64(b, 48),
        metanodes: get_u64(b, 56),
        root_metanodes: get_u64(b, 64),
        holder_bytes: get_u64(b, 72),
        mnt_offset: get_u64(b, 80),
        base_offset: get_u64(b, 88),
        data_offset: get_u64(b, 96),
        data_bytes: get_u64(b, 104),
        bounds: Bounds { min: [f(112), f(120), f(128)], max: [f(136), f(144), f(152)] },
    };
    if !h.page_bytes.is_power_of_two() || h.page_bytes < 512 {
        return Err(bad(format!("page size {} is not a power of two ≥ 512", h.page_bytes)));
    }
    if h.metanodes == 0 || h.root_metanodes == 0 || h.root_metanodes > h.metanodes || h.metanodes > u32::MAX as u64 / 2
    {
        return Err(bad(format!("{} meta-nodes with {} roots", h.metanodes, h.root_metanodes)));
    }
    if h.leaves == 0 || h.leaves > h.nodes || h.nodes >= NONE as u64 || h.base_triangles > h.triangles {
        return Err(bad(format!(
            "{} leaves, {} nodes, {} triangles ({} base)",
            h.leaves, h.nodes, h.triangles, h.base_triangles
        )));
    }
    let mnt_end = h.metanodes.checked_mul(24).and_then(|x| x.checked_add(h.mnt_offset));
    let base_end = h.base_triangles.checked_mul(12).and_then(|x| x.checked_add(h.base_offset));
    let data_end = h.data_offset.checked_add(h.data_bytes);
    let ordered = h.mnt_offset == HEADER_BYTES
        && mnt_end == Some(h.base_offset)
        && base_end.is_some_and(|e| e <= h.data_offset)
        && h.data_offset.is_multiple_of(h.page_bytes as u64);
    if !ordered || h.holder_bytes > u32::MAX as u64 {
        return Err(bad("section offsets are inconsistent".into()));
    }
    match data_end {
        Some(end) if end == len => {}
        Some(end) => return Err(Error::Truncated { path: path.into(), expected: end, found: len }),
        None => return Err(bad("DATA size overflows".into())),
    }
    Ok(h)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A complete binary tree over `leaves` (a power of two) leaves on a line, with one triangle
    /// per internal node (its first leaves) and one base triangle.
    fn line_forest(leaves: u32) -> (Vec<VdtNode>, Vec<VdtTriangle>) {
        let mut nodes: Vec<VdtNode> = (0..leaves)
            .map(|i| VdtNode {
                position: [i as f32, 0.0, 0.0],
                children: [NONE; 2],
                parent: NONE,
                leaves: 1,
                ..Default::default()
            })
            .collect();
        let mut tris = Vec::new();
        let mut level: Vec<u32> = (0..leaves).collect();
        while level.len() > 1 {
            let mut next = Vec::new();
            for pair in level.chunks(2) {
                let (a, b) = (pair[0], pair[1]);
                let p = nodes.len() as u32;
                let (na, nb) = (nodes[a as usize], nodes[b as usize]);
                nodes.push(VdtNode {
                    position: na.position,
                    switch: 1.0 + na.switch.max(nb.switch),
                    radius: na.radius.max(nb.position[0] - na.position[0] + nb.radius),
                    children: [a, b],
                    parent: NONE,
                    leaves: na.leaves + nb.leaves,
                    tri_start: tris.len() as u32,
                    tri_count: 1,
                    reserved: 0,
                });
                nodes[a as usize].parent = p;
                nodes[b as usize].parent = p;
                tris.push(VdtTriangle { corners: [0, 1, 2] });
                next.push(p);
            }
            level = next;
        }
        tris.push(VdtTriangle { corners: [0, 1, leaves - 1] });
        (nodes, tris)
    }

    fn forest<'a>(nodes: &'a [VdtNode], tris: &'a [VdtTriangle], leaves: u32) -> Forest<'a> {
        let bounds = Bounds { min: [0.0; 3], max: [leaves as f64, 0.0, 0.0] };
        Forest { nodes, triangles: tris, base_triangles: 1, leaves, metric: 0, bounds }
    }

    #[test]
    fn blocks_hold_every_node_once_within_page_and_levels() {
        let (nodes, tris) = line_forest(256);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.rmn");
        let options = BlockingOptions { levels_per_node: 3, page_bytes: 1024 };
        let report = write_metanode_file(&forest(&nodes, &tris, 256), options, &path).unwrap();
        let f = MetaNodeFile::open(&path).unwrap();
        assert_eq!(f.header().metanodes, report.metanodes);
        assert_eq!(f.header().root_metanodes, 1);
        let mut seen = vec![0u32; nodes.len()];
        let metas = f.header().metanodes as u32;
        for m in 0..metas {
            let view = BlockView::parse(f.mapped_block(m), metas).unwrap();
            assert!(f.mapped_block(m).len() <= 1024, "block {m} exceeds the page");
            let e = f.mnt()[m as usize];
            for (local, v) in view.nodes.iter().enumerate() {
                seen[v.id as usize] += 1;
                let orig = &nodes[v.id as usize];
                assert_eq!(view.position(v), orig.position);
                assert_eq!(v.leaves, orig.leaves);
                if v.parent_id != NONE {
                    // The parent is in this block or in the parent meta-node.
                    assert!(v.parent_meta == m || v.parent_meta == e.parent, "node {} parent block", v.id);
                    let pv = BlockView::parse(f.mapped_block(v.parent_meta), metas).unwrap();
                    let p = &pv.nodes[v.parent_local as usize];
                    assert_eq!(p.id, orig.parent);
                    let k = if p.child_meta[0] == m && p.child_local[0] as usize == local { 0 } else { 1 };
                    assert_eq!((p.child_meta[k], p.child_local[k] as usize), (m, local));
                    assert_eq!(v.parent_switch, p.switch);
                }
                if !v.is_leaf() {
                    for k in 0..2 {
                        let c = v.child_meta[k];
                        assert!(c == m || (e.first_child..e.first_child + e.child_count).contains(&c));
                    }
                    assert_eq!(view.triangles_of(v).len(), 1);
                }
            }
            // At most L levels per block: no chain of three in-block parents above a node.
            for v in view.nodes {
                let mut depth = 0;
                let mut cur = *v;
                while cur.parent_id != NONE && cur.parent_meta == m {
                    cur = view.nodes[cur.parent_local as usize];
                    depth += 1;
                }
                assert!(depth < 3, "block {m} has more than L = 3 levels");
            }
        }
        assert!(seen.iter().all(|&c| c == 1), "every node in exactly one block");
        assert_eq!(f.base_triangles(), &[[0, 1, 255]]);
        assert!(report.fill_mean > 0.3 && report.fill_mean <= 1.0, "fill {}", report.fill_mean);
    }

    #[test]
    fn damaged_files_are_one_line_errors() {
        let (nodes, tris) = line_forest(64);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.rmn");
        write_metanode_file(&forest(&nodes, &tris, 64), BlockingOptions::default(), &path).unwrap();
        let good = std::fs::read(&path).unwrap();
        let bad = dir.path().join("bad.rmn");
        let open = |bytes: &[u8]| {
            std::fs::write(&bad, bytes).unwrap();
            MetaNodeFile::open(&bad).err().map(|e| e.to_string()).unwrap_or_default()
        };
        let mut b = good.clone();
        b[0] = b'X';
        assert!(open(&b).contains("magic"), "{}", open(&b));
        let mut b = good.clone();
        b[60] ^= 1;
        assert!(open(&b).contains("checksum"), "{}", open(&b));
        assert!(open(&good[..good.len() - 100]).contains("truncated"), "{}", open(&good[..good.len() - 100]));
        assert!(open(&good[..100]).contains("truncated"));
        let e = open(&good[..100]);
        assert!(e.starts_with(&bad.display().to_string()) && !e.contains('\n'), "{e}");
        // A block whose counts are wrong is caught when parsed.
        let f = MetaNodeFile::open(&path).unwrap();
        let at = f.mnt()[0].offset as usize;
        let mut b = good.clone();
        b[at..at + 4].copy_from_slice(&100_000u32.to_le_bytes());
        std::fs::write(&bad, &b).unwrap();
        let g = MetaNodeFile::open(&bad).unwrap();
        assert!(BlockView::parse(g.mapped_block(0), 1).is_err());
        // Options.
        let e = write_metanode_file(
            &forest(&nodes, &tris, 64),
            BlockingOptions { levels_per_node: 0, page_bytes: 4096 },
            &path,
        );
        assert!(e.unwrap_err().to_string().contains("levels"));
        let e = write_metanode_file(
            &forest(&nodes, &tris, 64),
            BlockingOptions { levels_per_node: 4, page_bytes: 3000 },
            &path,
        );
        assert!(e.unwrap_err().to_string().contains("power of two"));
    }
}
