//! The VDT file: the view-dependence forest of a mesh (El-Sana & Chiang 2000, §3.1), written by
//! [`crate::metanode::build`] and read back, mapped, to block it into meta-nodes.
//!
//! # VDT file (little-endian; the container's header block, then the records)
//! ```text
//! offset size  field
//!      0    8  magic "\x89RLFVDT\n"
//!      8    4  version (2)
//!     12    4  metric (0 length, 1 quadric)
//!     16    8  leaves (input vertices)
//!     24    8  nodes (leaves + collapses); node records are indexed by id
//!     32    8  triangles (input triangles kept, in the triangle section)
//!     40    8  base triangles (the last `base` entries of the triangle section: m(t) = none)
//!     48   24  bounding box min x, y, z (f64)
//!     72   24  bounding box max x, y, z (f64)
//!     96  152  reserved (0)
//!    248    8  header checksum: XXH3-64 of bytes 0..248
//!    256    -  node records, `nodes` × 48 bytes ([`VdtNode`]), in id order
//!      -    -  triangle records, `triangles` × 12 bytes ([`VdtTriangle`]): grouped by m(t) in
//!              increasing node id (node p's are `tri_start .. tri_start + tri_count`), then the
//!              base triangles
//! ```
//! Version 1 had a 128-byte header without a checksum.
//!
//! [`VdtFile::open`] checks the magic, the version, the metric, the counts against each other and
//! the exact file length against the counts, then every node record (children below the node,
//! parent above it, triangle ranges inside the section, leaf counts) and every triangle corner.
//! After that, ids read from the file can be used as indices without further checks of their
//! range. A bad file gives one error line naming the file and the problem.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use serde::Serialize;

use super::{corrupt, corrupt_at, read_header, Bounds, FileKind, Format, HeaderBytes, Problem};
use crate::error::{Error, Result};
use crate::pager::source::{Source, SourceKind};

pub const NONE: u32 = u32::MAX;

/// One node of the view-dependence forest (48 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct VdtNode {
    /// The node's position: `children[0]`'s (a leaf's), in the mesh's units.
    pub position: [f32; 3],
    /// Switch value: the collapse metric of the edge whose collapse created this node, nested
    /// (≥ both children's); 0 for leaves. Length metric: metres (mesh units); quadric: the square
    /// root of the quadric error, also in mesh units.
    pub switch: f32,
    /// Radius of a sphere around `position` holding every leaf of the subtree, nested
    /// (≥ ‖p − c‖ + r_c for both children c); 0 for leaves.
    pub radius: f32,
    /// The two children (`children[0]` gives the position); [`NONE`] for leaves.
    pub children: [u32; 2],
    /// [`NONE`] for roots.
    pub parent: u32,
    /// Leaves in the subtree (1 for a leaf).
    pub leaves: u32,
    /// The triangles that this node's split creates (m(t) = this node): a range of the triangle
    /// section. Empty for leaves.
    pub tri_start: u32,
    pub tri_count: u32,
    pub reserved: u32,
}

/// An input triangle by its three corner leaves (input vertex ids), counter-clockwise.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct VdtTriangle {
    pub corners: [u32; 3],
}

/// The version this build writes and reads.
pub const VERSION: u32 = 2;
/// Bytes before the node records.
pub const HEADER_BYTES: usize = super::HEADER_BYTES;
/// Bytes per node record.
pub const NODE_BYTES: usize = std::mem::size_of::<VdtNode>();
/// Bytes per triangle record.
pub const TRIANGLE_BYTES: usize = std::mem::size_of::<VdtTriangle>();

const _: () = assert!(NODE_BYTES == 48 && TRIANGLE_BYTES == 12);

/// The collapse metric, which gives the switch values their meaning.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
#[repr(u32)]
pub enum VdtMetric {
    /// Edge length, mesh units.
    Length = 0,
    /// Square root of the Garland–Heckbert quadric error of the collapse (mesh units).
    Quadric = 1,
}

impl VdtMetric {
    pub const ALL: [VdtMetric; 2] = [VdtMetric::Length, VdtMetric::Quadric];

    pub fn name(self) -> &'static str {
        match self {
            VdtMetric::Length => "length",
            VdtMetric::Quadric => "quadric",
        }
    }

    pub fn from_name(name: &str) -> Option<VdtMetric> {
        VdtMetric::ALL.into_iter().find(|m| m.name() == name)
    }

    fn from_code(code: u32) -> Option<VdtMetric> {
        VdtMetric::ALL.into_iter().find(|&m| m as u32 == code)
    }
}

/// The header fields (everything but the magic, version and reserved bytes).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct VdtHeader {
    pub metric: VdtMetric,
    /// Input vertices: node ids `0..leaves` are leaves.
    pub leaves: u64,
    /// Leaves plus collapses.
    pub nodes: u64,
    /// Triangle records (every input triangle, once).
    pub triangles: u64,
    /// The last `base_triangles` triangle records: those that never die (m(t) = none).
    pub base_triangles: u64,
    pub bounds: Bounds,
}

