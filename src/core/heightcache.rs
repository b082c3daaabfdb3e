//! The GPU tile caches' CPU side: data too large for GPU memory as a pool of fixed-size tiles at
//! several resolutions (a quadtree of levels, as in virtual texturing and clipmaps), the tiles a
//! strip wants, which of them are resident, and the indirection table the shaders read. One
//! mechanism, [`TileCache`], over two [`TileSet`]s: a terrain's heights ([`HeightCache`], below)
//! and draped imagery from an imagery tile file ([`ImageryTiles`]: the same levels, slots and
//! table, RGBA texels, each vertex wanting the level whose texels project to about a pixel).
//! GPU-free: the renderer (`render::height_cache`) owns the textures and writes what
//! [`TileCache::frame`] hands it. ARCHITECTURE.md, "GPU height cache" and "Paged imagery", gives
//! the reasons. For heights:
//!
//! - **Levels.** Level `k` holds every `2^k`-th post of the `(2^n + 1)²` grid (post `i` of level
//!   `k` is post `i · 2^k` of the grid), cut into tiles of `T × T` cells (`T` a power of two). The
//!   coarsest level is one tile; it is filled when the cache is made and never evicted, so every
//!   fragment has heights.
//! - **Slots.** A tile is stored with one post of border before and two after (`T + 3` posts a
//!   side), which is what bilinear heights and central-difference normals read around any cell of
//!   the tile, so a fragment reads one slot per level.
//! - **Geometry never comes from here.** Strip vertices carry their exact heights (the strip's
//!   morph data, [`crate::refine::RefineOptions::heights`]); tiles only shade. A fragment shades
//!   from the finest resident level under it, blending in a new tile over a few frames.
//! - **What is wanted** follows the strip: for each vertex the level whose posts project to about a
//!   pixel, with the coarser levels above it (so a miss falls back gracefully), then the same-level
//!   neighbours, then a look-ahead one level finer for vertices the camera is approaching. The
//!   list is cut at the pool's size, in that priority order.
//! - **Who does what.** A loader thread plans the wants from a copy of the strip and fills tiles
//!   from the terrain file (through its pager); the render thread takes finished tiles within a
//!   per-frame upload budget, never waiting, and evicts the least recently wanted tile.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, AtomicU8, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;

use serde::Serialize;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::format::imagery::ImageryFile;
use crate::format::terrain::TerrainFile;
use crate::layout::{Layout, LayoutVisitor};
use crate::refine::{Morph, PagerRecords, RecordSource, StripVertex};

// The tile table's layout, which the imagery tile file shares.
pub use crate::format::imagery::{MAX_LEVELS, TABLE_HEADER};

/// Tile cells per side unless asked otherwise.
pub const DEFAULT_TILE_CELLS: u32 = 256;
/// Frames a new tile takes to blend in over the coarser one below it.
pub const FADE_FRAMES: u32 = 8;

/// The tiles of a terrain: levels, tiles per level, the table's keys, what a slot holds.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TileGrid {
    /// `n` of the `(2^n + 1)²` grid.
    n: u32,
    /// log2 of the tile's cells per side.
    t_log2: u32,
    /// Per level: its first key and tiles per side.
    first: Vec<u32>,
    tiles: Vec<u32>,
}

impl TileGrid {
    /// The tiles of a `(2^n + 1)²` grid with `tile_cells` (a power of two ≥ 4) cells per side.
    pub fn new(n: u32, tile_cells: u32) -> Result<TileGrid> {
        if !tile_cells.is_power_of_two() || tile_cells < 4 {
            return Err(Error::InvalidArgument(format!(
                "height tiles need a power-of-two side of at least 4 cells, got {tile_cells}"
            )));
        }
        let t_log2 = tile_cells.trailing_zeros();
        let coarsest = n.saturating_sub(t_log2);
        if coarsest + 1 > MAX_LEVELS {
            return Err(Error::InvalidArgument(format!(
                "a 2^{n} + 1 grid in tiles of {tile_cells} cells needs {} levels, more than {MAX_LEVELS}",
                coarsest + 1
            )));
        }
        let (mut first, mut tiles, mut next) = (Vec::new(), Vec::new(), 0u32);
        for k in 0..=coarsest {
            let per_side = 1u32 << (n - k).saturating_sub(t_log2);
            first.push(next);
            tiles.push(per_side);
            next += per_side * per_side;
        }
        Ok(TileGrid { n, t_log2, first, tiles })
    }

    pub fn levels(&self) -> u32 {
        self.first.len() as u32
    }

    pub fn coarsest_level(&self) -> u32 {
        self.levels() - 1
    }

    /// Cells per tile side.
    pub fn tile_cells(&self) -> u32 {
        1 << self.t_log2
    }

    /// Posts per slot side: the tile's cells, one post before and two after.
    pub fn slot_posts(&self) -> u32 {
        self.tile_cells() + 3
    }

    /// GPU bytes of one slot (`R32Float`).
    pub fn slot_bytes(&self) -> u64 {
        self.slot_posts() as u64 * self.slot_posts() as u64 * 4
    }

    /// Tiles in all levels (table entries).
    pub fn tiles(&self) -> u32 {
        let k = self.coarsest_level() as usize;
        self.first[k] + self.tiles[k] * self.tiles[k]
    }

    /// Bytes of the whole table, header included.
    pub fn table_bytes(&self) -> u64 {
        (TABLE_HEADER + self.tiles()) as u64 * 4
    }

    /// The last post index of level `k` (its posts are `0..=last`).
    pub fn last_post(&self, k: u32) -> u32 {
        1 << (self.n - k.min(self.n))
    }

    pub fn tiles_per_side(&self, k: u32) -> u32 {
        self.tiles[k as usize]
    }

    /// The key (table entry) of tile `(tx, ty)` of level `k`.
    pub fn key(&self, k: u32, tx: u32, ty: u32) -> u32 {
        self.first[k as usize] + ty * self.tiles[k as usize] + tx
    }

