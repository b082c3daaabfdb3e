//! `interleaved`: interleaved quadtrees, Lindstrom & Pascucci, *Visualization of Large Terrains
//! Made Easy* (2001), §5, as in the authors' SOAR code.
//!
//! The non-corner vertices form two quadtrees. The **white** tree holds the square centres: the
//! root is the grid centre `c`, and a centre at step `h` has the four centres at step `h/2` around
//! it as children, digit `k` = 0 south-west `(−,−)`, 1 south-east `(+,−)`, 2 north-east `(+,+)`,
//! 3 north-west `(−,+)` (offsets `(±h/2, ±h/2)`). The **black** tree holds the edge midpoints: an
//! edge midpoint at step `h` has the four edge midpoints at step `h/2` along the axes as children,
//! digit 0 north `(0,+)`, 1 east `(+,0)`, 2 south `(0,−)`, 3 west `(−,0)`. It is a quadtree rotated
//! by 45°; its children that fall outside the grid are *ghosts* (unused slots, as are their whole
//! subtrees). Both trees share one index space in which child `k` of node `p` is `4p − 7 + k`:
//!
//! ```text
//! 0..3   corners sw, se, ne, nw          4      c (white level 1)
//! 5..8   w, s, e, n (black level 1, as children of a virtual node 3)
//! 9..12  white level 2 (children of 4)   13..28 black level 2 (children of 5..8)
//! 29..44 white level 3                   45..108 black level 3   …
//! ```
//!
//! White level `k` (step `h = N/2^k`, `4^(k−1)` nodes) starts at `W(k) = 4 + 5·(4^(k−1) − 1)/3`
//! and black level `k` (`4^k` slots) right after it; the levels thus run strictly coarse to fine.
//! Records = `4 + 5·(4^n − 1)/3`, about 2/3 more than the `(2^n + 1)²` vertices.
//!
//! **Offsets within a level** are Morton codes of the child path. For a white node at step
//! `h = 2^t`, `x = h·(2X + 1)` and `y = h·(2Y + 1)` where the bits of `X` (`Y`) are the east
//! (north) choices along the path, most significant first; a digit's high bit is the `y` choice
//! and its low bit the `x` choice XOR the `y` choice, so the offset is `morton(X ^ Y, Y)` (the
//! first operand in the even bits). For a black node at step `h` take the rotated coordinates
//! `U = x + y` and `V = x − y + N` (both odd multiples of `h` in `(0, 2N)`), `P = U >> (t+1)`,
//! `Q = V >> (t+1)` (`k`-bit numbers). The top digit picks the level-1 node (w, s, e, n = 0..3,
//! the quadrants `(P, Q)` high bits `00, 01, 11, 10`), the others the axis-aligned children;
//! both cases reduce to the white formula with `Y = P' = P ^ (2^(k−1) − 1)` (`P` with its low
//! `k − 1` bits inverted) and `X = Q`: offset `morton(Q ^ P', P')`.
//!
//! **Children during refinement** (SOAR's `submesh_refine(i, j)`, apex `i`, split vertex `j`): the
//! two DAG children of `j` on `i`'s side are quadtree children of `i`, left first
//! `4i − 7 + ((2i + j + 2) & 3)`, then `4i − 7 + ((2i + j + 3) & 3)`: pure index arithmetic.

use super::{morton, Layout, LayoutKind, Vertex};
use crate::layout::hierarchy::{split_children, Grid};

#[derive(Clone, Debug)]
pub struct Interleaved {
    grid: Grid,
    records: u64,
}

impl Interleaved {
    pub fn new(grid: Grid) -> Self {
        Interleaved { grid, records: 4 + 5 * morton::quad_sum(grid.n()) }
    }
}

/// Corner index 0..3 (sw, se, ne, nw) of a corner position (the white digit convention).
#[inline(always)]
pub(crate) fn corner_index(x: u32, y: u32) -> u64 {
    let (east, north) = ((x != 0) as u64, (y != 0) as u64);
    2 * north + (east ^ north)
}

/// Position of corner `i` (0..3) in a grid with maximum coordinate `m`.
#[inline(always)]
pub(crate) fn corner_coords(i: u64, m: u32) -> (u32, u32) {
    let north = (i >> 1) as u32;
    let east = (i as u32 ^ north) & 1;
    (east * m, north * m)
}