impl VdtHeader {
    /// The exact size of a file with this header, bytes.
    pub fn file_bytes(&self) -> u64 {
        HEADER_BYTES as u64 + self.nodes * NODE_BYTES as u64 + self.triangles * TRIANGLE_BYTES as u64
    }
}

impl Format for VdtHeader {
    const KIND: FileKind = FileKind::Vdt;

    fn encode_fields(&self, h: &mut HeaderBytes) {
        h.put_u32(12, self.metric as u32);
        h.put_u64(16, self.leaves);
        h.put_u64(24, self.nodes);
        h.put_u64(32, self.triangles);
        h.put_u64(40, self.base_triangles);
        h.put_f64x3(48, self.bounds.min);
        h.put_f64x3(72, self.bounds.max);
    }

    /// Checks the counts against each other and the file's exact length against them.
    fn decode(h: &HeaderBytes, file_len: u64) -> std::result::Result<VdtHeader, Problem> {
        let bad = |what: String| Problem::Corrupt(format!("header: {what}"));
        let metric =
            VdtMetric::from_code(h.u32(12)).ok_or_else(|| bad(format!("unknown metric code {}", h.u32(12))))?;
        let (leaves, nodes, triangles, base_triangles) = (h.u64(16), h.u64(24), h.u64(32), h.u64(40));
        if nodes < leaves || nodes >= NONE as u64 {
            return Err(bad(format!("{nodes} nodes for {leaves} leaves")));
        }
        if nodes > (2 * leaves).saturating_sub(1) {
            return Err(bad(format!("{nodes} nodes is more than a binary forest on {leaves} leaves has")));
        }
        if base_triangles > triangles || triangles >= NONE as u64 {
            return Err(bad(format!("{base_triangles} base triangles of {triangles}")));
        }
        let bounds = Bounds { min: h.f64x3(48), max: h.f64x3(72) };
        if bounds.min.iter().chain(&bounds.max).any(|c| !c.is_finite()) {
            return Err(bad("non-finite bounding box".into()));
        }
        let header = VdtHeader { metric, leaves, nodes, triangles, base_triangles, bounds };
        let expected = header.file_bytes();
        if file_len != expected {
            return Err(Problem::Truncated { expected, found: file_len });
        }
        Ok(header)
    }
}

/// Writes a whole VDT file's header; the caller then writes `nodes` node records and `triangles`
/// triangle records (see [`super::build`], which assembles the file atomically).
pub fn write_header(w: &mut impl Write, header: &VdtHeader) -> std::io::Result<()> {
    w.write_all(&header.encode().0)
}

/// A validated VDT file, mapped read-only.
pub struct VdtFile {
    path: PathBuf,
    header: VdtHeader,
    /// A local map (checked at open): the node and triangle sections are borrowed in place.
    file: Arc<dyn Source>,
}

impl VdtFile {
    /// Opens and validates a VDT file (see the module docs for what is checked).
    pub fn open(path: &Path) -> Result<VdtFile> {
        let file = crate::pager::open(path, SourceKind::Map)?;
        if file.mapped().is_none() {
            return Err(Error::InvalidArgument(format!(
                "{}: a VDT file is read in place from a local map (not remotely)",
                path.display()
            )));
        }
        let header: VdtHeader = read_header(&*file)?;
        let vdt = VdtFile { path: path.to_path_buf(), header, file };
        vdt.check_records()?;
        Ok(vdt)
    }

    /// The mapped file (a map, checked at open).
    fn bytes(&self) -> &[u8] {
        self.file.mapped().unwrap_or(&[])
    }