    /// `(level, tx, ty)` of a key.
    pub fn decode(&self, key: u32) -> (u32, u32, u32) {
        let k = self.first.partition_point(|&f| f <= key) as u32 - 1;
        let i = key - self.first[k as usize];
        let per = self.tiles[k as usize];
        (k, i % per, i / per)
    }

    /// The key of the level-`k` tile under grid position `(gx, gy)` (level-0 posts, clamped to
    /// the grid): the tile of the cell the point lies in, the rule the fragment shader follows.
    pub fn tile_at(&self, k: u32, gx: f64, gy: f64) -> u32 {
        let last = self.last_post(k);
        let cell = |g: f64| {
            let gk = (g / (1u64 << k) as f64).clamp(0.0, last as f64);
            (gk.floor() as u32).min(last - 1)
        };
        self.key(k, cell(gx) >> self.t_log2, cell(gy) >> self.t_log2)
    }

    /// The grid post of slot texel `(i, j)` of tile `key`: level-`k` post `(tx·T − 1 + i,
    /// ty·T − 1 + j)` clamped to the level, as a level-0 post.
    pub fn texel_post(&self, key: u32, i: u32, j: u32) -> (u32, u32) {
        let (k, tx, ty) = self.decode(key);
        (self.slot_post(k, tx, i), self.slot_post(k, ty, j))
    }

    /// Along one axis: the grid post of texel `d` of a level-`k` slot whose tile index is `t`.
    #[inline]
    fn slot_post(&self, k: u32, t: u32, d: u32) -> u32 {
        ((((t as i64) << self.t_log2) - 1 + d as i64).clamp(0, self.last_post(k) as i64) as u32) << k
    }

    /// The table's header: per level its first entry (slots `0..16`), then tiles per side.
    pub fn header(&self) -> [u32; TABLE_HEADER as usize] {
        let mut h = [0u32; TABLE_HEADER as usize];
        for k in 0..self.levels() as usize {
            h[k] = self.first[k];
            h[MAX_LEVELS as usize + k] = self.tiles[k];
        }
        h
    }

    /// Fills slot data for tile `key` (row-major, `slot_posts()²` heights) from `terrain`'s records
    /// through its pager.
    pub fn fill(&self, terrain: &TerrainFile, key: u32, out: &mut [f32]) -> Result<()> {
        let s = self.slot_posts();
        debug_assert_eq!(out.len(), (s * s) as usize);
        // Decoded once per tile, not per texel.
        let (k, tx, ty) = self.decode(key);
        let at = move |t: u32, d: u32| self.slot_post(k, t, d);
        let mut texels = out.iter_mut();
        read_heights(terrain, (0..s).flat_map(|j| (0..s).map(move |i| (at(tx, i), at(ty, j)))), |z| {
            if let Some(h) = texels.next() {
                *h = z;
            }
        })
    }
}

/// The height of each of `posts`, handed to `put` in order, read from `terrain`'s records: in
/// place when the file is mapped, else through its pager; a read error is returned.
pub fn read_heights(
    terrain: &TerrainFile,
    posts: impl Iterator<Item = (u32, u32)>,
    put: impl FnMut(f32),
) -> Result<()> {
    struct Read<'a, I, P> {
        terrain: &'a TerrainFile,
        posts: I,
        put: P,
    }
    impl<I: Iterator<Item = (u32, u32)>, P: FnMut(f32)> LayoutVisitor for Read<'_, I, P> {
        type Output = Result<()>;
        fn visit<L: Layout>(mut self, layout: &L) -> Result<()> {
            let h = self.terrain.header();
            match self.terrain.mapped_records() {
                Some(records) => {
                    for (x, y) in self.posts {
                        let (x, y) = h.data_post(x, y);
                        (self.put)(records.record(layout.index(x, y)).z);
                    }
                    Ok(())
                }
                None => {
                    let records = PagerRecords::new(self.terrain);
                    for (x, y) in self.posts {
                        let (x, y) = h.data_post(x, y);
                        (self.put)(records.record(layout.index(x, y)).z);
                    }
                    records.take_error()
                }
            }
        }
    }
    terrain.layout().visit(Read { terrain, posts, put })
}

/// Morph data with blend 1 and the exact height for every vertex of `vertices`: what a renderer
/// that does not hold every height draws the strip with.
pub fn exact_heights(terrain: &TerrainFile, vertices: &[StripVertex], out: &mut Vec<Morph>) -> Result<()> {
    out.clear();
    out.reserve(vertices.len());
    read_heights(terrain, vertices.iter().map(|v| (v.x, v.y)), |z_m| out.push(Morph { blend: 1.0, z_m }))
}

/// What the strip asks of the cache: the tiles to load in priority order (at most the pool's
/// capacity), first those the vertices want now with their coarser ancestors, then neighbours and
/// look-ahead; and every tile wanted now (`needed`, uncut: the ones missing fall back).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Wants {
    pub keys: Vec<u32>,
    pub needed: Vec<u32>,
}

/// The view a strip's wants are planned for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WantView {
    pub eye_in_world: glam::DVec3,
    /// Pixels per radian at the image centre (κ at τ = 1 px).
    pub px_per_rad: f64,
    /// Metres per post (x, y).
    pub spacing_m: [f64; 2],
    /// The view's basis (right, up, forward) and the tangents of its half fields of view, widened
    /// by [`VIEW_MARGIN`]: vertices outside want nothing.
    pub basis: [glam::DVec3; 3],
    pub tan_half: [f64; 2],
}

/// How much wider than the image the wants reach (a turning camera finds tiles there).
pub const VIEW_MARGIN: f64 = 1.25;

