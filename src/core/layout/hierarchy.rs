//! The longest-edge bisection hierarchy of a (2^n + 1)² grid, in grid coordinates.
//!
//! Lindstrom & Pascucci, *Visualization of Large Terrains Made Easy* (IEEE Visualization 2001), §3:
//! the square is split into four right triangles around its centre, and every triangle is split by
//! inserting the midpoint of its hypotenuse. Each inserted vertex is either
//! - a **square centre** at step `h` (both `x/h` and `y/h` odd): it bisects a diagonal of the square
//!   of side `2h` around it; refinement level `2·log2(h) + 2` (the grid centre has level `2n`), or
//! - an **edge midpoint** at step `h` (exactly one of `x/h`, `y/h` odd): it bisects an axis-aligned
//!   edge of length `2h`; refinement level `2·log2(h) + 1` (the finest vertices have level 1).
//!
//! The four corners are never inserted; they carry level `2n + 1` here so that "coarser" means
//! "larger level" everywhere. Coordinates: `x` grows east, `y` grows north, `(0, 0)` is the
//! south-west corner. Every function here is pure integer geometry; layouts and preprocessing build
//! on it, and the tests check them against each other.

/// Largest supported `n` (grid side `2^n + 1`): keeps coordinates in `u32` and every layout's index
/// space in `u64` (the interleaved layout needs about `5/3 · 4^n` records).
pub const MAX_N: u32 = 31;

/// A square grid of `(2^n + 1)²` vertices.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Grid {
    n: u32,
}

/// What kind of vertex a grid position is in the bisection hierarchy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VertexKind {
    Corner,
    /// Centre of a square of side `2·step`; bisects one of its diagonals.
    SquareCentre {
        step: u32,
    },
    /// Midpoint of an axis-aligned edge of length `2·step`.
    EdgeMidpoint {
        step: u32,
    },
}

impl Grid {
    /// A grid of side `2^n + 1`, `1 <= n <= MAX_N`.
    pub fn new(n: u32) -> Option<Grid> {
        (1..=MAX_N).contains(&n).then_some(Grid { n })
    }

    /// The smallest grid (n >= 1) whose side is at least `max(width, height)`; `None` if too large.
    pub fn covering(width: u64, height: u64) -> Option<Grid> {
        let need = width.max(height).max(2);
        let mut n = 1;
        while (1u64 << n) + 1 < need {
            n += 1;
            if n > MAX_N {
                return None;
            }
        }
        Grid::new(n)
    }

    /// `n`, with side `2^n + 1`.
    pub fn n(&self) -> u32 {
        self.n
    }

    /// Vertices per side, `2^n + 1`.
    pub fn size(&self) -> u32 {
        (1u32 << self.n) + 1
    }

    /// `2^n`: the largest coordinate.
    pub fn max_coord(&self) -> u32 {
        1u32 << self.n
    }

    /// Number of refinement levels, `2n` (levels `1..=2n`; corners are level `2n + 1`).
    pub fn levels(&self) -> u32 {
        2 * self.n
    }

    /// Number of grid vertices, `(2^n + 1)²`.
    pub fn vertices(&self) -> u64 {
        let s = self.size() as u64;
        s * s
    }

    pub fn contains(&self, x: i64, y: i64) -> bool {
        let m = self.max_coord() as i64;
        (0..=m).contains(&x) && (0..=m).contains(&y)
    }

    /// Corners in the order sw, se, ne, nw.
    pub fn corners(&self) -> [(u32, u32); 4] {
        let m = self.max_coord();
        [(0, 0), (m, 0), (m, m), (0, m)]
    }

    /// The grid centre (the first vertex inserted).
    pub fn centre(&self) -> (u32, u32) {
        let h = self.max_coord() / 2;
        (h, h)
    }

    /// Edge midpoints of the whole square in the order w, s, e, n.
    pub fn edge_midpoints(&self) -> [(u32, u32); 4] {
        let m = self.max_coord();
        let h = m / 2;
        [(0, h), (h, 0), (m, h), (h, m)]
    }

    /// Classifies a position (which must lie in the grid).
    pub fn kind(&self, x: u32, y: u32) -> VertexKind {
        debug_assert!(self.contains(x as i64, y as i64));
        let m = self.max_coord();
        if (x == 0 || x == m) && (y == 0 || y == m) {
            return VertexKind::Corner;
        }
        // x | y != 0 here, and its lowest set bit is the step.
        let step = 1u32 << (x | y).trailing_zeros();
        if (x / step) & 1 == 1 && (y / step) & 1 == 1 {
            VertexKind::SquareCentre { step }
        } else {
            VertexKind::EdgeMidpoint { step }
        }
    }

