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

use std::io::Write;
use std::path::Path;

use serde::Serialize;

use super::{VdtNode, VdtTriangle, NONE};
use crate::error::{Error, Result};
use crate::format::metanode::{
    MetaHeader, MnNode, MntEntry, BLOCK_HEADER_BYTES, COORD_BYTES, HEADER_BYTES, MAX_PAGE_BYTES, MIN_PAGE_BYTES,
    NODE_BYTES, TRI_BYTES,
};
use crate::format::Format;
use crate::mesh::Bounds;

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

    let meta_header = MetaHeader {
        metric: forest.metric,
        page_bytes: options.page_bytes,
        levels_per_node: options.levels_per_node,
        leaves: forest.leaves as u64,
        nodes: forest.nodes.len() as u64,
        triangles: forest.triangles.len() as u64,
        base_triangles: forest.base_triangles as u64,
        metanodes: plan.metas.len() as u64,
        root_metanodes: roots,
        holder_bytes,
        mnt_offset,
        base_offset,
        data_offset,
        data_bytes,
        bounds: forest.bounds,
    };
    let mut header = vec![0u8; HEADER_BYTES as usize];
    header[..crate::format::HEADER_BYTES].copy_from_slice(&meta_header.encode().0);

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
        // Blocks are encoded in parallel, a chunk of meta-nodes at a time, and written in order.
        use rayon::prelude::*;
        const CHUNK: usize = 4096;
        let zeros = vec![0u8; page as usize];
        for first in (0..plan.metas.len()).step_by(CHUNK) {
            let last = (first + CHUNK).min(plan.metas.len());
            let blocks: Vec<Vec<u8>> = (first..last)
                .into_par_iter()
                .map(|m| {
                    let mut block = Vec::new();
                    encode_block(forest, &plan, m as u32, &mut block);
                    block
                })
                .collect();
            for (block, meta) in blocks.iter().zip(&plan.metas[first..last]) {
                if block.len() != meta.bytes {
                    return Err(std::io::Error::other(format!(
                        "internal error: a block of {} bytes planned as {}",
                        block.len(),
                        meta.bytes
                    )));
                }
                w.write_all(block)?;
                let padded = block.len().div_ceil(page as usize) * page as usize;
                w.write_all(&zeros[..padded - block.len()])?;
            }
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

impl BlockingOptions {
    /// Checks the levels (1 to 16) and the page size (a power of two from 512 bytes to 1 MiB).
    pub fn validate(&self) -> Result<()> {
        validate_options(*self)
    }
}

fn validate_options(o: BlockingOptions) -> Result<()> {
    if !(1..=16).contains(&o.levels_per_node) {
        return Err(Error::out_of_range("levels per meta-node", "1 to 16", o.levels_per_node));
    }
    if !o.page_bytes.is_power_of_two() || !(MIN_PAGE_BYTES..=MAX_PAGE_BYTES).contains(&o.page_bytes) {
        return Err(Error::out_of_range("page size", "a power of two from 512 bytes to 1 MiB", o.page_bytes));
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
    let mut scratch = (Vec::new(), Vec::new());
    let mut estimate = |v: u32| -> usize {
        let (level, next) = &mut scratch;
        let mut bytes = 0;
        level.clear();
        level.push(v);
        for _ in 0..levels {
            next.clear();
            for &u in level.iter() {
                let node = &nodes[u as usize];
                bytes += NODE_BYTES + COORD_BYTES / 2 + TRI_BYTES * node.tri_count as usize;
                if node.children[0] != NONE {
                    next.extend(node.children);
                }
            }
            if bytes >= page || next.is_empty() {
                break;
            }
            std::mem::swap(level, next);
        }
        bytes.min(page)
    };
    let mut group = |frontier: &[u32]| -> Vec<Vec<u32>> {
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
    let mut coords = rustc_hash::FxHashSet::default();
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
    // The byte count above may overcount shared coordinates of later duplicates; count exactly
    // (what encode_block writes: the members, their distinct coordinates, their triangles).
    let mut plan = Plan { metas, order, meta_of, local_of, dfs_lo };
    for meta in &mut plan.metas {
        coords.clear();
        let members = &plan.order[meta.start..meta.start + meta.len];
        let mut tris = 0;
        for &v in members {
            let node = &nodes[v as usize];
            coords.insert(node.position.map(f32::to_bits));
            if node.children[0] != NONE {
                tris += node.tri_count as usize;
            }
        }
        meta.bytes = BLOCK_HEADER_BYTES + members.len() * NODE_BYTES + coords.len() * COORD_BYTES + tris * TRI_BYTES;
    }
    Ok(plan)
}

/// Encodes meta-node `m`'s block into `out` (cleared first).
fn encode_block(forest: &Forest<'_>, plan: &Plan, m: u32, out: &mut Vec<u8>) {
    let nodes = forest.nodes;
    let meta = &plan.metas[m as usize];
    let members = &plan.order[meta.start..meta.start + meta.len];
    let mut coords: Vec<[f32; 3]> = Vec::new();
    let mut coord_index = rustc_hash::FxHashMap::default();
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::metanode::{BlockView, MetaNodeFile};

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
            let block = f.block(m).unwrap();
            let view = BlockView::parse(&block, metas).unwrap();
            assert!(block.len() <= 1024, "block {m} exceeds the page");
            let e = f.mnt()[m as usize];
            for (local, v) in view.nodes.iter().enumerate() {
                seen[v.id as usize] += 1;
                let orig = &nodes[v.id as usize];
                assert_eq!(view.position(v), orig.position);
                assert_eq!(v.leaves, orig.leaves);
                if v.parent_id != NONE {
                    // The parent is in this block or in the parent meta-node.
                    assert!(v.parent_meta == m || v.parent_meta == e.parent, "node {} parent block", v.id);
                    let parent_block = f.block(v.parent_meta).unwrap();
                    let pv = BlockView::parse(&parent_block, metas).unwrap();
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
        assert!(BlockView::parse(&g.block(0).unwrap(), 1).is_err());
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