impl WantView {
    pub fn new(camera: &Camera, spacing_m: [f64; 2]) -> WantView {
        let (r, u, f) = camera.basis();
        let tan_x = (camera.fov_x_deg.to_radians() / 2.0).tan();
        let tan_y = (camera.fov_y_deg().to_radians() / 2.0).tan();
        WantView {
            eye_in_world: camera.eye_in_world,
            px_per_rad: camera.kappa(1.0),
            spacing_m,
            basis: [r, u, f],
            tan_half: [tan_x * VIEW_MARGIN, tan_y * VIEW_MARGIN],
        }
    }

    /// Whether a point `rel` (world − eye, metres) is in the widened view, or near the eye.
    pub fn sees(&self, rel: glam::DVec3) -> bool {
        let [r, u, f] = self.basis;
        let z = rel.dot(f);
        let near = 4.0 * self.spacing_m[0].max(self.spacing_m[1]) * (1 << 8) as f64;
        if rel.length_squared() < near * near {
            return true;
        }
        z > 0.0 && rel.dot(r).abs() <= z * self.tan_half[0] && rel.dot(u).abs() <= z * self.tan_half[1]
    }

    /// The level whose posts project to at least a pixel at `distance_m`: the largest `k` with
    /// `2^k · spacing · κ ≤ distance`.
    pub fn level_at(&self, distance_m: f64, coarsest: u32) -> u32 {
        self.level_for(self.spacing_m[0].min(self.spacing_m[1]), distance_m, coarsest)
    }

    /// The largest `k` with `2^k · unit_m · κ ≤ distance` (0 when none), at most `coarsest`.
    pub fn level_for(&self, unit_m: f64, distance_m: f64, coarsest: u32) -> u32 {
        let ratio = distance_m / (unit_m * self.px_per_rad);
        if ratio.is_finite() && ratio >= 2.0 {
            (ratio.log2().floor() as u32).min(coarsest)
        } else {
            0
        }
    }
}

/// Vertices whose distance, shrunk by this factor, would ask for a finer level are looked ahead.
const LOOK_AHEAD: f64 = 1.5;

/// Plans the wants of a strip (its vertices and exact heights) seen from `view`, at most `capacity`
/// tiles. `stamp` is scratch (one per tile, reused between calls).
pub fn plan_wants(
    grid: &TileGrid,
    vertices: &[StripVertex],
    heights: &[Morph],
    view: &WantView,
    capacity: usize,
    stamp: &mut Vec<u8>,
) -> Wants {
    let unit_m = view.spacing_m[0].min(view.spacing_m[1]);
    let coarsest = grid.coarsest_level();
    plan_tiles(
        grid.tiles(),
        coarsest,
        |k, gx, gy| grid.tile_at(k, gx, gy),
        |key| {
            let (k, tx, ty) = grid.decode(key);
            let per = grid.tiles_per_side(k);
            (k, tx, ty, per, per)
        },
        |k, tx, ty| grid.key(k, tx, ty),
        vertices,
        heights,
        view,
        unit_m,
        |v| Some((v.x as f64, v.y as f64)),
        capacity,
        stamp,
    )
}

/// [`plan_wants`] over any quadtree of tiles: `tile_at(k, position)` the level-`k` tile under a
/// position (in the tiles' own level-0 units, `position(vertex)`; `None`: the vertex wants
/// nothing), `decode(key)` its level, tile and the level's tiles per row and column, `key` the
/// inverse; level `k`'s units are `2^k · unit_m` metres (what is wanted projects to a pixel).
#[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
pub fn plan_tiles(
    tiles: u32,
    coarsest: u32,
    tile_at: impl Fn(u32, f64, f64) -> u32,
    decode: impl Fn(u32) -> (u32, u32, u32, u32, u32),
    key: impl Fn(u32, u32, u32) -> u32,
    vertices: &[StripVertex],
    heights: &[Morph],
    view: &WantView,
    unit_m: f64,
    position: impl Fn(&StripVertex) -> Option<(f64, f64)>,
    capacity: usize,
    stamp: &mut Vec<u8>,
) -> Wants {
    stamp.clear();
    stamp.resize(tiles as usize, 0);
    let eye = view.eye_in_world;
    // (level, squared distance, key) per tier; tier 0 sorted coarse first, then near first.
    type Tier = Vec<(u32, f64, u32)>;
    let mut tiers: [Tier; 3] = Default::default();
    fn want(tier: &mut Tier, k: u32, d2: f64, key: u32, stamp: &mut [u8]) {
        if stamp[key as usize] == 0 {
            stamp[key as usize] = 1;
            tier.push((k, d2, key));
        }
    }
    for (v, m) in vertices.iter().zip(heights.iter().chain(std::iter::repeat(&Morph::default()))) {
        let p = glam::DVec3::new(v.x as f64 * view.spacing_m[0], v.y as f64 * view.spacing_m[1], m.z_m as f64);
        let rel = p - eye;
        if !view.sees(rel) {
            continue;
        }
        let Some((gx, gy)) = position(v) else { continue };
        let d2 = rel.length_squared();
        let d = d2.sqrt();
        let k = view.level_for(unit_m, d, coarsest);
        let key = tile_at(k, gx, gy);
        if stamp[key as usize] != 0 {
            continue;
        }
        for a in k..=coarsest {
            want(&mut tiers[0], a, d2, tile_at(a, gx, gy), stamp);
        }
        let ahead = view.level_for(unit_m, d / LOOK_AHEAD, coarsest);
        if ahead < k {
            // Marked later, after the neighbours have taken theirs.
            tiers[2].push((ahead, d2, tile_at(ahead, gx, gy)));
        }
    }
    // The same-level neighbours of every wanted tile.
    let [first, near, _] = &mut tiers;
    for &(_, d2, k0) in first.iter() {
        let (k, tx, ty, per_x, per_y) = decode(k0);
        for (dx, dy) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
            let (nx, ny) = (tx as i64 + dx, ty as i64 + dy);
            if (0..per_x as i64).contains(&nx) && (0..per_y as i64).contains(&ny) {
                want(near, k, d2, key(k, nx as u32, ny as u32), stamp);
            }
        }
    }
    let ahead = std::mem::take(&mut tiers[2]);
    for (k, d2, key) in ahead {
        want(&mut tiers[2], k, d2, key, stamp);
    }
    tiers[0].sort_by(|a, b| b.0.cmp(&a.0).then(a.1.total_cmp(&b.1)));
    tiers[1].sort_by(|a, b| a.1.total_cmp(&b.1));
    tiers[2].sort_by(|a, b| a.1.total_cmp(&b.1));
    let needed = tiers[0].iter().map(|t| t.2).collect();
    let keys: Vec<u32> = tiers.iter().flatten().map(|t| t.2).take(capacity).collect();
    Wants { keys, needed }
}

