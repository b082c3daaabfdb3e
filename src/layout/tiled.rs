//! STUB: to be written.

use super::{Layout, LayoutKind};
use crate::hierarchy::Grid;

#[derive(Clone, Debug)]
pub struct Tiled {
    grid: Grid, side: u32,
}

impl Tiled {
    pub fn new(grid: Grid, side: u32) -> Self { Tiled { grid, side } }
}

impl Layout for Tiled {
    fn kind(&self) -> LayoutKind {
        LayoutKind::Tiled
    }
    fn grid(&self) -> Grid {
        self.grid
    }
    fn records(&self) -> u64 {
        todo!()
    }
    fn index(&self, _x: u32, _y: u32) -> u64 {
        todo!()
    }
    fn coords(&self, _index: u64) -> Option<(u32, u32)> {
        todo!()
    }
}
