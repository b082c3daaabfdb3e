//! `embedded`: the single-quadtree variant of the interleaved layout (Lindstrom & Pascucci 2001,
//! §5): the white quadtree (square centres) is stored in unused ghost slots of the black one
//! (edge midpoints), which roughly halves the waste of [`super::Interleaved`].
//!
//! There is one quadtree with root `c = 4` and child `k` of node `p` at `4p − 11 + k`; corners
//! take 0..3. Tree level `k` (`4^k` slots) starts at `E(k) = 4 + (4^k − 1)/3`:
//!
//! - level 1 (5..8) holds the black level-1 nodes w, s, e, n (the root's children);
//! - from there the black tree continues with the black direction convention of the interleaved
//!   layout (children north, east, south, west), so black level `k` sits at tree level `k` with
//!   the same within-level offset as in the interleaved layout;
//! - black level 2 has exactly four ghosts: the west child of w (slot 12), the south child of s
//!   (15), the east child of e (18) and the north child of n (21). Their subtrees lie wholly
//!   outside the grid, and at tree level `k` they offer `4 · 4^(k−2) = 4^(k−1)` slots — exactly the
//!   size of white level `k`. The white level-2 centres go there, sw → 21, se → 18, ne → 15,
//!   nw → 12 (white digit `d` → slot prefix `(3 − d, d)`), and below them the white children follow
//!   `4p − 11 + k` with the white direction convention (sw, se, ne, nw). So white level `k` sits at
//!   tree level `k` with offset `(3 − d)·4^(k−1) + o`, where `o` is its interleaved offset and `d`
//!   that offset's top digit.
//!
//! Every node's index is congruent mod 4 to its interleaved index (both level starts are ≡ 1 and
//! the last digit is the same), and child `k` of a node is the same vertex in both layouts. Hence
//! SOAR's child rule carries over: for an apex `i ≠ 4` and split vertex `j`, the children are
//! `4i − 11 + ((2i + j + 2) & 3)` and `4i − 11 + ((2i + j + 3) & 3)`; for `i = c = 4` they are white
//! level-2 centres, white digit `d = (j + 2) & 3` resp. `(j + 3) & 3` at slot `21 − 3d`.
//!
//! Records = `4 + (4^(n+1) − 1)/3 = 5 + 4·(4^n − 1)/3`, about 1/3 more than the vertices (the
//! remaining black ghosts outside the four white subtrees stay unused). Tree level `k` holds the
//! refinement levels `2(n − k) + 1` and `2(n − k) + 2`, so the file is coarse to fine up to that
//! pairing.

use super::interleaved::{
    black_coords, corner_coords, corner_index, level_offset, quadtree_child_indices, quadtree_split_children,
    white_coords,
};
use super::{morton, Layout, LayoutKind, Vertex};
use crate::layout::hierarchy::{split_children, Grid};

#[derive(Clone, Debug)]
pub struct Embedded {
    grid: Grid,
    records: u64,
}

impl Embedded {
    pub fn new(grid: Grid) -> Self {
        Embedded { grid, records: 4 + morton::quad_sum(grid.n() + 1) }
    }
}

impl Layout for Embedded {
    const PREFETCH_GRANDCHILDREN: bool = true;

    fn kind(&self) -> LayoutKind {
        LayoutKind::Embedded
    }
    fn grid(&self) -> Grid {
        self.grid
    }
    fn records(&self) -> u64 {
        self.records
    }

    #[inline]
    fn index(&self, x: u32, y: u32) -> u64 {
        let n = self.grid.n();
        let t = (x | y).trailing_zeros();
        if t >= n {
            return corner_index(x, y);
        }
        let k = n - t;
        let (white, o) = level_offset(x, y, t, n);
        if white && k == 1 {
            return 4;
        }
        // A white node at level k >= 2 goes into the ghost subtree with prefix (3 − d, d), d its
        // top digit: add (3 − d)·4^(k−1). Computed for black nodes too (hence the wrapping
        // arithmetic; the value is then discarded) so that the selection needs no branch.
        let d = o >> ((2 * k).wrapping_sub(4) & 63);
        let lift = 3u64.wrapping_sub(d) << (2 * (k - 1));
        4 + morton::quad_sum(k) + o + if white { lift } else { 0 }
    }

    #[inline]
    fn coords(&self, index: u64) -> Option<(u32, u32)> {
        let n = self.grid.n();
        if index < 4 {
            return Some(corner_coords(index, 1 << n));
        }
        if index >= self.records {
            return None;
        }
        let r = index - 4;
        if r == 0 {
            return Some(self.grid.centre());
        }
        // Tree level k spans r in [(4^k − 1)/3, (4^(k+1) − 1)/3); floor(log4 r) is k − 1 or k.
        let mut k = (63 - r.leading_zeros()) / 2 + 1;
        if morton::quad_sum(k) > r {
            k -= 1;
        }
        let o = r - morton::quad_sum(k);
        let t = n - k;
        if k >= 2 {
            let d1 = o >> (2 * (k - 1));
            let d2 = (o >> (2 * (k - 2))) & 3;
            if d1 + d2 == 3 {
                // Inside one of the four ghost subtrees of black level 2: a white node.
                return Some(white_coords(o & ((1u64 << (2 * (k - 1))) - 1), t));
            }
        }
        black_coords(o, t, n)
    }