/// What a tile cache holds: a quadtree of levels of tiles filled from a file, one slot (GPU
/// texture layer) per resident tile, and the table the shaders read (its header, then one entry
/// per tile). Heights ([`TerrainTiles`]) and draped imagery ([`ImageryTiles`]) are the two.
pub trait TileSet: Send + Sync + 'static {
    /// A slot's texel: an `f32` height, an RGBA8 colour.
    type Texel: Copy + Default + Send + 'static;
    /// Tiles in all levels (table entries).
    fn tiles(&self) -> u32;
    /// The one tile of the coarsest level: filled first, never evicted.
    fn coarsest_key(&self) -> u32;
    /// Texels per slot side.
    fn slot_side(&self) -> u32;
    /// The table's header: per level its first entry, then tiles per row.
    fn header(&self) -> [u32; TABLE_HEADER as usize];
    /// Fills `out` (`slot_side()²` texels, rows first) with tile `key`.
    fn fill(&self, key: u32, out: &mut [Self::Texel]) -> Result<()>;
    /// The tiles a strip seen from `view` wants, at most `capacity` (see [`plan_wants`]); runs on
    /// the loader thread, so reading what the plan needs (a strip's heights) happens there.
    fn plan(
        &self,
        vertices: &[StripVertex],
        heights: &[Morph],
        view: &WantView,
        capacity: usize,
        stamp: &mut Vec<u8>,
    ) -> Result<Wants>;

    /// GPU bytes of one slot.
    fn slot_bytes(&self) -> u64 {
        self.slot_side() as u64 * self.slot_side() as u64 * std::mem::size_of::<Self::Texel>() as u64
    }

    /// Bytes of the whole table, header included.
    fn table_bytes(&self) -> u64 {
        (TABLE_HEADER + self.tiles()) as u64 * 4
    }
}

/// A terrain's heights as tiles ([`TileGrid`]), filled from its records through its pager.
pub struct TerrainTiles {
    pub terrain: Arc<TerrainFile>,
    pub grid: TileGrid,
}

impl TileSet for TerrainTiles {
    type Texel = f32;
    fn tiles(&self) -> u32 {
        self.grid.tiles()
    }
    fn coarsest_key(&self) -> u32 {
        self.grid.key(self.grid.coarsest_level(), 0, 0)
    }
    fn slot_side(&self) -> u32 {
        self.grid.slot_posts()
    }
    fn header(&self) -> [u32; TABLE_HEADER as usize] {
        self.grid.header()
    }
    fn fill(&self, key: u32, out: &mut [f32]) -> Result<()> {
        self.grid.fill(&self.terrain, key, out)
    }
    fn plan(
        &self,
        v: &[StripVertex],
        h: &[Morph],
        view: &WantView,
        capacity: usize,
        stamp: &mut Vec<u8>,
    ) -> Result<Wants> {
        Ok(plan_wants(&self.grid, v, h, view, capacity, stamp))
    }
}

/// Imagery draped on a terrain as tiles of an imagery tile file ([`ImageryFile`]): a strip vertex
/// wants the level whose texels project to about a pixel where it lies in the image.
pub struct ImageryTiles {
    pub file: ImageryFile,
    /// The terrain it is draped on: a strip handed over without its heights has them read from
    /// here, on the loader thread (the plan's distances need them).
    pub terrain: Arc<TerrainFile>,
    /// Texture coordinates of grid posts: `u = uv[0] + uv[1]·x`, `v = uv[2] + uv[3]·y` (0..1
    /// over the image, v down).
    pub uv: [f64; 4],
    /// Whether u wraps (a world image on a geographic terrain).
    pub wraps: bool,
}

impl ImageryTiles {
    /// Level-0 texel coordinates of grid position `(x, y)`, `None` outside the image.
    pub fn texel_of(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let g = self.file.grid();
        let (mut u, v) = (self.uv[0] + self.uv[1] * x, self.uv[2] + self.uv[3] * y);
        if self.wraps {
            u = u.rem_euclid(1.0);
        }
        ((0.0..=1.0).contains(&u) && (0.0..=1.0).contains(&v)).then_some((u * g.width as f64, v * g.height as f64))
    }
}

impl TileSet for ImageryTiles {
    type Texel = u32;
    fn tiles(&self) -> u32 {
        self.file.grid().tiles()
    }
    fn coarsest_key(&self) -> u32 {
        self.file.grid().tiles() - 1
    }
    fn slot_side(&self) -> u32 {
        self.file.grid().slot_side()
    }
    fn header(&self) -> [u32; TABLE_HEADER as usize] {
        self.file.grid().header()
    }
    fn fill(&self, key: u32, out: &mut [u32]) -> Result<()> {
        self.file.read_tile(key, out)
    }
    fn plan(
        &self,
        v: &[StripVertex],
        h: &[Morph],
        view: &WantView,
        capacity: usize,
        stamp: &mut Vec<u8>,
    ) -> Result<Wants> {
        let mut read = Vec::new();
        let h = if h.len() == v.len() {
            h
        } else {
            exact_heights(&self.terrain, v, &mut read)?;
            &read
        };
        let g = self.file.grid();
        // Metres per level-0 texel, in the view's (possibly scaled) scene.
        let texels_per_post = [self.uv[1].abs() * g.width as f64, self.uv[3].abs() * g.height as f64];
        let unit_m = (view.spacing_m[0] / texels_per_post[0]).min(view.spacing_m[1] / texels_per_post[1]);
        Ok(plan_tiles(
            g.tiles(),
            g.coarsest_level(),
            |k, px, py| g.tile_at(k, px, py),
            |key| {
                let (k, tx, ty) = g.decode(key);
                let l = g.levels[k as usize];
                (k, tx, ty, l.tiles_x, l.tiles_y)
            },
            |k, tx, ty| g.key(k, tx, ty),
            v,
            h,
            view,
            unit_m,
            |p| self.texel_of(p.x as f64, p.y as f64),
            capacity,
            stamp,
        ))
    }
}

