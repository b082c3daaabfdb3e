//! View-dependence trees and meta-node trees for general meshes, out of core (El-Sana & Chiang,
//! *External Memory View-Dependent Simplification*, Eurographics 2000; ARCHITECTURE.md, "Meta-node trees").
//!
//! Pipeline (`relief mesh build`):
//! 1. [`build`]: spanned sub-mesh simplification. Edges live in a redb B-tree keyed by the
//!    collapse metric; connected components of the shortest edges are grown with union–find until
//!    the memory budget, collapsed in memory ([`simplify`]) up to the longest spanning edge ℓ, and
//!    the left-over edges go back. The result is a **VDT file** (below): the binary vertex
//!    hierarchy, node ids in collapse order.
//! 2. [`metanode`]: the forest blocked L levels at a time into page-sized meta-nodes (the
//!    **meta-node file**: DATA + MNT).
//! 3. [`navigate`]: run-time split/collapse against switch values with implicit dependencies,
//!    over a meta-node store: the buffer pool ([`crate::pager::pool`], "Ext") or the plain map ("Virt").
//!
//! # Node ids and the forest
//! Leaves are the input vertices, ids `0..leaves`. Each collapse of a vertex pair (a, b) creates a
//! parent p with the next id, so a parent's id exceeds its children's (the implicit dependencies
//! rely on this). p takes the position of `children[0]` (a half-edge collapse), so every node's
//! position is a leaf's. Nodes never collapsed are roots; there may be many (a forest).
//!
//! A triangle dies when two of its corners collapse into one node. That node is the deepest
//! pairwise lowest common ancestor of its three corner leaves, written `m(t)`: t is drawn iff
//! m(t) is split. Triangles that never die (m(t) = none) form the base mesh over the roots.
//!
//! # VDT file (little-endian, written by [`build`])
//! ```text
//! offset size  field
//!      0    8  magic "\x89RLFVDT\n"
//!      8    4  version (1)
//!     12    4  metric (0 length, 1 quadric)
//!     16    8  leaves (input vertices)
//!     24    8  nodes (leaves + collapses); node records are indexed by id
//!     32    8  triangles (input triangles kept, in the triangle section)
//!     40    8  base triangles (the last `base` entries of the triangle section: m(t) = none)
//!     48   24  bounding box min x, y, z (f64)
//!     72   24  bounding box max x, y, z (f64)
//!     96   32  reserved (0)
//!    128    -  node records, `nodes` × 48 bytes ([`VdtNode`]), in id order
//!      -    -  triangle records, `triangles` × 12 bytes ([`VdtTriangle`]): grouped by m(t) in
//!              increasing node id (node p's are `tri_start .. tri_start + tri_count`), then the
//!              base triangles
//! ```

pub mod blocking;
pub mod navigate;
pub mod source;

pub mod build;
pub mod collapse;
mod dense;
pub mod simplify;

pub use crate::format::vdt::{VdtFile, VdtHeader, VdtMetric, VdtNode, VdtTriangle, NONE};

/// The whole `relief mesh build` pipeline in one call: the VDT forest of `mesh` out of core
/// ([`build::build_vdt_from_mesh`]), then blocked into the meta-node file `output`
/// ([`blocking::write_metanode_file`]). The forest goes to `vdt` when given (kept), else to a
/// scratch directory beside `output` that is removed whatever happens.
pub fn build_tree(
    mesh: crate::mesh::Mesh,
    output: &std::path::Path,
    vdt: Option<&std::path::Path>,
    build: &build::BuildOptions,
    blocking_options: blocking::BlockingOptions,
) -> crate::Result<TreeReport> {
    use crate::error::Error;
    let dir = match output.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => std::path::PathBuf::from("."),
    };
    let scratch = tempfile::Builder::new().prefix(".relief-vdt.").tempdir_in(&dir).map_err(|e| Error::Scratch {
        path: dir.clone(),
        problem: format!("cannot create a scratch directory: {e}"),
    })?;
    let vdt_path = vdt.map_or_else(|| scratch.path().join("forest.vdt"), |p| p.to_path_buf());
    let vdt_report = build::build_vdt_from_mesh(mesh, &vdt_path, build)?;
    let forest_file = VdtFile::open(&vdt_path)?;
    let forest = blocking::Forest {
        nodes: forest_file.nodes(),
        triangles: forest_file.triangles(),
        base_triangles: forest_file.base_triangles().len(),
        leaves: forest_file.leaves() as u32,
        metric: forest_file.metric() as u32,
        bounds: forest_file.bounds(),
    };
    let metanode = blocking::write_metanode_file(&forest, blocking_options, output)?;
    Ok(TreeReport {
        vdt: vdt_report,
        metanode,
        levels_per_node: blocking_options.levels_per_node,
        page_bytes: blocking_options.page_bytes as u64,
    })
}

/// What [`build_tree`] did: the forest's build and the meta-node file's blocking.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TreeReport {
    #[serde(flatten)]
    pub vdt: build::BuildReport,
    pub metanode: blocking::MetaNodeReport,
    pub levels_per_node: u32,
    pub page_bytes: u64,
}