    /// Every node's links, counts and triangle range, and every triangle's corners, against the
    /// header (one pass over the file).
    fn check_records(&self) -> Result<()> {
        let bad = |what: String| corrupt(&self.path, FileKind::Vdt, what);
        // A node's or a triangle's record, by its byte offset.
        let node_at = |id: u32, what: String| {
            corrupt_at(&self.path, FileKind::Vdt, (HEADER_BYTES + id as usize * NODE_BYTES) as u64, what)
        };
        let leaves = self.header.leaves as u32;
        let nodes = self.nodes();
        let dying = self.header.triangles - self.header.base_triangles;
        let mut next_tri = 0u64;
        for (id, n) in nodes.iter().enumerate() {
            let id = id as u32;
            let parent_ok = n.parent == NONE || (n.parent > id && (n.parent as usize) < nodes.len());
            if !parent_ok {
                return Err(node_at(id, format!("node {id}: parent {} is not a later node", n.parent)));
            }
            if id < leaves {
                if n.children != [NONE, NONE] || n.leaves != 1 || n.tri_count != 0 {
                    return Err(node_at(
                        id,
                        format!("leaf {id}: has children, triangles or a leaf count other than 1"),
                    ));
                }
                continue;
            }
            let [c0, c1] = n.children;
            if c0 >= id || c1 >= id || c0 == c1 {
                return Err(node_at(id, format!("node {id}: children {c0}, {c1} are not two earlier nodes")));
            }
            let sum = nodes[c0 as usize].leaves as u64 + nodes[c1 as usize].leaves as u64;
            if n.leaves as u64 != sum {
                return Err(node_at(id, format!("node {id}: {} leaves, its children have {sum}", n.leaves)));
            }
            if n.tri_start as u64 != next_tri || next_tri + n.tri_count as u64 > dying {
                return Err(node_at(
                    id,
                    format!(
                        "node {id}: triangles {}..+{} do not follow the previous node's in the section",
                        n.tri_start, n.tri_count
                    ),
                ));
            }
            next_tri += n.tri_count as u64;
        }
        if next_tri != dying {
            return Err(bad(format!("the nodes' triangle ranges cover {next_tri} of {dying} non-base triangles")));
        }
        if let Some((k, t)) = self.triangles().iter().enumerate().find(|(_, t)| t.corners.iter().any(|&c| c >= leaves))
        {
            let at = HEADER_BYTES + self.header.nodes as usize * NODE_BYTES + k * TRIANGLE_BYTES;
            return Err(corrupt_at(
                &self.path,
                FileKind::Vdt,
                at as u64,
                format!("triangle {k}: corner out of range {:?} ({leaves} leaves)", t.corners),
            ));
        }
        Ok(())
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn header(&self) -> &VdtHeader {
        &self.header
    }

    /// Node records by id (leaves first).
    pub fn nodes(&self) -> &[VdtNode] {
        let start = HEADER_BYTES;
        let end = start + self.header.nodes as usize * NODE_BYTES;
        bytemuck::cast_slice(&self.bytes()[start..end])
    }

    /// Every triangle record: grouped by m(t) in increasing node id, then the base triangles.
    pub fn triangles(&self) -> &[VdtTriangle] {
        let start = HEADER_BYTES + self.header.nodes as usize * NODE_BYTES;
        let end = start + self.header.triangles as usize * TRIANGLE_BYTES;
        bytemuck::cast_slice(&self.bytes()[start..end])
    }

    /// The triangles that never die (m(t) = none): the base mesh over the roots.
    pub fn base_triangles(&self) -> &[VdtTriangle] {
        let all = self.triangles();
        &all[all.len() - self.header.base_triangles as usize..]
    }

    /// The triangles that node `id`'s split creates (m(t) = id); empty for leaves.
    pub fn node_triangles(&self, id: u32) -> &[VdtTriangle] {
        let n = &self.nodes()[id as usize];
        // A leaf's start is not checked at open (it has no range), so it is not used here.
        if n.tri_count == 0 {
            return &[];
        }
        &self.triangles()[n.tri_start as usize..n.tri_start as usize + n.tri_count as usize]
    }

    /// Input vertices (leaf ids are `0..leaves`).
    pub fn leaves(&self) -> u64 {
        self.header.leaves
    }

    /// The input mesh's bounding box.
    pub fn bounds(&self) -> Bounds {
        self.header.bounds
    }

    pub fn metric(&self) -> VdtMetric {
        self.header.metric
    }

    /// Nodes without a parent.
    pub fn roots(&self) -> impl Iterator<Item = u32> + '_ {
        self.nodes().iter().enumerate().filter(|(_, n)| n.parent == NONE).map(|(id, _)| id as u32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> VdtHeader {
        VdtHeader {
            metric: VdtMetric::Quadric,
            leaves: 3,
            nodes: 5,
            triangles: 1,
            base_triangles: 0,
            bounds: Bounds { min: [0.0, -1.0, 2.0], max: [1.0, 0.5, 3.0] },
        }
    }

    fn decode(b: &[u8], len: u64) -> Result<VdtHeader> {
        super::super::decode_header(Path::new("x.vdt"), b, len)
    }

    #[test]
    fn header_round_trips_and_sizes_the_file() {
        let h = header();
        let bytes = h.encode().0;
        assert_eq!(&bytes[..8], b"\x89RLFVDT\n");
        assert_eq!(h.file_bytes(), 256 + 5 * 48 + 12);
        assert_eq!(decode(&bytes, h.file_bytes()).unwrap(), h);
    }

    #[test]
    fn inconsistent_headers_are_refused() {
        let err = |h: VdtHeader| decode(&h.encode().0, h.file_bytes()).unwrap_err().to_string();
        assert_eq!(
            err(VdtHeader { nodes: 6, ..header() }),
            "x.vdt: corrupt VDT file: header: 6 nodes is more than a binary forest on 3 leaves has"
        );
        assert_eq!(err(VdtHeader { nodes: 2, ..header() }), "x.vdt: corrupt VDT file: header: 2 nodes for 3 leaves");
        assert_eq!(
            err(VdtHeader { base_triangles: 2, ..header() }),
            "x.vdt: corrupt VDT file: header: 2 base triangles of 1"
        );
        let mut b = header().encode();
        b.put_u32(12, 7);
        b.seal();
        assert_eq!(
            decode(&b.0, header().file_bytes()).unwrap_err().to_string(),
            "x.vdt: corrupt VDT file: header: unknown metric code 7"
        );
    }
}