/// The cache's size: GPU memory for slots and table, and CPU → GPU bytes per frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CacheBudget {
    pub gpu_bytes: u64,
    pub upload_bytes_per_frame: u64,
    /// Slots the GPU allows at most (its texture-array layer limit).
    pub max_slots: u32,
}

/// One frame of the cache, as reported in flight statistics and the window's panel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct HeightCacheStats {
    /// Whether heights come from the cache (else the whole grid is resident, or nothing is drawn).
    pub cached: bool,
    /// The GPU memory budget and what the heights take of it now (resident slots and the table;
    /// the whole grid when resident), bytes.
    pub budget_bytes: u64,
    pub in_use_bytes: u64,
    pub tiles_resident: u64,
    /// Tiles uploaded this frame and their bytes (with the table when it changed).
    pub tiles_uploaded: u64,
    pub upload_bytes: u64,
    /// Tiles the strip wants now that are not resident: their fragments shade from a coarser level.
    pub fallbacks: u64,
    /// Tiles the strip wants now (with ancestors).
    pub wanted: u64,
    /// Tiles evicted this frame.
    pub evicted: u64,
    /// The render thread's time in the cache's step this frame (taking finished tiles and writing
    /// them and the table), microseconds: it never waits for the loader.
    pub step_us: u64,
}

/// What a frame writes: the filled tiles and, when it changed, the table.
pub type FrameUploads<'a, T> = (Vec<TileUpload<'a, T>>, Option<&'a [u32]>);

/// A filled tile for the renderer to write into slot `slot` (its `slot_side()²` texels).
pub struct TileUpload<'a, T> {
    pub slot: u32,
    pub texels: &'a [T],
}

const ABSENT: u8 = 0;
const LOADING: u8 = 1;
const RESIDENT: u8 = 2;

/// A filled tile on its way to the GPU.
struct Filled<T> {
    key: u32,
    texels: Vec<T>,
}

/// A strip to plan wants for.
struct WantJob {
    vertices: Vec<StripVertex>,
    heights: Vec<Morph>,
    view: WantView,
    seq: u64,
}

/// What the loader and the render thread share.
struct Shared<T> {
    job: Option<WantJob>,
    ready: VecDeque<Filled<T>>,
    /// Spent tile buffers, for reuse.
    spare: Vec<Vec<T>>,
    /// The newest plan's needed tiles (for counting fallbacks).
    needed: Vec<u32>,
    error: Option<Error>,
    /// The loader has a strip to plan or wanted tiles left to fill.
    busy: bool,
    closed: bool,
}

struct Link<T> {
    shared: Mutex<Shared<T>>,
    wake: Condvar,
    /// Per tile: ABSENT, LOADING (being filled or waiting in `ready`) or RESIDENT.
    state: Vec<AtomicU8>,
    /// Per tile: the sequence number of the newest plan that wanted it.
    wanted: Vec<AtomicU64>,
}

impl<T> Link<T> {
    fn lock(&self) -> MutexGuard<'_, Shared<T>> {
        self.shared.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The render thread's side of a tile cache: slots, the table, the loader thread.
pub struct TileCache<S: TileSet> {
    set: Arc<S>,
    budget: CacheBudget,
    slots: u32,
    /// Per slot: the tile in it.
    slot_key: Vec<Option<u32>>,
    free: Vec<u32>,
    /// The table the shaders read (header, then one entry per tile: 0 absent, else
    /// `slot + 1 | fade << 24`).
    table: Vec<u32>,
    table_dirty: bool,
    /// Slots fading in.
    fading: Vec<u32>,
    /// Tiles taken from the loader this frame (their buffers go back after the upload).
    taken: Vec<Filled<S::Texel>>,
    link: Arc<Link<S::Texel>>,
    seq: u64,
    loader: Option<JoinHandle<()>>,
    stats: HeightCacheStats,
}

/// The GPU height cache's CPU side: a terrain's heights as tiles.
pub type HeightCache = TileCache<TerrainTiles>;

impl HeightCache {
    /// A cache of `terrain`'s heights in tiles of `tile_cells` cells within `budget`, its coarsest
    /// tile filled now (into slot 0; the caller uploads it from [`Self::frame`]'s first call).
    pub fn new(terrain: Arc<TerrainFile>, tile_cells: u32, budget: CacheBudget) -> Result<HeightCache> {
        let grid = TileGrid::new(terrain.header().n, tile_cells)?;
        TileCache::of(TerrainTiles { terrain, grid }, budget, "height")
    }