    /// Refinement level: 1 for the finest edge midpoints, `2n` for the centre, `2n + 1` for corners.
    pub fn level(&self, x: u32, y: u32) -> u32 {
        match self.kind(x, y) {
            VertexKind::Corner => 2 * self.n + 1,
            VertexKind::SquareCentre { step } => 2 * step.trailing_zeros() + 2,
            VertexKind::EdgeMidpoint { step } => 2 * step.trailing_zeros() + 1,
        }
    }

    /// End points of the edge that vertex `(x, y)` bisects (its raw error is measured against their
    /// mean). `None` for corners.
    pub fn split_edge(&self, x: u32, y: u32) -> Option<[(u32, u32); 2]> {
        match self.kind(x, y) {
            VertexKind::Corner => None,
            VertexKind::EdgeMidpoint { step } => {
                Some(if (x / step) & 1 == 1 { [(x - step, y), (x + step, y)] } else { [(x, y - step), (x, y + step)] })
            }
            VertexKind::SquareCentre { step } => {
                // In units of 2·step the square's corners are (a..=a+1, b..=b+1); the bisected
                // diagonal joins its both-even corner and its both-odd corner.
                let s2 = 2 * step;
                let (a, b) = ((x - step) / s2, (y - step) / s2);
                let even = (a + (a & 1), b + (b & 1));
                let odd = (a + 1 - (a & 1), b + 1 - (b & 1));
                Some([(even.0 * s2, even.1 * s2), (odd.0 * s2, odd.1 * s2)])
            }
        }
    }

    /// DAG parents (the apexes of the one or two triangles whose shared hypotenuse this vertex
    /// bisects). Returns the parents and their count; corners have none.
    pub fn dag_parents(&self, x: u32, y: u32) -> ([(u32, u32); 2], usize) {
        let mut out = [(0, 0); 2];
        let mut count = 0;
        let Some([a, b]) = self.split_edge(x, y) else {
            return (out, 0);
        };
        // The apexes lie on the perpendicular bisector of the split edge, at half its length.
        let (dx, dy) = ((b.0 as i64 - a.0 as i64) / 2, (b.1 as i64 - a.1 as i64) / 2);
        for (px, py) in [(x as i64 - dy, y as i64 + dx), (x as i64 + dy, y as i64 - dx)] {
            if self.contains(px, py) {
                out[count] = (px as u32, py as u32);
                count += 1;
            }
        }
        (out, count)
    }

    /// DAG children (the vertices that bisect the legs of the triangles this vertex creates):
    /// up to four; none at level 1 and for corners.
    pub fn dag_children(&self, x: u32, y: u32) -> ([(u32, u32); 4], usize) {
        let mut out = [(0, 0); 4];
        let mut count = 0;
        let (x, y) = (x as i64, y as i64);
        let offsets: [(i64, i64); 4] = match self.kind(x as u32, y as u32) {
            VertexKind::Corner => return (out, 0),
            VertexKind::SquareCentre { step } => {
                let h = step as i64;
                [(h, 0), (0, h), (-h, 0), (0, -h)]
            }
            VertexKind::EdgeMidpoint { step } => {
                if step == 1 {
                    return (out, 0);
                }
                let h = (step / 2) as i64;
                [(h, h), (-h, h), (-h, -h), (h, -h)]
            }
        };
        for (dx, dy) in offsets {
            if self.contains(x + dx, y + dy) {
                out[count] = ((x + dx) as u32, (y + dy) as u32);
                count += 1;
            }
        }
        (out, count)
    }
}

/// The two DAG children of `split` on `apex`'s side, in triangle-strip order (left first), for the
/// triangle whose right-angle apex is `apex` and whose hypotenuse midpoint is `split`.
///
/// With `d = apex − split` and `rot(d)` its 90° counter-clockwise rotation, the children are
/// `split + (d ± rot(d)) / 2`; the left one takes `+` when `d` is axis-aligned (split is an edge
/// midpoint) and `−` when `d` is diagonal, because the strip's winding flips at every level.
/// Only meaningful when `split` is above level 1 (its children exist).
#[inline(always)]
pub fn split_children(apex: (u32, u32), split: (u32, u32)) -> [(u32, u32); 2] {
    let (dx, dy) = (apex.0 as i64 - split.0 as i64, apex.1 as i64 - split.1 as i64);
    let (rx, ry) = (-dy, dx);
    let sign = if dx == 0 || dy == 0 { 1 } else { -1 };
    let (sx, sy) = (split.0 as i64, split.1 as i64);
    let left = (sx + (dx + sign * rx) / 2, sy + (dy + sign * ry) / 2);
    let right = (sx + (dx - sign * rx) / 2, sy + (dy - sign * ry) / 2);
    [(left.0 as u32, left.1 as u32), (right.0 as u32, right.1 as u32)]
}

