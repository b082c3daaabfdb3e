//! Index layouts: the order of vertex records in a terrain file (Lindstrom & Pascucci 2001, §5).
//!
//! Every layout maps a grid position `(x, y)` to a record index in `0..records()`, maps record
//! indices back to positions where a slot holds a vertex (`None` for unused slots), and computes the
//! two DAG children that top-down refinement visits next. The refinement is generic over
//! [`Layout`], so each layout's child computation is monomorphised into the hot loop; code that is
//! not hot can use [`AnyLayout`], which implements the trait by matching on the kind.

mod embedded;
pub mod hierarchy;
mod hz;
mod interleaved;
mod morton;
mod row_major;
pub mod stored;
mod tiled;

pub use embedded::Embedded;
pub use hz::Hz;
pub use interleaved::Interleaved;
pub use row_major::RowMajor;
pub use stored::Stored;
pub use tiled::Tiled;

use crate::layout::hierarchy::{split_children, Grid};

/// The five layouts, with their on-disk codes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum LayoutKind {
    RowMajor = 0,
    Tiled = 1,
    Interleaved = 2,
    Embedded = 3,
    Hz = 4,
}

impl LayoutKind {
    pub const ALL: [LayoutKind; 5] =
        [LayoutKind::RowMajor, LayoutKind::Tiled, LayoutKind::Interleaved, LayoutKind::Embedded, LayoutKind::Hz];

    /// The name used on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            LayoutKind::RowMajor => "row-major",
            LayoutKind::Tiled => "tiled",
            LayoutKind::Interleaved => "interleaved",
            LayoutKind::Embedded => "embedded",
            LayoutKind::Hz => "hz",
        }
    }

    pub fn from_name(name: &str) -> Option<LayoutKind> {
        LayoutKind::ALL.into_iter().find(|k| k.name() == name)
    }

    pub fn from_code(code: u32) -> Option<LayoutKind> {
        LayoutKind::ALL.into_iter().find(|k| *k as u32 == code)
    }
}

impl std::fmt::Display for LayoutKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A grid position together with its record index in some layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Vertex {
    pub x: u32,
    pub y: u32,
    pub index: u64,
}

/// A record order for a `(2^n + 1)²` grid.
pub trait Layout: Clone + Send + Sync + 'static {
    /// Whether [`Self::split_children`] is cheap enough (a few integer operations) that refinement
    /// should compute grandchildren ahead of time to prefetch their records.
    const PREFETCH_GRANDCHILDREN: bool = false;

    fn kind(&self) -> LayoutKind;

    fn grid(&self) -> Grid;

    /// The layout's parameter as stored in the file header (tile side for `tiled`, else 0).
    fn param(&self) -> u32 {
        0
    }

    /// Size of the index space (number of record slots, used or not).
    fn records(&self) -> u64;

    /// Record index of grid position `(x, y)`; the position must lie in the grid.
    fn index(&self, x: u32, y: u32) -> u64;

    /// Grid position stored at `index`, or `None` for an unused slot or an index out of range.
    fn coords(&self, index: u64) -> Option<(u32, u32)>;

    #[inline(always)]
    fn vertex(&self, x: u32, y: u32) -> Vertex {
        Vertex { x, y, index: self.index(x, y) }
    }

    /// The two DAG children of `split` on `apex`'s side, left first in strip order (see
    /// [`crate::layout::hierarchy::split_children`]). `split` must be above level 1. Layouts with an
    /// index-arithmetic shortcut override this; the default goes through coordinates.
    #[inline(always)]
    fn split_children(&self, apex: Vertex, split: Vertex) -> [Vertex; 2] {
        let [l, r] = split_children((apex.x, apex.y), (split.x, split.y));
        [self.vertex(l.0, l.1), self.vertex(r.0, r.1)]
    }

    /// Record indices of `split`'s two children on `apex`'s side at positions `left` and `right`
    /// (from [`crate::layout::hierarchy::split_children_at`]), for an `apex` that is itself a split
    /// vertex of the refinement: below the four root triangles, so never a corner or the grid
    /// centre. The quadtree layouts compute them from the two parents' indices alone.
    #[inline(always)]
    fn inner_child_indices(&self, apex_index: u64, split_index: u64, left: (u32, u32), right: (u32, u32)) -> [u64; 2] {
        let _ = (apex_index, split_index);
        [self.index(left.0, left.1), self.index(right.0, right.1)]
    }

    /// In the quadtree layouts, the records refinement reads two levels below a split vertex (the
    /// children of both its children, on its side) are its own four quadtree children, which lie
    /// together: the index of the first (for one prefetch). `None` where they do not.
    #[inline(always)]
    fn quadtree_children(&self, index: u64) -> Option<u64> {
        let _ = index;
        None
    }

    /// Unused fraction of the index space relative to the vertex count: `records / vertices − 1`.
    fn waste_ratio(&self) -> f64 {
        self.records() as f64 / self.grid().vertices() as f64 - 1.0
    }
}

