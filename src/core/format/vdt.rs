//! The VDT file (view-dependence forest, El-Sana & Chiang 2000, §3.1; layout in [`super`]): its
//! header, the writer used by [`super::build`], and a validated, memory-mapped reader.
//!
//! [`VdtFile::open`] checks the magic, the version, the metric, the counts against each other and
//! the exact file length against the counts, then every node record (children below the node,
//! parent above it, triangle ranges inside the section, leaf counts) and every triangle corner.
//! After that, ids read from the file can be used as indices without further checks of their
//! range. A bad file gives one error line naming the file and the problem.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

use memmap2::Mmap;
use serde::Serialize;

use crate::error::{Error, IoContext, Result};
use crate::mesh::Bounds;
use crate::metanode::{VdtNode, VdtTriangle, NONE};

/// The file's first 8 bytes.
pub const MAGIC: [u8; 8] = *b"\x89RLFVDT\n";
/// The version this build writes and reads.
pub const VERSION: u32 = 1;
/// Bytes before the node records.
pub const HEADER_BYTES: usize = 128;
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

    /// The 128 header bytes.
    pub fn encode(&self) -> [u8; HEADER_BYTES] {
        let mut b = [0u8; HEADER_BYTES];
        b[0..8].copy_from_slice(&MAGIC);
        b[8..12].copy_from_slice(&VERSION.to_le_bytes());
        b[12..16].copy_from_slice(&(self.metric as u32).to_le_bytes());
        b[16..24].copy_from_slice(&self.leaves.to_le_bytes());
        b[24..32].copy_from_slice(&self.nodes.to_le_bytes());
        b[32..40].copy_from_slice(&self.triangles.to_le_bytes());
        b[40..48].copy_from_slice(&self.base_triangles.to_le_bytes());
        for k in 0..3 {
            b[48 + 8 * k..56 + 8 * k].copy_from_slice(&self.bounds.min[k].to_le_bytes());
            b[72 + 8 * k..80 + 8 * k].copy_from_slice(&self.bounds.max[k].to_le_bytes());
        }
        b
    }

    /// Decodes and checks a header against the file's length; errors name `path`.
    pub fn decode(path: &Path, head: &[u8], file_len: u64) -> Result<VdtHeader> {
        let bad = |problem: String| Error::BadVdt { path: path.into(), problem };
        if head.len() < 8 || head[0..8] != MAGIC {
            return Err(bad("not a VDT file (bad magic)".into()));
        }
        if head.len() < HEADER_BYTES {
            return Err(Error::Truncated { path: path.into(), expected: HEADER_BYTES as u64, found: file_len });
        }
        let u32_at = |o: usize| u32::from_le_bytes(head[o..o + 4].try_into().unwrap_or_default());
        let u64_at = |o: usize| u64::from_le_bytes(head[o..o + 8].try_into().unwrap_or_default());
        let f64_at = |o: usize| f64::from_le_bytes(head[o..o + 8].try_into().unwrap_or_default());
        let version = u32_at(8);
        if version != VERSION {
            return Err(bad(format!("VDT version {version} is not supported (this build reads version {VERSION})")));
        }
        let metric =
            VdtMetric::from_code(u32_at(12)).ok_or_else(|| bad(format!("unknown metric code {}", u32_at(12))))?;
        let (leaves, nodes, triangles, base_triangles) = (u64_at(16), u64_at(24), u64_at(32), u64_at(40));
        if nodes < leaves || nodes >= NONE as u64 {
            return Err(bad(format!("corrupt header: {nodes} nodes for {leaves} leaves")));
        }
        if nodes > (2 * leaves).saturating_sub(1) {
            return Err(bad(format!(
                "corrupt header: {nodes} nodes is more than a binary forest on {leaves} leaves has"
            )));
        }
        if base_triangles > triangles || triangles >= NONE as u64 {
            return Err(bad(format!("corrupt header: {base_triangles} base triangles of {triangles}")));
        }
        let bounds = Bounds { min: [f64_at(48), f64_at(56), f64_at(64)], max: [f64_at(72), f64_at(80), f64_at(88)] };
        if bounds.min.iter().chain(&bounds.max).any(|c| !c.is_finite()) {
            return Err(bad("corrupt header: non-finite bounding box".into()));
        }
        let header = VdtHeader { metric, leaves, nodes, triangles, base_triangles, bounds };
        let expected = header.file_bytes();
        if file_len < expected {
            return Err(Error::Truncated { path: path.into(), expected, found: file_len });
        }
        if file_len > expected {
            return Err(bad(format!(
                "{} bytes after the triangle section (expected {expected} bytes in all)",
                file_len - expected
            )));
        }
        Ok(header)
    }
}

/// Writes a whole VDT file's header; the caller then writes `nodes` node records and `triangles`
/// triangle records (see [`super::build`], which assembles the file atomically).
pub fn write_header(w: &mut impl Write, header: &VdtHeader) -> std::io::Result<()> {
    w.write_all(&header.encode())
}

