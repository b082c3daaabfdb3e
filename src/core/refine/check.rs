//! Proof that a refined strip is a conforming mesh: decodes the strip into triangles and checks,
//! independently of how it was produced, that it tiles the grid square without cracks.
//!
//! - every triangle is wound clockwise seen from above (the strip's parity is right);
//! - every edge is shared by exactly two triangles, except edges on the grid border (one);
//! - the triangle areas sum to the square's area (no overlaps, no holes);
//! - no edge has a mesh vertex at its midpoint (no T-junction);
//! - against the refinement's own active test: every inserted vertex is active and no triangle
//!   edge has an active midpoint (the mesh is exactly the refinement of the active set).

use std::collections::{HashMap, HashSet};

use serde::Serialize;

use crate::layout::hierarchy::Grid;
use crate::refine::{Strip, StripVertex};

/// What [`check_strip`] found.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct MeshCheck {
    /// No bad edge, no wrong winding, areas sum to the square.
    pub crack_free: bool,
    /// Edges shared by other than two triangles (one, on the border), plus T-junction edges and
    /// edges with an active midpoint.
    pub edge_errors: u64,
    pub unmatched_edges: u64,
    pub t_junctions: u64,
    pub active_midpoints: u64,
    /// Triangles wound counter-clockwise or collinear.
    pub winding_errors: u64,
    pub area_ok: bool,
    /// Inserted mesh vertices that the active test calls inactive.
    pub inactive_vertices: u64,
    pub triangles: u64,
}

/// Checks `strip` as a mesh of `grid`. `is_active(x, y)` is the refinement's active test for a
/// non-corner, non-centre vertex.
pub fn check_strip(grid: Grid, strip: &Strip, is_active: impl Fn(u32, u32) -> bool) -> MeshCheck {
    let m = grid.max_coord();
    let key = |a: StripVertex, b: StripVertex| if a <= b { (a, b) } else { (b, a) };
    let mut edges: HashMap<(StripVertex, StripVertex), u32> = HashMap::new();
    let mut vertices: HashSet<StripVertex> = HashSet::new();
    let mut report = MeshCheck::default();
    let mut twice_area: u128 = 0;
    for [a, b, c] in strip.triangles() {
        report.triangles += 1;
        let cross = (b.x as i64 - a.x as i64) * (c.y as i64 - a.y as i64)
            - (b.y as i64 - a.y as i64) * (c.x as i64 - a.x as i64);
        if cross >= 0 {
            report.winding_errors += 1;
        }
        twice_area += cross.unsigned_abs() as u128;
        for (p, q) in [(a, b), (b, c), (c, a)] {
            *edges.entry(key(p, q)).or_insert(0) += 1;
        }
        vertices.extend([a, b, c]);
    }
    let on_border = |a: StripVertex, b: StripVertex| {
        (a.x == 0 && b.x == 0) || (a.y == 0 && b.y == 0) || (a.x == m && b.x == m) || (a.y == m && b.y == m)
    };
    for (&(a, b), &count) in &edges {
        let ok = count == 2 || (count == 1 && on_border(a, b));
        if !ok {
            report.unmatched_edges += 1;
        }
        let (sx, sy) = (a.x as u64 + b.x as u64, a.y as u64 + b.y as u64);
        if sx % 2 == 0 && sy % 2 == 0 {
            let mid = StripVertex { x: (sx / 2) as u32, y: (sy / 2) as u32 };
            if vertices.contains(&mid) {
                report.t_junctions += 1;
            } else if is_active(mid.x, mid.y) {
                report.active_midpoints += 1;
            }
        }
    }
    report.edge_errors = report.unmatched_edges + report.t_junctions + report.active_midpoints;
    let (cx, cy) = grid.centre();
    for v in &vertices {
        let corner = (v.x == 0 || v.x == m) && (v.y == 0 || v.y == m);
        if !corner && (v.x, v.y) != (cx, cy) && !is_active(v.x, v.y) {
            report.inactive_vertices += 1;
        }
    }
    report.area_ok = twice_area == 2 * (m as u128) * (m as u128);
    report.crack_free = report.edge_errors == 0 && report.winding_errors == 0 && report.area_ok;
    report
}

#[cfg(test)]
mod tests {
    use super::*;

    fn strip(v: &[(u32, u32)]) -> Strip {
        Strip::from_vertices(v.iter().map(|&(x, y)| StripVertex { x, y }).collect())
    }

    #[test]
    fn detects_a_t_junction_that_keeps_the_area() {
        let g = Grid::new(1).unwrap();
        let (sw, se, ne, nw, c) = ((0, 0), (2, 0), (2, 2), (0, 2), (1, 1));
        // Lower-right root triangle split at the centre, upper-left one not: c sits on sw–ne.
        let r = check_strip(g, &strip(&[sw, c, se, ne, ne, sw, sw, nw, ne]), |_, _| false);
        assert_eq!(r.triangles, 3);
        assert!(r.area_ok);
        assert_eq!(r.winding_errors, 0);
        assert_eq!(r.t_junctions, 1);
        assert_eq!(r.unmatched_edges, 3);
        assert!(!r.crack_free);
        // The four root triangles around the centre are conforming.
        let ok = check_strip(g, &strip(&[sw, sw, sw, c, se, c, ne, c, nw, sw]), |_, _| false);
        assert!(ok.crack_free && ok.triangles == 4, "{ok:?}");
        // ...unless the test says an edge midpoint should have been inserted.
        let active_s = check_strip(g, &strip(&[sw, sw, sw, c, se, c, ne, c, nw, sw]), |x, y| (x, y) == (1, 0));
        assert_eq!(active_s.active_midpoints, 1);
        assert!(!active_s.crack_free);
    }

    #[test]
    fn detects_wrong_winding_and_holes() {
        let g = Grid::new(1).unwrap();
        let (sw, se, ne, c) = ((0, 0), (2, 0), (2, 2), (1, 1));
        let r = check_strip(g, &strip(&[sw, se, c]), |_, _| false);
        assert_eq!(r.winding_errors, 1);
        assert!(!r.area_ok && !r.crack_free);
        let r = check_strip(g, &strip(&[sw, c, se, ne]), |_, _| false);
        assert_eq!(r.winding_errors, 0);
        assert!(!r.area_ok && r.unmatched_edges > 0);
    }
}
