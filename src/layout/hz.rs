//! STUB: to be written.

use super::{Layout, LayoutKind};
use crate::hierarchy::Grid;

#[derive(Clone, Debug)]
pub struct Hz {
    grid: Grid,
}

impl Hz {
    pub fn new(grid: Grid) -> Self { Hz { grid } }
}

impl Layout for Hz {
    fn kind(&self) -> LayoutKind {
        LayoutKind::Hz
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
