//! Which posts of the padded (2^n + 1)² grid a terrain file stores (ARCHITECTURE.md, "Padding
//! that is never stored").
//!
//! A DEM of `width × height` posts lies in the grid's south-west corner. Refinement needs a record
//! for every data post and for every *ancestor* of one (a vertex is active only with both DAG
//! parents, so the set must be closed upwards); a padding vertex with no data post among its DAG
//! descendants is never needed. Such vertices are **null**: their record is all zeros (error 0,
//! radius 0), which the active test never accepts, and the pages that hold only null records are
//! not stored in the file at all.
//!
//! The stored set is a rectangle per level: level `l`'s vertices with `x ≤ width − 1 + d_l` and
//! `y ≤ height − 1 + d_l`, where `d_1 = 0` and `d_{l+1} = d_l + o_l`, `o_l = 2^⌊(l−1)/2⌋` being the
//! largest coordinate offset from a level-`l` vertex to a DAG parent. A parent of a stored vertex is
//! then stored (its coordinates exceed the child's by at most `o_l`), every data post is stored, and
//! at the finest levels the rectangle exceeds the data by a post or two, so a file holds about the
//! DEM's own posts. The four corners (always active) are stored too.

use crate::layout::hierarchy::Grid;

/// The stored vertices of a grid over a `width × height` DEM at its south-west corner.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stored {
    grid: Grid,
    /// Per level `l` (index `l`, 1..=2n), the largest stored x and y.
    max_x: [u32; 64],
    max_y: [u32; 64],
}

impl Stored {
    /// The stored set of `grid` over a DEM of `width × height` posts (each at least 1 and at most
    /// the grid's side).
    pub fn new(grid: Grid, width: u32, height: u32) -> Stored {
        debug_assert!(width >= 1 && height >= 1 && width <= grid.size() && height <= grid.size());
        let m = grid.max_coord() as u64;
        let (mut max_x, mut max_y) = ([0u32; 64], [0u32; 64]);
        let mut d = 0u64;
        for l in 1..=grid.levels() as usize {
            max_x[l] = (width as u64 - 1 + d).min(m) as u32;
            max_y[l] = (height as u64 - 1 + d).min(m) as u32;
            d += 1u64 << ((l - 1) / 2);
        }
        Stored { grid, max_x, max_y }
    }

    /// Every vertex of `grid` (a DEM that fills it).
    pub fn all(grid: Grid) -> Stored {
        Stored::new(grid, grid.size(), grid.size())
    }

    pub fn grid(&self) -> Grid {
        self.grid
    }

    /// Whether every vertex is stored.
    pub fn is_all(&self) -> bool {
        let m = self.grid.max_coord();
        self.max_x[1] == m && self.max_y[1] == m
    }

    /// The largest stored `(x, y)` at `level` (1..=2n); every coordinate up to it is stored.
    #[inline]
    pub fn max_at(&self, level: u32) -> (u32, u32) {
        let l = level as usize & 63;
        (self.max_x[l], self.max_y[l])
    }

    /// Whether the record of `(x, y)` (a grid position) is stored.
    #[inline]
    pub fn contains(&self, x: u32, y: u32) -> bool {
        let m = self.grid.max_coord();
        if (x == 0 || x == m) && (y == 0 || y == m) {
            return true;
        }
        let (mx, my) = self.max_at(self.grid.level(x, y));
        x <= mx && y <= my
    }

    /// The number of stored vertices.
    pub fn count(&self) -> u64 {
        let m = self.grid.max_coord();
        let mut total = 0u64;
        for level in 1..=self.grid.levels() {
            let (mx, my) = self.max_at(level);
            let step = 1u32 << ((level - 1) / 2);
            // Multiples of `step` up to `v`, and the odd ones among them.
            let all = |v: u32| (v / step) as u64 + 1;
            let odd = |v: u32| (v / step).div_ceil(2) as u64;
            total += if level % 2 == 1 {
                // Edge midpoints: exactly one of x/step, y/step odd.
                let (ox, oy) = (odd(mx), odd(my));
                let (ex, ey) = (all(mx) - ox, all(my) - oy);
                ox * ey + ex * oy
            } else {
                // Square centres: both odd.
                odd(mx) * odd(my)
            };
        }
        // The corners; the grid centre is counted at level 2n.
        let corners = [(0, 0), (m, 0), (m, m), (0, m)];
        total + corners.len() as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Upward closed (a stored vertex's DAG parents are stored), every data post stored, nothing
    /// stored without a data post among its descendants except through the rectangle's slack,
    /// and `count` the number of stored positions.
    #[test]
    fn stored_sets_are_closed_upwards_and_cover_the_data() {
        for (n, w, h) in [(3, 9, 9), (3, 5, 3), (4, 17, 2), (5, 20, 11), (5, 1, 1), (6, 40, 21), (6, 33, 33)] {
            let grid = Grid::new(n).unwrap();
            let s = Stored::new(grid, w, h);
            let mut count = 0;
            for y in 0..grid.size() {
                for x in 0..grid.size() {
                    if !s.contains(x, y) {
                        continue;
                    }
                    count += 1;
                    let (parents, k) = grid.dag_parents(x, y);
                    for &(px, py) in &parents[..k] {
                        assert!(s.contains(px, py), "n {n} {w}x{h}: ({x}, {y}) stored, parent ({px}, {py}) not");
                    }
                }
            }
            for y in 0..h {
                for x in 0..w {
                    assert!(s.contains(x, y));
                }
            }
            assert_eq!(s.count(), count, "n {n} {w}x{h}");
            assert_eq!(s.is_all(), w == grid.size() && h == grid.size());
        }
    }

    /// A 2:1 DEM in its square grid stores a little over its own posts, not the square's.
    #[test]
    fn a_wide_dem_stores_about_its_posts() {
        let grid = Grid::new(11).unwrap(); // 2049²
        let s = Stored::new(grid, 1081, 540);
        let ratio = s.count() as f64 / (1081.0 * 540.0);
        assert!((1.0..1.05).contains(&ratio), "{ratio}");
        assert_eq!(Stored::all(grid).count(), grid.vertices());
    }
}