    pub fn grid(&self) -> &TileGrid {
        &self.set.grid
    }
}

impl<S: TileSet> TileCache<S> {
    /// A cache of `set`'s tiles within `budget` (`what` names it in messages: "height",
    /// "imagery"), its coarsest tile filled now (into slot 0; the caller uploads it from
    /// [`Self::frame`]'s first call).
    pub fn of(set: S, budget: CacheBudget, what: &str) -> Result<TileCache<S>> {
        let set = Arc::new(set);
        let slot = set.slot_bytes();
        let fixed = set.table_bytes();
        // No more slots than tiles: a small set is held whole in what it needs.
        let slots = (budget.gpu_bytes.saturating_sub(fixed) / slot)
            .min(budget.max_slots as u64)
            .min(set.tiles().max(2) as u64) as u32;
        if slots < 2 {
            return Err(Error::InvalidArgument(format!(
                "a GPU {what} budget of {} bytes is too small: the cache needs at least {} (two tiles of {} bytes and a {}-byte table)",
                budget.gpu_bytes,
                2 * slot + fixed,
                slot,
                fixed
            )));
        }
        if budget.upload_bytes_per_frame < slot + fixed {
            return Err(Error::InvalidArgument(format!(
                "an upload budget of {} bytes per frame is too small for {what} tiles: one tile and the table take {} bytes",
                budget.upload_bytes_per_frame,
                slot + fixed
            )));
        }
        let tiles = set.tiles() as usize;
        let link = Arc::new(Link {
            shared: Mutex::new(Shared {
                job: None,
                ready: VecDeque::new(),
                spare: Vec::new(),
                needed: Vec::new(),
                error: None,
                busy: false,
                closed: false,
            }),
            wake: Condvar::new(),
            state: (0..tiles).map(|_| AtomicU8::new(ABSENT)).collect(),
            wanted: (0..tiles).map(|_| AtomicU64::new(0)).collect(),
        });
        // The coarsest tile: filled here, so the first frame has texels everywhere.
        let top = set.coarsest_key();
        let mut texels = vec![S::Texel::default(); (set.slot_side() * set.slot_side()) as usize];
        set.fill(top, &mut texels)?;
        link.state[top as usize].store(LOADING, Ordering::Relaxed);
        link.lock().ready.push_back(Filled { key: top, texels });
        let mut table = vec![0u32; (TABLE_HEADER + set.tiles()) as usize];
        table[..TABLE_HEADER as usize].copy_from_slice(&set.header());
        let (g, l) = (set.clone(), link.clone());
        // The plan names the coarsest tile too (every tile's last ancestor): the pool holds it all.
        let capacity = slots as usize;
        let loader = std::thread::Builder::new()
            .name(format!("relief-{what}"))
            .spawn(move || load(&*g, &l, capacity))
            .map_err(Error::thread(format!("{what} loader")))?;
        let stats = HeightCacheStats { cached: true, budget_bytes: budget.gpu_bytes, ..Default::default() };
        Ok(TileCache {
            set,
            budget,
            slots,
            slot_key: vec![None; slots as usize],
            free: (0..slots).rev().collect(),
            table,
            table_dirty: true,
            fading: Vec::new(),
            taken: Vec::new(),
            link,
            seq: 0,
            loader: Some(loader),
            stats,
        })
    }

    /// What the cache holds tiles of.
    pub fn set(&self) -> &S {
        &self.set
    }

    /// Slots in the pool (GPU texture layers).
    pub fn slots(&self) -> u32 {
        self.slots
    }

    /// GPU bytes the pool and table take (allocated once, ≤ the budget).
    pub fn pool_bytes(&self) -> u64 {
        self.slots as u64 * self.set.slot_bytes() + self.set.table_bytes()
    }

    /// The table as the shaders read it.
    pub fn table(&self) -> &[u32] {
        &self.table
    }

    /// Hands a new strip (vertices and their exact heights) seen from `view` to the loader.
    pub fn want(&mut self, vertices: &[StripVertex], heights: &[Morph], view: WantView) {
        self.seq += 1;
        let mut s = self.link.lock();
        let (mut v, mut h) = match s.job.take() {
            Some(old) => (old.vertices, old.heights),
            None => (Vec::new(), Vec::new()),
        };
        v.clear();
        v.extend_from_slice(vertices);
        h.clear();
        h.extend_from_slice(heights);
        s.job = Some(WantJob { vertices: v, heights: h, view, seq: self.seq });
        s.busy = true;
        drop(s);
        self.link.wake.notify_all();
    }

    /// The render thread's step: takes the finished tiles that fit this frame's upload budget
    /// (never waiting), places them (evicting the least recently wanted), advances the blends,
    /// and returns what to write: the tiles and, when it changed, the table. Call
    /// [`Self::uploaded`] once they are written.
    pub fn frame(&mut self) -> Result<FrameUploads<'_, S::Texel>> {
        self.recycle();
        let mut stats = HeightCacheStats { cached: true, budget_bytes: self.budget.gpu_bytes, ..Default::default() };
        // Blends advance first, so a tile placed now shows from 0.
        let step = 255u32.div_ceil(FADE_FRAMES);
        let (table, mut blended) = (&mut self.table, false);
        self.fading.retain(|&slot| {
            let Some(key) = self.slot_key[slot as usize] else { return false };
            let e = &mut table[(TABLE_HEADER + key) as usize];
            let fade = ((*e >> 24) + step).min(255);
            *e = (*e & 0x00ff_ffff) | fade << 24;
            blended = true;
            fade < 255
        });
        // Every step goes to the GPU, the last one (to 255) included.
        self.table_dirty |= blended;
        let (slot_bytes, table_bytes) = (self.set.slot_bytes(), self.set.table_bytes());
        let mut room = self.budget.upload_bytes_per_frame.saturating_sub(table_bytes);
        {
            let mut s = self.link.lock();
            if let Some(e) = s.error.take() {
                return Err(e);
            }
            while room >= slot_bytes {
                let Some(f) = s.ready.pop_front() else { break };
                self.taken.push(f);
                room -= slot_bytes;
            }
        }
        if !self.taken.is_empty() {
            self.link.wake.notify_all();
        }
        let mut placed = Vec::with_capacity(self.taken.len());
        for i in 0..self.taken.len() {
            let key = self.taken[i].key;
            match self.place(key, &mut stats) {
                Some(slot) => placed.push((i, slot)),
                None => self.link.state[key as usize].store(ABSENT, Ordering::Release),
            }
        }
        stats.tiles_uploaded = placed.len() as u64;
        if !placed.is_empty() {
            self.table_dirty = true;
        }
        let resident = self.slot_key.iter().filter(|k| k.is_some()).count() as u64;
        stats.tiles_resident = resident;
        stats.in_use_bytes = resident * slot_bytes + table_bytes;
        {
            let s = self.link.lock();
            stats.wanted = s.needed.len() as u64;
            let absent = |&&k: &&u32| self.link.state[k as usize].load(Ordering::Relaxed) != RESIDENT;
            stats.fallbacks = s.needed.iter().filter(absent).count() as u64;
        }
        stats.upload_bytes = placed.len() as u64 * slot_bytes + if self.table_dirty { table_bytes } else { 0 };
        self.stats = stats;
        let uploads = placed.into_iter().map(|(i, slot)| TileUpload { slot, texels: &self.taken[i].texels }).collect();
        let table = if std::mem::take(&mut self.table_dirty) { Some(&self.table[..]) } else { None };
        Ok((uploads, table))
    }