/// Calls a generic function with the concrete layout type (for monomorphised hot loops).
pub trait LayoutVisitor {
    type Output;
    fn visit<L: Layout>(self, layout: &L) -> Self::Output;
}

/// Any of the five layouts, chosen at run time.
#[derive(Clone, Debug)]
pub enum AnyLayout {
    RowMajor(RowMajor),
    Tiled(Tiled),
    Interleaved(Interleaved),
    Embedded(Embedded),
    Hz(Hz),
}

/// Default tile side for `tiled`: the largest power of two whose square tile of `record_bytes`
/// records fits in one 4 KiB page.
pub fn default_tile_side(record_bytes: u32) -> u32 {
    let per_page = 4096 / record_bytes.max(1);
    let mut side = 1u32;
    while (2 * side) * (2 * side) <= per_page {
        side *= 2;
    }
    side
}

impl AnyLayout {
    /// Builds a layout of `kind` for `grid`. `param` is the tile side for `tiled` (a power of two
    /// >= 1, or 0 for the default); it must be 0 for the other layouts.
    pub fn new(kind: LayoutKind, grid: Grid, param: u32, record_bytes: u32) -> Result<AnyLayout, String> {
        if kind != LayoutKind::Tiled && param != 0 {
            return Err(format!("layout {kind} takes no parameter (got {param})"));
        }
        Ok(match kind {
            LayoutKind::RowMajor => AnyLayout::RowMajor(RowMajor::new(grid)),
            LayoutKind::Tiled => {
                let side = if param == 0 { default_tile_side(record_bytes) } else { param };
                if !side.is_power_of_two() || side > (1 << 15) {
                    return Err(format!("tile side must be a power of two up to 32768, got {side}"));
                }
                AnyLayout::Tiled(Tiled::new(grid, side))
            }
            LayoutKind::Interleaved => AnyLayout::Interleaved(Interleaved::new(grid)),
            LayoutKind::Embedded => AnyLayout::Embedded(Embedded::new(grid)),
            LayoutKind::Hz => AnyLayout::Hz(Hz::new(grid)),
        })
    }

    pub fn visit<V: LayoutVisitor>(&self, visitor: V) -> V::Output {
        match self {
            AnyLayout::RowMajor(l) => visitor.visit(l),
            AnyLayout::Tiled(l) => visitor.visit(l),
            AnyLayout::Interleaved(l) => visitor.visit(l),
            AnyLayout::Embedded(l) => visitor.visit(l),
            AnyLayout::Hz(l) => visitor.visit(l),
        }
    }
}

macro_rules! any_dispatch {
    ($self:ident, $l:ident => $e:expr) => {
        match $self {
            AnyLayout::RowMajor($l) => $e,
            AnyLayout::Tiled($l) => $e,
            AnyLayout::Interleaved($l) => $e,
            AnyLayout::Embedded($l) => $e,
            AnyLayout::Hz($l) => $e,
        }
    };
}

impl Layout for AnyLayout {
    fn kind(&self) -> LayoutKind {
        any_dispatch!(self, l => l.kind())
    }
    fn grid(&self) -> Grid {
        any_dispatch!(self, l => l.grid())
    }
    fn param(&self) -> u32 {
        any_dispatch!(self, l => l.param())
    }
    fn records(&self) -> u64 {
        any_dispatch!(self, l => l.records())
    }
    fn index(&self, x: u32, y: u32) -> u64 {
        any_dispatch!(self, l => l.index(x, y))
    }
    fn coords(&self, index: u64) -> Option<(u32, u32)> {
        any_dispatch!(self, l => l.coords(index))
    }
    fn split_children(&self, apex: Vertex, split: Vertex) -> [Vertex; 2] {
        any_dispatch!(self, l => l.split_children(apex, split))
    }
    fn inner_child_indices(&self, apex_index: u64, split_index: u64, left: (u32, u32), right: (u32, u32)) -> [u64; 2] {
        any_dispatch!(self, l => l.inner_child_indices(apex_index, split_index, left, right))
    }
    fn quadtree_children(&self, index: u64) -> Option<u64> {
        any_dispatch!(self, l => l.quadtree_children(index))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_tile_is_about_one_page() {
        assert_eq!(default_tile_side(12), 16); // 16² · 12 B = 3 KiB
        assert_eq!(default_tile_side(4), 32); // 32² · 4 B = 4 KiB
        assert_eq!(default_tile_side(16), 16);
    }

    #[test]
    fn names_round_trip() {
        for k in LayoutKind::ALL {
            assert_eq!(LayoutKind::from_name(k.name()), Some(k));
            assert_eq!(LayoutKind::from_code(k as u32), Some(k));
        }
        assert_eq!(LayoutKind::from_name("zorder"), None);
    }
}