/// Whether the non-corner position `(x, y)` with step `2^t` is white (a square centre), and its
/// offset within its white or black level `k = n − t` (see the module docs).
///
/// Both cases are `morton(X ^ Y, Y)`: white `X = x >> (t+1)`, `Y = y >> (t+1)`; black
/// `X = (x − y + N) >> (t+1)`, `Y = ((x + y) >> (t+1)) ^ (2^(k−1) − 1)`. The operands are selected
/// without branching, since white and black vertices alternate unpredictably.
#[inline(always)]
pub(crate) fn level_offset(x: u32, y: u32, t: u32, n: u32) -> (bool, u64) {
    let white = (x >> t) & (y >> t) & 1 == 1;
    let (x, y) = (x as u64, y as u64);
    let low = (1u64 << (n - t - 1)) - 1;
    let (a, b, flip) = if white { (x, y, 0) } else { (x + (1u64 << n) - y, x + y, low) };
    let (xs, ys) = ((a >> (t + 1)) as u32, ((b >> (t + 1)) ^ flip) as u32);
    (white, morton::encode(xs ^ ys, ys))
}

/// Inverse of [`level_offset`] for a white node.
#[inline(always)]
pub(crate) fn white_coords(offset: u64, t: u32) -> (u32, u32) {
    let (a, by) = morton::decode(offset);
    let bx = a ^ by;
    (((2 * bx as u64 + 1) << t) as u32, ((2 * by as u64 + 1) << t) as u32)
}

/// Inverse of [`level_offset`] for a black node; `None` for a ghost.
#[inline(always)]
pub(crate) fn black_coords(offset: u64, t: u32, n: u32) -> Option<(u32, u32)> {
    let k = n - t;
    let (a, p) = morton::decode(offset);
    let q = a ^ p;
    let p = p ^ ((1u32 << (k - 1)) - 1);
    let u = ((2 * p as i64) + 1) << t;
    let v = ((2 * q as i64) + 1) << t;
    let m = 1i64 << n;
    // x = (u + v − N) / 2, y = (u − v + N) / 2; both sums are even below the top level.
    let (x, y) = ((u + v - m) >> 1, (u - v + m) >> 1);
    ((0..=m).contains(&x) && (0..=m).contains(&y)).then_some((x as u32, y as u32))
}

impl Layout for Interleaved {
    const PREFETCH_GRANDCHILDREN: bool = true;

    fn kind(&self) -> LayoutKind {
        LayoutKind::Interleaved
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
        // Level k = n − t: white level k starts at 4 + 5·(4^(k−1) − 1)/3, black level k 4^(k−1)
        // records later.
        let k1 = n - t - 1;
        let (white, offset) = level_offset(x, y, t, n);
        4 + 5 * morton::quad_sum(k1) + ((!white as u64) << (2 * k1)) + offset
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
        // Level k = j + 1 spans r in [5·(4^j − 1)/3, 5·(4^(j+1) − 1)/3); floor(log4 r) is j or j + 1.
        let mut j = (63 - r.leading_zeros()) / 2;
        if 5 * morton::quad_sum(j) > r {
            j -= 1;
        }
        let o = r - 5 * morton::quad_sum(j);
        let t = n - j - 1;
        let whites = 1u64 << (2 * j);
        if o < whites {
            Some(white_coords(o, t))
        } else {
            black_coords(o - whites, t, n)
        }
    }

    #[inline]
    fn split_children(&self, apex: Vertex, split: Vertex) -> [Vertex; 2] {
        if apex.index < 4 {
            return self.corner_split_children(apex, split);
        }
        quadtree_split_children(apex, split, 7)
    }

    #[inline(always)]
    fn inner_child_indices(&self, apex_index: u64, split_index: u64, _: (u32, u32), _: (u32, u32)) -> [u64; 2] {
        quadtree_child_indices(apex_index, split_index, 7)
    }

    #[inline(always)]
    fn quadtree_children(&self, index: u64) -> Option<u64> {
        // A hint only: wrapping, as an index without children gives no valid one.
        Some(index.wrapping_mul(4).wrapping_sub(7))
    }
}