/// A grid position as one word, `x` in the low half (as refinement carries vertices).
#[inline(always)]
pub fn pack(x: u32, y: u32) -> u64 {
    x as u64 | (y as u64) << 32
}

/// The inverse of [`pack`].
#[inline(always)]
pub fn unpack(k: u64) -> (u32, u32) {
    (k as u32, (k >> 32) as u32)
}

/// [`split_children`] when the split vertex's level is known (as it is during refinement): the
/// sign that [`split_children`] finds by looking at `apex − split` follows from the level's parity
/// instead (an edge midpoint, odd level, sees an axis-aligned `d`). `split_level` must be ≥ 2.
#[inline(always)]
pub fn split_children_at(apex: (u32, u32), split: (u32, u32), split_level: u32) -> [(u32, u32); 2] {
    let (a, s) = (pack(apex.0, apex.1), pack(split.0, split.1));
    let [l, r] =
        if split_level & 1 == 1 { split_children_packed::<true>(a, s) } else { split_children_packed::<false>(a, s) };
    [unpack(l), unpack(r)]
}

/// [`split_children_at`] on [`pack`]ed positions, `ODD_SPLIT` saying that the split vertex's
/// level is odd. With `d = apex − split` and `rot(d) = (−dy, dx)` the children are
/// `split + (d ± rot d)/2`: integer halving is exact (both components of `d ± rot(d)` are even
/// above level 1), and the packed sums are exact because every component stays in `0..2³²`.
#[inline(always)]
pub fn split_children_packed<const ODD_SPLIT: bool>(apex: u64, split: u64) -> [u64; 2] {
    let d = apex.wrapping_sub(split) as i64;
    let dx = d as i32 as i64;
    let dy = (d - dx) >> 32;
    let (p, q) = ((dx - dy) >> 1, (dx + dy) >> 1);
    let plus = split.wrapping_add(p.wrapping_add(q << 32) as u64); // split + (d + rot d)/2
    let minus = split.wrapping_add(q.wrapping_sub(p << 32) as u64); // split + (d − rot d)/2
    if ODD_SPLIT {
        [plus, minus]
    } else {
        [minus, plus]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all(g: Grid) -> impl Iterator<Item = (u32, u32)> {
        let s = g.size();
        (0..s).flat_map(move |y| (0..s).map(move |x| (x, y)))
    }

    #[test]
    fn covering_picks_smallest_power_of_two_plus_one() {
        assert_eq!(Grid::covering(2, 2).unwrap().size(), 3);
        assert_eq!(Grid::covering(3, 1).unwrap().size(), 3);
        assert_eq!(Grid::covering(4, 3).unwrap().size(), 5);
        assert_eq!(Grid::covering(399, 366).unwrap().size(), 513);
        assert_eq!(Grid::covering(1025, 17).unwrap().size(), 1025);
        assert_eq!(Grid::covering(1026, 17).unwrap().size(), 2049);
        assert!(Grid::covering(1 << 40, 1).is_none());
    }

    #[test]
    fn level_counts_double_like_bisection() {
        for n in 1..=6 {
            let g = Grid::new(n).unwrap();
            let mut per_level = vec![0u64; 2 * n as usize + 2];
            for (x, y) in all(g) {
                per_level[g.level(x, y) as usize] += 1;
            }
            assert_eq!(per_level[0], 0);
            assert_eq!(per_level[2 * n as usize + 1], 4, "corners");
            assert_eq!(per_level[2 * n as usize], 1, "centre");
            assert_eq!(per_level.iter().sum::<u64>(), g.vertices());
            // Square centres at step h: (2^n / 2h)² of them.
            for t in 0..n {
                let side = 1u64 << (n - t - 1);
                assert_eq!(per_level[(2 * t + 2) as usize], side * side);
            }
        }
    }

    #[test]
    fn parents_are_one_level_coarser_and_children_one_finer() {
        for n in 1..=6 {
            let g = Grid::new(n).unwrap();
            for (x, y) in all(g) {
                let l = g.level(x, y);
                let (ps, np) = g.dag_parents(x, y);
                if l <= 2 * n {
                    let on_border = x == 0 || y == 0 || x == g.max_coord() || y == g.max_coord();
                    let expect = if on_border && l % 2 == 1 { 1 } else { 2 };
                    assert_eq!(np, expect, "parents of {x},{y}");
                }
                for &(px, py) in &ps[..np] {
                    // The centre's parents are corners (level 2n + 1) only in the degenerate sense
                    // of the initial split; every other parent is exactly one level up.
                    assert_eq!(g.level(px, py), l + 1, "parent of {x},{y}");
                    if g.kind(px, py) != VertexKind::Corner {
                        let (cs, nc) = g.dag_children(px, py);
                        assert!(cs[..nc].contains(&(x, y)), "{px},{py} lists {x},{y} as child");
                    }
                }
                let (cs, nc) = g.dag_children(x, y);
                for &(cx, cy) in &cs[..nc] {
                    assert_eq!(g.level(cx, cy), l - 1);
                    let (ps, np) = g.dag_parents(cx, cy);
                    assert!(ps[..np].contains(&(x, y)));
                }
            }
        }
    }

    #[test]
    fn split_edge_endpoints_are_coarser_and_centred() {
        let g = Grid::new(5).unwrap();
        for (x, y) in all(g) {
            if let Some([a, b]) = g.split_edge(x, y) {
                assert_eq!(a.0 + b.0, 2 * x);
                assert_eq!(a.1 + b.1, 2 * y);
                assert!(g.level(a.0, a.1) > g.level(x, y));
                assert!(g.level(b.0, b.1) > g.level(x, y));
            }
        }
        // Only corners active: the two root triangles share the sw–ne diagonal, which the centre
        // bisects.
        let g = Grid::new(3).unwrap();
        assert_eq!(g.split_edge(4, 4), Some([(0, 0), (8, 8)]));
    }

    /// Walk the whole refinement recursively and check that split_children always yields the
    /// split vertex's DAG children on the apex's side, left before right in strip order.
    #[test]
    fn split_children_follow_strip_order() {
        let g = Grid::new(3).unwrap();
        let c = g.centre();
        let [w, s, e, n] = g.edge_midpoints();
        // First children of the root triangles: the white level-2 centres sw, se, ne, nw.
        assert_eq!(split_children(c, s), [(2, 2), (6, 2)]);
        assert_eq!(split_children(c, e), [(6, 2), (6, 6)]);
        assert_eq!(split_children(c, n), [(6, 6), (2, 6)]);
        assert_eq!(split_children(c, w), [(2, 6), (2, 2)]);
        // Next level down from (s, sw-centre): the west child of s first, then the north one.
        assert_eq!(split_children(s, (2, 2)), [(2, 0), (4, 2)]);

        fn walk(g: Grid, i: (u32, u32), j: (u32, u32), seen: &mut Vec<(u32, u32)>) {
            seen.push(j);
            if g.level(j.0, j.1) == 1 {
                return;
            }
            let [l, r] = split_children(i, j);
            let (cs, nc) = g.dag_children(j.0, j.1);
            assert!(cs[..nc].contains(&l) && cs[..nc].contains(&r));
            // Both children bisect legs that end at the apex.
            for ch in [l, r] {
                let [a, b] = g.split_edge(ch.0, ch.1).unwrap();
                assert!(a == i || b == i, "{ch:?} should bisect a leg from {i:?}");
            }
            // Left child lies before right: going around the split vertex j, the left child is
            // on the side the strip comes from (checked via the sign of the cross product, which
            // alternates with the level).
            assert_eq!(split_children_at(i, j, g.level(j.0, j.1)), [l, r], "{i:?} {j:?}");
            walk(g, j, l, seen);
            walk(g, j, r, seen);
        }
        for n in 1..=5 {
            let g = Grid::new(n).unwrap();
            let mut seen = Vec::new();
            for j in g.edge_midpoints() {
                walk(g, g.centre(), j, &mut seen);
            }
            seen.push(g.centre());
            seen.sort();
            seen.dedup();
            // Every non-corner vertex is reached (interior ones twice, from both parents).
            assert_eq!(seen.len() as u64, g.vertices() - 4, "n = {n}");
        }
    }
}