/// A validated VDT file, mapped read-only.
pub struct VdtFile {
    path: PathBuf,
    header: VdtHeader,
    _file: File,
    map: Mmap,
}

impl VdtFile {
    /// Opens and validates a VDT file (see the module docs for what is checked).
    pub fn open(path: &Path) -> Result<VdtFile> {
        let file = File::open(path).at(path)?;
        let file_len = file.metadata().at(path)?.len();
        let mut head = vec![0u8; (HEADER_BYTES as u64).min(file_len) as usize];
        {
            use std::io::Read;
            (&file).read_exact(&mut head).at(path)?;
        }
        let header = VdtHeader::decode(path, &head, file_len)?;
        let map = crate::pager::source::map_read_only(path, &file, file_len)?;
        let vdt = VdtFile { path: path.to_path_buf(), header, _file: file, map };
        vdt.check_records()?;
        Ok(vdt)
    }

    /// Every node's links, counts and triangle range, and every triangle's corners, against the
    /// header (one pass over the file).
    fn check_records(&self) -> Result<()> {
        let bad = |problem: String| Error::BadVdt { path: self.path.clone(), problem };
        let leaves = self.header.leaves as u32;
        let nodes = self.nodes();
        let dying = self.header.triangles - self.header.base_triangles;
        let mut next_tri = 0u64;
        for (id, n) in nodes.iter().enumerate() {
            let id = id as u32;
            let parent_ok = n.parent == NONE || (n.parent > id && (n.parent as usize) < nodes.len());
            if !parent_ok {
                return Err(bad(format!("node {id}: parent {} is not a later node", n.parent)));
            }
            if id < leaves {
                if n.children != [NONE, NONE] || n.leaves != 1 || n.tri_count != 0 {
                    return Err(bad(format!("leaf {id}: has children, triangles or a leaf count other than 1")));
                }
                continue;
            }
            let [c0, c1] = n.children;
            if c0 >= id || c1 >= id || c0 == c1 {
                return Err(bad(format!("node {id}: children {c0}, {c1} are not two earlier nodes")));
            }
            let sum = nodes[c0 as usize].leaves as u64 + nodes[c1 as usize].leaves as u64;
            if n.leaves as u64 != sum {
                return Err(bad(format!("node {id}: {} leaves, its children have {sum}", n.leaves)));
            }
            if n.tri_start as u64 != next_tri || next_tri + n.tri_count as u64 > dying {
                return Err(bad(format!(
                    "node {id}: triangles {}..+{} do not follow the previous node's in the section",
                    n.tri_start, n.tri_count
                )));
            }
            next_tri += n.tri_count as u64;
        }
        if next_tri != dying {
            return Err(bad(format!("the nodes' triangle ranges cover {next_tri} of {dying} non-base triangles")));
        }
        if let Some((k, t)) = self.triangles().iter().enumerate().find(|(_, t)| t.corners.iter().any(|&c| c >= leaves))
        {
            return Err(bad(format!("triangle {k}: corner out of range {:?} ({leaves} leaves)", t.corners)));
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
        bytemuck::cast_slice(&self.map[start..end])
    }

    /// Every triangle record: grouped by m(t) in increasing node id, then the base triangles.
    pub fn triangles(&self) -> &[VdtTriangle] {
        let start = HEADER_BYTES + self.header.nodes as usize * NODE_BYTES;
        let end = start + self.header.triangles as usize * TRIANGLE_BYTES;
        bytemuck::cast_slice(&self.map[start..end])
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

    #[test]
    fn header_round_trips_and_sizes_the_file() {
        let h = header();
        let bytes = h.encode();
        assert_eq!(&bytes[..8], &MAGIC);
        assert_eq!(h.file_bytes(), 128 + 5 * 48 + 12);
        assert_eq!(VdtHeader::decode(Path::new("x.vdt"), &bytes, h.file_bytes()).unwrap(), h);
    }

    #[test]
    fn inconsistent_headers_are_refused() {
        let p = Path::new("x.vdt");
        let err = |h: VdtHeader| VdtHeader::decode(p, &h.encode(), h.file_bytes()).unwrap_err().to_string();
        assert_eq!(
            err(VdtHeader { nodes: 6, ..header() }),
            "x.vdt: corrupt header: 6 nodes is more than a binary forest on 3 leaves has"
        );
        assert_eq!(err(VdtHeader { nodes: 2, ..header() }), "x.vdt: corrupt header: 2 nodes for 3 leaves");
        assert_eq!(err(VdtHeader { base_triangles: 2, ..header() }), "x.vdt: corrupt header: 2 base triangles of 1");
        let mut b = header().encode();
        b[12] = 7;
        assert_eq!(
            VdtHeader::decode(p, &b, header().file_bytes()).unwrap_err().to_string(),
            "x.vdt: unknown metric code 7"
        );
    }
}