/// SOAR's child rule, shared by the quadtree layouts in which child `k` of node `p` sits at
/// `4p − back + k` (`back` = 7 interleaved, 11 embedded): the two DAG children of `split` on
/// `apex`'s side are `4i − back + ((2i + j + 2) & 3)` and `… + ((2i + j + 3) & 3)`.
#[inline(always)]
pub(crate) fn quadtree_split_children(apex: Vertex, split: Vertex, back: u64) -> [Vertex; 2] {
    let [l, r] = split_children((apex.x, apex.y), (split.x, split.y));
    let [li, ri] = quadtree_child_indices(apex.index, split.index, back);
    [Vertex { x: l.0, y: l.1, index: li }, Vertex { x: r.0, y: r.1, index: ri }]
}

/// The indices of [`quadtree_split_children`].
#[inline(always)]
pub(crate) fn quadtree_child_indices(apex_index: u64, split_index: u64, back: u64) -> [u64; 2] {
    let base = (4 * apex_index).wrapping_sub(back);
    let s = 2 * apex_index + split_index;
    [base + ((s + 2) & 3), base + ((s + 3) & 3)]
}

impl Interleaved {
    /// [`Layout::split_children`] for a corner apex (only the two initial triangles, split at the
    /// centre): no quadtree shortcut, go through coordinates.
    #[cold]
    #[inline(never)]
    fn corner_split_children(&self, apex: Vertex, split: Vertex) -> [Vertex; 2] {
        let [l, r] = split_children((apex.x, apex.y), (split.x, split.y));
        [self.vertex(l.0, l.1), self.vertex(r.0, r.1)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_indices_small_grid() {
        let g = Grid::new(3).unwrap();
        let l = Interleaved::new(g);
        let [sw, se, ne, nw] = g.corners();
        let [w, s, e, n] = g.edge_midpoints();
        let ids: Vec<u64> = [sw, se, ne, nw, g.centre(), w, s, e, n].iter().map(|&(x, y)| l.index(x, y)).collect();
        assert_eq!(ids, (0..9).collect::<Vec<_>>());
        // White level 2: sw, se, ne, nw centres.
        assert_eq!(l.index(2, 2), 9);
        assert_eq!(l.index(6, 2), 10);
        assert_eq!(l.index(6, 6), 11);
        assert_eq!(l.index(2, 6), 12);
        // Black level 2: children of s (6) are 17..20 = north, east, south (ghost), west.
        assert_eq!(l.index(4, 2), 17);
        assert_eq!(l.index(6, 0), 18);
        assert_eq!(l.coords(19), None);
        assert_eq!(l.index(2, 0), 20);
        assert_eq!(l.records(), 4 + 5 * 21);
    }

    /// Child `k` of every node `p` sits at `4p − 7 + k`, in the documented directions.
    #[test]
    fn quadtree_children_follow_direction_conventions() {
        for n in 1..=6 {
            let g = Grid::new(n).unwrap();
            let l = Interleaved::new(g);
            let m = g.max_coord() as i64;
            // The virtual node 3 has the black level-1 nodes w, s, e, n as children.
            for (k, &(x, y)) in g.edge_midpoints().iter().enumerate() {
                assert_eq!(l.coords(5 + k as u64), Some((x, y)));
            }
            for p in 4..l.records() {
                let Some((x, y)) = l.coords(p) else { continue };
                let (x, y) = (x as i64, y as i64);
                let dirs: [(i64, i64); 4] = match g.kind(x as u32, y as u32) {
                    crate::layout::hierarchy::VertexKind::SquareCentre { .. } => [(-1, -1), (1, -1), (1, 1), (-1, 1)],
                    _ => [(0, 1), (1, 0), (0, -1), (-1, 0)],
                };
                let h = 1i64 << (x | y).trailing_zeros();
                if h == 1 {
                    assert!(4 * p - 7 >= l.records());
                    continue;
                }
                for (k, (dx, dy)) in dirs.into_iter().enumerate() {
                    let (cx, cy) = (x + dx * h / 2, y + dy * h / 2);
                    let inside = (0..=m).contains(&cx) && (0..=m).contains(&cy);
                    let got = l.coords(4 * p - 7 + k as u64);
                    assert_eq!(got, inside.then_some((cx as u32, cy as u32)), "n={n} p={p} k={k}");
                }
            }
        }
    }
}