    #[inline]
    fn split_children(&self, apex: Vertex, split: Vertex) -> [Vertex; 2] {
        if apex.index <= 4 {
            return self.root_split_children(apex, split);
        }
        quadtree_split_children(apex, split, 11)
    }

    #[inline(always)]
    fn inner_child_indices(&self, apex_index: u64, split_index: u64, _: (u32, u32), _: (u32, u32)) -> [u64; 2] {
        quadtree_child_indices(apex_index, split_index, 11)
    }

    #[inline(always)]
    fn quadtree_children(&self, index: u64) -> Option<u64> {
        // A hint only: wrapping, as an index without children gives no valid one.
        Some(index.wrapping_mul(4).wrapping_sub(11))
    }
}

impl Embedded {
    /// [`Layout::split_children`] for the apexes without the quadtree rule: the centre, whose
    /// children (the white level-2 centres, white digit `d` at slot `21 − 3d`) are not its
    /// quadtree children, and the corners of the two initial triangles.
    #[cold]
    #[inline(never)]
    fn root_split_children(&self, apex: Vertex, split: Vertex) -> [Vertex; 2] {
        let [l, r] = split_children((apex.x, apex.y), (split.x, split.y));
        if apex.index == 4 {
            let j = split.index;
            [
                Vertex { x: l.0, y: l.1, index: 21 - 3 * ((j + 2) & 3) },
                Vertex { x: r.0, y: r.1, index: 21 - 3 * ((j + 3) & 3) },
            ]
        } else {
            [self.vertex(l.0, l.1), self.vertex(r.0, r.1)]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::hierarchy::VertexKind;

    #[test]
    fn fixed_slots_small_grid() {
        let g = Grid::new(3).unwrap();
        let l = Embedded::new(g);
        let [w, s, e, n] = g.edge_midpoints();
        assert_eq!(l.index(g.centre().0, g.centre().1), 4);
        assert_eq!([w, s, e, n].map(|(x, y)| l.index(x, y)), [5, 6, 7, 8]);
        // White level 2 in the four black level-2 ghost slots.
        assert_eq!(l.index(2, 2), 21);
        assert_eq!(l.index(6, 2), 18);
        assert_eq!(l.index(6, 6), 15);
        assert_eq!(l.index(2, 6), 12);
        // Black level 2: children of s (6) are 13..16 = north, east, south (the white ne slot), west.
        assert_eq!(l.index(4, 2), 13);
        assert_eq!(l.index(6, 0), 14);
        assert_eq!(l.index(2, 0), 16);
        assert_eq!(l.records(), 4 + 85);
    }

    /// Child `k` of every node `p` is at `4p − 11 + k`, in the documented directions, and every
    /// node has the same index mod 4 as in the interleaved layout.
    #[test]
    fn quadtree_children_and_residues() {
        for n in 1..=6 {
            let g = Grid::new(n).unwrap();
            let l = Embedded::new(g);
            let il = super::super::Interleaved::new(g);
            let m = g.max_coord() as i64;
            for (k, &(x, y)) in g.edge_midpoints().iter().enumerate() {
                assert_eq!(l.coords(5 + k as u64), Some((x, y)));
            }
            for p in 4..l.records() {
                let Some((x, y)) = l.coords(p) else { continue };
                assert_eq!(p % 4, il.index(x, y) % 4, "residue of {x},{y}");
                if p == 4 {
                    continue;
                }
                let (x, y) = (x as i64, y as i64);
                let dirs: [(i64, i64); 4] = match g.kind(x as u32, y as u32) {
                    VertexKind::SquareCentre { .. } => [(-1, -1), (1, -1), (1, 1), (-1, 1)],
                    _ => [(0, 1), (1, 0), (0, -1), (-1, 0)],
                };
                let h = 1i64 << (x | y).trailing_zeros();
                if h == 1 {
                    assert!(4 * p - 11 >= l.records());
                    continue;
                }
                for (k, (dx, dy)) in dirs.into_iter().enumerate() {
                    let (cx, cy) = (x + dx * h / 2, y + dy * h / 2);
                    let inside = (0..=m).contains(&cx) && (0..=m).contains(&cy);
                    let got = l.coords(4 * p - 11 + k as u64);
                    if inside {
                        assert_eq!(got, Some((cx as u32, cy as u32)), "n={n} p={p} k={k}");
                    } else {
                        // Only black nodes have children outside the grid. Such a ghost slot
                        // holds a white node exactly in the four black level-2 ghost subtrees
                        // (so always for the children of w, s, e, n), else it is unused.
                        assert!(!matches!(g.kind(x as u32, y as u32), VertexKind::SquareCentre { .. }));
                        if let Some((wx, wy)) = got {
                            assert!(matches!(g.kind(wx, wy), VertexKind::SquareCentre { .. }));
                        } else {
                            assert!(p > 8, "n={n}: ghost child of level-1 node {p} must be white");
                        }
                    }
                }
            }
        }
    }
}
