//! The minimal mesh for a view and tolerance, as the reference the nested top-down mesh is measured
//! against (Lindstrom & Pascucci 2001, §7): the DAG closure of the vertices whose own, un-nested
//! error projects over τ (and, with culling on, whose own position is in the frustum).
//!
//! Every such vertex is also active in the nested test (its nested error and sphere contain its own
//! error and position), and the nested active set is closed, so the minimal set is a subset of the
//! vertices of the refined strip: only those are examined, and the work is proportional to the
//! output, not to the grid.

use std::collections::HashSet;

use serde::Serialize;

use crate::layout::{Layout, Stored};
use crate::lod::metric::ErrorMetric;
use crate::preprocess::raw_error;
use crate::refine::{mesh_triangles, RecordSource, Strip, View};

/// Size of the minimal mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct MinimalMesh {
    /// Inserted vertices (centre included, corners not).
    pub vertices: u64,
    pub triangles: u64,
}

/// The minimal mesh for `view`, found among the vertices of `nested` (a strip refined for the same
/// view and tolerance), over the `stored` vertices.
pub fn minimal_mesh<L: Layout, R: RecordSource + ?Sized, M: ErrorMetric>(
    layout: &L,
    stored: &Stored,
    records: &R,
    view: &View<M>,
    nested: &Strip,
) -> MinimalMesh {
    let grid = layout.grid();
    let m = grid.max_coord();
    let centre = grid.centre();
    let mut candidates: Vec<(u32, u32, u32)> = nested
        .vertices
        .iter()
        // Corners are not inserted; null vertices (padding without data below, see `Stored`)
        // have no error of their own.
        .filter(|v| !((v.x == 0 || v.x == m) && (v.y == 0 || v.y == m)) && stored.contains(v.x, v.y))
        .map(|v| (grid.level(v.x, v.y), v.x, v.y))
        .collect();
    candidates.sort_unstable();
    candidates.dedup();
    let z = |x: u32, y: u32| records.record(layout.index(x, y)).z;
    // Finest level first: a vertex is in the closure if it is a seed or one of its DAG children is.
    let mut closure: HashSet<(u32, u32)> = HashSet::with_capacity(candidates.len());
    for &(_, x, y) in &candidates {
        let keep = (x, y) == centre || {
            let [a, b] = grid.split_edge(x, y).expect("not a corner");
            let zv = z(x, y);
            let p = view.position(x, y, zv);
            (view.point_in_frustum(p) && view.error_projects_over(p, raw_error(zv, z(a.0, a.1), z(b.0, b.1)))) || {
                let (children, count) = grid.dag_children(x, y);
                children[..count].iter().any(|c| closure.contains(c))
            }
        };
        if keep {
            closure.insert((x, y));
        }
    }
    MinimalMesh { vertices: closure.len() as u64, triangles: mesh_triangles(grid, closure.iter().copied()) }
}
