//! `hz`: hierarchical Z-order (Pascucci & Frank, *Global Static Indexing for Real-Time Exploration
//! of Very Large Regular Grids*, SC 2001), the coarse-to-fine layout Lindstrom & Pascucci (2001,
//! §5) compare with their quadtree layouts.
//!
//! **Main block**, the `2^n × 2^n` positions with `x < N` and `y < N`: take the Morton code `z`
//! (`2n` bits, `x` in the even bits, `y` in the odd ones), set the guard bit, `z' = z | 1 << 2n`,
//! and drop the trailing zeros and the lowest set bit: `hz = z' >> (trailing_zeros(z') + 1)`.
//! Level 0 is `{0}` (the origin) and level `k >= 1` (`trailing_zeros(z) = 2n − k`) fills
//! `[2^(k−1), 2^k)`; even level `2j` holds the step-`N/2^j` vertices with odd `x / step`, odd level
//! `2j − 1` those with odd `y / step` and even `x / step`.
//!
//! **Edges**: the last row (`y = N`, `x < N`), the last column (`x = N`, `y < N`) and the corner
//! `(N, N)` get 1-D hierarchical blocks: `t = x' >> (trailing_zeros(x') + 1)` with
//! `x' = x | 1 << n` (resp. `y`), edge level `j >= 1` (resolution `N/2^j`) filling `[2^(j−1), 2^j)`.
//! Edge level `j` is placed right after main level `2j`, as the corner (only at `j = 0`), then
//! `row(t), col(t)` alternating over the `t` of that level. With `E(j) = 1 + 2^(j+1)` edge entries
//! in levels `0..=j`:
//!
//! ```text
//! main entry at hz level k >= 1:  index = hz + E(⌊(k − 1)/2⌋)        (level 0: index 0)
//! edge level j:                   starts at 4^j + E(j − 1) (j >= 1), at 1 for j = 0
//! ```
//!
//! Main levels `2j − 1`, `2j` and edge level `j` together end at `(2^j + 1)²`: every prefix of that
//! length is exactly the grid subsampled at step `N/2^j`. Records = `(2^n + 1)²`, zero waste.

use super::{morton, Layout, LayoutKind};
use crate::layout::hierarchy::Grid;

#[derive(Clone, Debug)]
pub struct Hz {
    grid: Grid,
}

impl Hz {
    pub fn new(grid: Grid) -> Self {
        Hz { grid }
    }
}

/// Edge entries in edge levels `0..=j`: `1 + 2^(j+1)`.
#[inline(always)]
fn edge_count(j: u32) -> u64 {
    1 + (2u64 << j)
}

impl Layout for Hz {
    fn kind(&self) -> LayoutKind {
        LayoutKind::Hz
    }
    fn grid(&self) -> Grid {
        self.grid
    }
    fn records(&self) -> u64 {
        self.grid.vertices()
    }

    #[inline]
    fn index(&self, x: u32, y: u32) -> u64 {
        let n = self.grid.n();
        let m = 1u32 << n;
        if x < m && y < m {
            let z = morton::encode(x, y) | (1u64 << (2 * n));
            let tz = z.trailing_zeros();
            if tz == 2 * n {
                return 0;
            }
            let k = 2 * n - tz;
            (z >> (tz + 1)) + edge_count((k - 1) / 2)
        } else {
            // Edge: the coordinate that runs along it, and row (0) or column (1).
            let (s, col) = if y == m { (x, 0) } else { (y, 1) };
            if s == m {
                return 1; // (N, N)
            }
            let s = s | m;
            let tz = s.trailing_zeros();
            if tz == n {
                return 2 + col;
            }
            let j = n - tz;
            let t = (s >> (tz + 1)) as u64;
            (1u64 << (2 * j)) + edge_count(j - 1) + 2 * (t - (1u64 << (j - 1))) + col
        }
    }

    #[inline]
    fn coords(&self, index: u64) -> Option<(u32, u32)> {
        let n = self.grid.n();
        let m = 1u32 << n;
        match index {
            0 => return Some((0, 0)),
            1 => return Some((m, m)),
            2 => return Some((0, m)),
            3 => return Some((m, 0)),
            _ if index >= self.records() => return None,
            _ => {}
        }
        // Block j (main levels 2j − 1, 2j, then edge level j) spans [(2^(j−1) + 1)², (2^j + 1)²).
        let mut j = (63 - index.leading_zeros()) / 2;
        let end = (1u64 << j) + 1;
        if index >= end * end {
            j += 1;
        }
        let start = (1u64 << (j - 1)) + 1;
        let o = index - start * start;
        let main = 3u64 << (2 * (j - 1));
        if o < main {
            // hz value in levels 2j − 1 and 2j: [4^(j−1), 4^j).
            let hz = (1u64 << (2 * (j - 1))) + o;
            let level = 64 - hz.leading_zeros();
            let z = ((2 * hz + 1) << (2 * n - level)) & !(1u64 << (2 * n));
            Some(morton::decode(z))
        } else {
            let e = o - main;
            let t = (1u64 << (j - 1)) + e / 2;
            let s = (((2 * t + 1) << (n - j)) as u32) & (m - 1);
            Some(if e & 1 == 0 { (s, m) } else { (m, s) })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_grid_order() {
        // n = 1: 3 × 3 grid, step-2 grid first, then level 1 (y-odd) and level 2 (x-odd) and the
        // edges at step 1.
        let l = Hz::new(Grid::new(1).unwrap());
        let order: Vec<_> = (0..9).map(|i| l.coords(i).unwrap()).collect();
        assert_eq!(order, [(0, 0), (2, 2), (0, 2), (2, 0), (0, 1), (1, 0), (1, 1), (1, 2), (2, 1)]);
    }

    #[test]
    fn prefixes_are_subsampled_grids() {
        for n in 1..=6 {
            let g = Grid::new(n).unwrap();
            let l = Hz::new(g);
            for j in 0..=n {
                let side = (1u64 << j) + 1;
                let step = 1u32 << (n - j);
                for i in 0..side * side {
                    let (x, y) = l.coords(i).unwrap();
                    assert!(x % step == 0 && y % step == 0, "n={n} j={j} i={i}: {x},{y}");
                }
            }
        }
    }
}