    /// A slot for tile `key` (free, else the least recently wanted tile's), its table entry set at
    /// fade 0; `None` when every slot holds a tile wanted at least as recently (the tile is dropped).
    fn place(&mut self, key: u32, stats: &mut HeightCacheStats) -> Option<u32> {
        let link = self.link.clone();
        let wanted = |k: u32| link.wanted[k as usize].load(Ordering::Relaxed);
        let top = self.set.coarsest_key();
        let slot = match self.free.pop() {
            Some(s) => s,
            None => {
                let (slot, victim) = self
                    .slot_key
                    .iter()
                    .enumerate()
                    .filter_map(|(s, k)| k.filter(|&k| k != top).map(|k| (s as u32, k)))
                    .min_by_key(|&(_, k)| wanted(k))?;
                if wanted(victim) >= wanted(key) {
                    return None;
                }
                self.table[(TABLE_HEADER + victim) as usize] = 0;
                self.link.state[victim as usize].store(ABSENT, Ordering::Release);
                self.slot_key[slot as usize] = None;
                stats.evicted += 1;
                slot
            }
        };
        self.slot_key[slot as usize] = Some(key);
        // A reused slot may still be fading in for its old tile.
        self.fading.retain(|&s| s != slot);
        // The coarsest tile has nothing to blend from: it shows at once.
        let fade = if key == top { 255 } else { 0 };
        self.table[(TABLE_HEADER + key) as usize] = (slot + 1) | fade << 24;
        if fade < 255 {
            self.fading.push(slot);
        }
        self.link.state[key as usize].store(RESIDENT, Ordering::Release);
        Some(slot)
    }

    /// Gives the tiles of the last [`Self::frame`] back to the loader once they are written.
    pub fn uploaded(&mut self) {
        self.recycle();
    }

    fn recycle(&mut self) {
        if self.taken.is_empty() {
            return;
        }
        let mut s = self.link.lock();
        for f in self.taken.drain(..) {
            if s.spare.len() < 8 {
                s.spare.push(f.texels);
            }
        }
    }

    /// The last frame's figures.
    pub fn stats(&self) -> HeightCacheStats {
        self.stats
    }

    /// Whether the loader has nothing left to do for the newest strip: every wanted tile that fits
    /// is resident or was dropped, and nothing waits for upload.
    pub fn settled(&self) -> bool {
        let s = self.link.lock();
        !s.busy && s.job.is_none() && s.ready.is_empty() && self.taken.is_empty()
    }

    /// [`Self::settled`], and every placed tile has finished blending in.
    pub fn converged(&self) -> bool {
        self.fading.is_empty() && self.settled()
    }

    /// The tile in each slot (tests).
    pub fn slot_keys(&self) -> &[Option<u32>] {
        &self.slot_key
    }
}

impl<S: TileSet> Drop for TileCache<S> {
    fn drop(&mut self) {
        self.link.lock().closed = true;
        self.link.wake.notify_all();
        if let Some(h) = self.loader.take() {
            let _ = h.join();
        }
    }
}

/// Filled tiles waiting for upload at most (bounded CPU memory).
const READY_MAX: usize = 64;

