//! `row-major`: the linear matrix order, south row first (`index = y · side + x`). No waste; the
//! baseline every other layout is compared with.

use super::{Layout, LayoutKind};
use crate::layout::hierarchy::Grid;

#[derive(Clone, Debug)]
pub struct RowMajor {
    grid: Grid,
    side: u64,
}

impl RowMajor {
    pub fn new(grid: Grid) -> Self {
        RowMajor { grid, side: grid.size() as u64 }
    }
}

impl Layout for RowMajor {
    const PREFETCH_GRANDCHILDREN: bool = true;

    fn kind(&self) -> LayoutKind {
        LayoutKind::RowMajor
    }
    fn grid(&self) -> Grid {
        self.grid
    }
    fn records(&self) -> u64 {
        self.side * self.side
    }
    #[inline(always)]
    fn index(&self, x: u32, y: u32) -> u64 {
        y as u64 * self.side + x as u64
    }
    fn coords(&self, index: u64) -> Option<(u32, u32)> {
        (index < self.records()).then(|| ((index % self.side) as u32, (index / self.side) as u32))
    }
}
