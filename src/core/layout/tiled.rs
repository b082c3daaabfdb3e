//! `tiled`: square tiles of `T × T` vertices (`T` a power of two), tiles in row-major order (south
//! tile row first), row-major inside each tile. This is the classic blocked ("tiled") matrix
//! layout that Lindstrom & Pascucci (2001, §5) compare their hierarchical layouts against: it
//! keeps 2-D neighbourhoods within one page at the finest level but has no coarse-to-fine order.
//!
//! The grid side `P = 2^n + 1` is never a multiple of `T` (unless `T = 1`), so the last tile
//! column and the last tile row are ragged. They are packed without gaps: tile column `tx` has
//! width `w(tx) = min(T, P − tx·T)` and tile row `ty` has height `h(ty) = min(T, P − ty·T)`, and
//!
//! ```text
//! index(x, y) = ty·T·P + tx·T·h(ty) + (y − ty·T)·w(tx) + (x − tx·T),   tx = x / T, ty = y / T
//! ```
//!
//! (a full tile row holds `T·P` records, the tiles before `tx` in row `ty` hold `tx·T·h(ty)`).
//! Records = `P²`, zero waste. With `T >= P` there is a single tile and this is row-major.

use super::{Layout, LayoutKind};
use crate::layout::hierarchy::Grid;

#[derive(Clone, Debug)]
pub struct Tiled {
    grid: Grid,
    /// Tile side `T`.
    side: u32,
    /// `log2(T)`.
    shift: u32,
    /// Grid side `P`.
    p: u64,
}

impl Tiled {
    /// Tiles of `side × side` vertices.
    ///
    /// # Panics
    /// If `side` is not a power of two (callers validate user input first, see
    /// [`super::AnyLayout::new`]).
    pub fn new(grid: Grid, side: u32) -> Self {
        assert!(side.is_power_of_two(), "tile side must be a power of two, got {side}");
        Tiled { grid, side, shift: side.trailing_zeros(), p: grid.size() as u64 }
    }

    /// Extent of tile number `t` (a width for a tile column, a height for a tile row).
    #[inline(always)]
    fn extent(&self, t: u64) -> u64 {
        let t_side = self.side as u64;
        t_side.min(self.p - t * t_side)
    }
}

impl Layout for Tiled {
    const PREFETCH_GRANDCHILDREN: bool = true;

    fn kind(&self) -> LayoutKind {
        LayoutKind::Tiled
    }
    fn grid(&self) -> Grid {
        self.grid
    }
    fn param(&self) -> u32 {
        self.side
    }
    fn records(&self) -> u64 {
        self.p * self.p
    }
    #[inline]
    fn index(&self, x: u32, y: u32) -> u64 {
        let (x, y) = (x as u64, y as u64);
        let (tx, ty) = (x >> self.shift, y >> self.shift);
        let (x0, y0) = (tx << self.shift, ty << self.shift);
        y0 * self.p + x0 * self.extent(ty) + (y - y0) * self.extent(tx) + (x - x0)
    }
    #[inline]
    fn coords(&self, index: u64) -> Option<(u32, u32)> {
        if index >= self.records() {
            return None;
        }
        let t_side = self.side as u64;
        // A full tile row holds T·P records; the last one fewer, but every index in it still
        // divides down to the right row.
        let ty = index / (t_side * self.p);
        let y0 = ty << self.shift;
        let rest = index - y0 * self.p;
        let h = self.extent(ty);
        let tx = rest / (t_side * h);
        let x0 = tx << self.shift;
        let rest = rest - x0 * h;
        let w = self.extent(tx);
        Some(((x0 + rest % w) as u32, (y0 + rest / w) as u32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_example_packs_ragged_tiles() {
        // n = 2: P = 5, T = 2. Tile columns have widths 2, 2, 1; tile rows heights 2, 2, 1.
        let l = Tiled::new(Grid::new(2).unwrap(), 2);
        assert_eq!(l.index(0, 0), 0);
        assert_eq!(l.index(1, 0), 1);
        assert_eq!(l.index(0, 1), 2);
        assert_eq!(l.index(1, 1), 3);
        assert_eq!(l.index(2, 0), 4);
        assert_eq!(l.index(4, 0), 8); // ragged tile: width 1
        assert_eq!(l.index(4, 1), 9);
        assert_eq!(l.index(0, 2), 10); // second tile row starts at T·P
        assert_eq!(l.index(0, 4), 20); // last tile row: height 1
        assert_eq!(l.index(2, 4), 22);
        assert_eq!(l.index(4, 4), 24);
        assert_eq!(l.coords(9), Some((4, 1)));
        assert_eq!(l.coords(25), None);
    }

    #[test]
    fn huge_tile_is_row_major() {
        let g = Grid::new(3).unwrap();
        let l = Tiled::new(g, 64);
        for y in 0..g.size() {
            for x in 0..g.size() {
                assert_eq!(l.index(x, y), y as u64 * 9 + x as u64);
            }
        }
    }
}