/// The loader thread: plans each new strip's wants and fills the wanted tiles that are absent,
/// in priority order, until the plan is done or a newer strip arrives.
fn load<S: TileSet>(set: &S, link: &Link<S::Texel>, capacity: usize) {
    let mut stamp = Vec::new();
    let mut plan: Vec<u32> = Vec::new();
    let mut next = 0usize;
    let side = (set.slot_side() * set.slot_side()) as usize;
    loop {
        let job = {
            let mut s = link.lock();
            loop {
                if s.closed {
                    return;
                }
                if let Some(job) = s.job.take() {
                    break Some(job);
                }
                if next < plan.len() && s.ready.len() < READY_MAX {
                    break None;
                }
                s.busy = next < plan.len();
                s = link.wake.wait(s).unwrap_or_else(|p| p.into_inner());
            }
        };
        if let Some(job) = job {
            let wants = match set.plan(&job.vertices, &job.heights, &job.view, capacity, &mut stamp) {
                Ok(w) => w,
                Err(e) => {
                    link.lock().error.get_or_insert(e);
                    plan.clear();
                    continue;
                }
            };
            for &k in &wants.keys {
                link.wanted[k as usize].store(job.seq, Ordering::Relaxed);
            }
            // The coarsest tile is always wanted (never evicted).
            link.wanted[set.coarsest_key() as usize].store(u64::MAX, Ordering::Relaxed);
            link.lock().needed = wants.needed;
            plan = wants.keys;
            next = 0;
            continue;
        }
        while next < plan.len() && link.state[plan[next] as usize].load(Ordering::Acquire) != ABSENT {
            next += 1;
        }
        let Some(&key) = plan.get(next) else { continue };
        next += 1;
        link.state[key as usize].store(LOADING, Ordering::Release);
        let mut texels = link.lock().spare.pop().unwrap_or_default();
        texels.resize(side, S::Texel::default());
        match set.fill(key, &mut texels) {
            Ok(()) => link.lock().ready.push_back(Filled { key, texels }),
            Err(e) => {
                link.state[key as usize].store(ABSENT, Ordering::Release);
                link.lock().error.get_or_insert(e);
                plan.clear();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_end_in_one_tile_and_keys_are_a_bijection() {
        // 2^10 + 1 posts in tiles of 64 cells: levels 0..=4 with 16, 8, 4, 2, 1 tiles a side.
        let g = TileGrid::new(10, 64).unwrap();
        assert_eq!(g.levels(), 5);
        assert_eq!((0..5).map(|k| g.tiles_per_side(k)).collect::<Vec<_>>(), [16, 8, 4, 2, 1]);
        assert_eq!(g.tiles(), 256 + 64 + 16 + 4 + 1);
        let mut seen = vec![false; g.tiles() as usize];
        for k in 0..g.levels() {
            for ty in 0..g.tiles_per_side(k) {
                for tx in 0..g.tiles_per_side(k) {
                    let key = g.key(k, tx, ty);
                    assert_eq!(g.decode(key), (k, tx, ty));
                    assert!(!std::mem::replace(&mut seen[key as usize], true));
                }
            }
        }
        assert!(seen.iter().all(|&s| s));
        // A grid smaller than a tile is one level of one tile.
        let small = TileGrid::new(5, 64).unwrap();
        assert_eq!((small.levels(), small.tiles()), (1, 1));
        assert!(TileGrid::new(10, 48).is_err());
        assert!(TileGrid::new(40, 4).is_err());
    }

    /// Every cell's 4 × 4 neighbourhood of posts (what the shader reads around a fragment) lies in
    /// the slot of the tile `tile_at` names, at the texel the shader computes.
    #[test]
    fn a_tile_holds_every_post_its_fragments_read() {
        let g = TileGrid::new(8, 16).unwrap();
        for k in 0..g.levels() {
            let last = g.last_post(k);
            for cy in 0..last {
                for cx in 0..last {
                    let (gx, gy) = (((cx << k) as f64) + 0.5, ((cy << k) as f64) + 0.25);
                    let key = g.tile_at(k, gx, gy);
                    let (kk, tx, ty) = g.decode(key);
                    assert_eq!(kk, k);
                    for dy in -1i64..=2 {
                        for dx in -1i64..=2 {
                            let (px, py) =
                                ((cx as i64 + dx).clamp(0, last as i64), (cy as i64 + dy).clamp(0, last as i64));
                            let (i, j) = (px - ((tx as i64) * 16 - 1), py - ((ty as i64) * 16 - 1));
                            assert!((0..19).contains(&i) && (0..19).contains(&j), "level {k} cell {cx},{cy}");
                            assert_eq!(g.texel_post(key, i as u32, j as u32), ((px as u32) << k, (py as u32) << k));
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn levels_follow_projected_post_size() {
        let cam = Camera::new(glam::DVec3::ZERO, glam::DVec3::X, glam::DVec3::Z, 60.0, 100, 100).unwrap();
        let v = WantView { px_per_rad: 1000.0, ..WantView::new(&cam, [10.0, 10.0]) };
        // A post of 10 m at 10 km is 1 px: level 0 below 20 km, then one level per doubling.
        assert_eq!(v.level_at(5_000.0, 7), 0);
        assert_eq!(v.level_at(19_999.0, 7), 0);
        assert_eq!(v.level_at(20_000.0, 7), 1);
        assert_eq!(v.level_at(80_000.0, 7), 3);
        assert_eq!(v.level_at(1e12, 7), 7);
        assert_eq!(v.level_at(f64::NAN, 7), 0);
    }

    #[test]
    fn wants_put_ancestors_first_and_stop_at_the_capacity() {
        let g = TileGrid::new(10, 64).unwrap();
        // Looking north-east over the grid from above its corner.
        let eye = glam::DVec3::new(0.0, 0.0, 100.0);
        let cam = Camera::new(eye, glam::DVec3::new(1000.0, 1000.0, 0.0), glam::DVec3::Z, 90.0, 100, 100).unwrap();
        let v = WantView { px_per_rad: 1000.0, ..WantView::new(&cam, [1.0, 1.0]) };
        let verts = [StripVertex { x: 10, y: 10 }, StripVertex { x: 1000, y: 1000 }];
        let heights = [Morph { blend: 1.0, z_m: 0.0 }; 2];
        let mut stamp = Vec::new();
        let w = plan_wants(&g, &verts, &heights, &v, 1000, &mut stamp);
        // The near vertex wants level 0 and its 4 ancestors; the far one (1.4 km: 1.4 px posts)
        // level 0 as well, sharing the coarsest tile.
        assert_eq!(w.needed.len(), 9);
        assert_eq!(w.needed[..], w.keys[..9]);
        let levels: Vec<u32> = w.needed.iter().map(|&k| g.decode(k).0).collect();
        assert!(levels.windows(2).all(|p| p[0] >= p[1]), "coarse first: {levels:?}");
        assert_eq!(w.keys[0], g.key(4, 0, 0));
        let unique: std::collections::HashSet<_> = w.keys.iter().collect();
        assert_eq!(unique.len(), w.keys.len());
        // Behind the camera, a vertex wants nothing.
        let behind = [StripVertex { x: 1000, y: 1000 }];
        let back = WantView { basis: v.basis.map(|b| -b), ..v };
        let near_only = plan_wants(
            &g,
            &behind,
            &heights[..1],
            &WantView { eye_in_world: glam::DVec3::new(-3000.0, -3000.0, 100.0), ..back },
            1000,
            &mut stamp,
        );
        assert!(near_only.keys.is_empty());
        let cut = plan_wants(&g, &verts, &heights, &v, 3, &mut stamp);
        assert_eq!((cut.keys.len(), cut.needed.len()), (3, 9));
        assert_eq!(cut.keys[..], w.keys[..3]);
    }
}
