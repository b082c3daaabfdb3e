//! Sharded conversion: the nested bounds of Lindstrom & Pascucci (2001, §4) computed block by
//! block on many processes or machines, then merged into the one terrain file a single process
//! writes, byte for byte (ARCHITECTURE.md, "Sharded conversion").
//!
//! **Partition.** The grid is cut into square blocks of `2^b` posts (the last row and column
//! belong to the last blocks). A block *owns* its vertices of the fine levels `1..=2c`, those
//! with a coordinate that is not a multiple of the lattice step `g = 2^c`; the coarse levels
//! `2c + 1..=2n` live on that lattice, `(2^n / g + 1)²` vertices, and are the merge's. Shards
//! are runs of blocks in Morton order, balanced by posts.
//!
//! **Exactness.** A vertex's nested error is the maximum of its descendants' raw errors, and its
//! radius a maximum over descendant paths, rounded up to f32 at each level; maximum and that
//! rounding are monotone, so the value over all descendants is the maximum of *partial* values,
//! each computed with the same recurrence over the descendants in one block's reach. A block
//! computes every vertex within `3·step` of it at each fine level (no descendant is farther
//! from a vertex of that step), flags those with a descendant in the block (*relevant*), and
//! hands the merge its own vertices' partial records and its relevant foreign vertices' partial
//! bounds; the merge takes maxima. Heights are never partial, so the coarse levels are then
//! computed from the lattice's heights and the top fine level's (merged) bounds by the very
//! loop of [`super::bounds`] (through [`LevelRows`]), and every record equals the single pass's.
//!
//! The DEM must be free of nodata: filling a void reads the nearest valid post along its whole
//! row and column, which no block's window holds; such DEMs are converted in one process.

use std::cell::Cell;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use super::bounds::{level_row, level_rows, LevelRows};
use super::convert::{finish_file, header_template, prepare, stored_pages, ConvertOptions, PresentPages};
use crate::dem::{self, Run};
use crate::error::FileKind;
use crate::error::{Error, IoContext, Result};
use crate::format::shard::{ShardHeader, ENTRY_BYTES, SECTIONS_AT};
use crate::format::terrain::{self, Header, Record, RECORD_BYTES};
use crate::format::{decode_header, file_error, Format, Problem, HEADER_BYTES};
use crate::layout::hierarchy::Grid;
use crate::layout::{AnyLayout, Layout, LayoutVisitor, Stored};
use crate::sys::cancel;
use crate::sys::mem::AnonSampler;
use crate::sys::progress::Progress;

/// How the grid is cut: blocks of `2^block_bits` posts, coarse lattice step `2^lattice_bits`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ShardPlan {
    pub grid: Grid,
    pub width: u32,
    pub height: u32,
    pub block_bits: u32,
    pub lattice_bits: u32,
}

/// The x positions of `level`'s vertices on row `y`: first, stride, last possible.
#[inline]
fn level_xs(grid: Grid, level: u32, y: u32) -> (u32, u32, u32) {
    let m = grid.max_coord();
    let step = 1u32 << ((level - 1) / 2);
    if level % 2 == 1 && !(y / step).is_multiple_of(2) {
        (0, 2 * step, m) // vertical-edge midpoints
    } else {
        (step, 2 * step, m - 1) // horizontal-edge midpoints, square centres
    }
}

/// Calls `f(x, y)` for every stored vertex of `level` in `[x0, x1] × [y0, y1]`.
fn for_level(grid: Grid, stored: &Stored, level: u32, [x0, x1, y0, y1]: [u32; 4], mut f: impl FnMut(u32, u32)) {
    let xmax = stored.max_at(level).0.min(x1);
    for y in level_rows(grid, stored, level).filter(|y| (y0..=y1).contains(y)) {
        let (first, stride, last) = level_xs(grid, level, y);
        let mut x = if x0 <= first { first } else { first + (x0 - first).div_ceil(stride) * stride };
        while x <= last && x <= xmax {
            f(x, y);
            x += stride;
        }
    }
}

/// Bit-interleaved order of block `(bx, by)`.
fn morton(bx: u32, by: u32) -> u64 {
    let spread = |v: u32| (0..32).fold(0u64, |acc, k| acc | (((v >> k) & 1) as u64) << (2 * k));
    spread(bx) | spread(by) << 1
}

impl ShardPlan {
    /// The plan of a `width × height` DEM on `grid`: about 256 blocks, each between 64 and 4096
    /// posts a side, and a lattice 64 times finer than a block (at least 2).
    pub fn new(grid: Grid, width: u32, height: u32) -> Result<ShardPlan> {
        let n = grid.n();
        if n < 2 {
            return Err(Error::InvalidArgument(format!(
                "a {w}x{h} DEM is too small to shard (a {s}² grid); convert it in one process",
                w = width,
                h = height,
                s = grid.size()
            )));
        }
        let block_bits = n.saturating_sub(4).clamp(6, 12).min(n);
        let lattice_bits = block_bits.saturating_sub(6).clamp(1, n - 1);
        Ok(ShardPlan { grid, width, height, block_bits, lattice_bits })
    }

    fn g(&self) -> u32 {
        1 << self.lattice_bits
    }

    /// Levels the blocks compute.
    fn fine_levels(&self) -> u32 {
        2 * self.lattice_bits
    }

    fn per_side(&self) -> u32 {
        1 << (self.grid.n() - self.block_bits)
    }

    /// The vertices block `(bx, by)` owns: `[x0, x1, y0, y1]`, inclusive.
    fn owned(&self, bx: u32, by: u32) -> [u32; 4] {
        let (b, m, last) = (1u32 << self.block_bits, self.grid.max_coord(), self.per_side() - 1);
        let end = |k: u32| if k == last { m } else { (k + 1) * b - 1 };
        [bx * b, end(bx), by * b, end(by)]
    }

    /// Blocks with stored fine vertices, in Morton order, each with its weight (DEM posts).
    fn blocks(&self) -> Vec<(u32, u32, u64)> {
        let stored = Stored::new(self.grid, self.width, self.height);
        let (xmax, ymax) = stored.max_at(self.fine_levels());
        let mut blocks = Vec::new();
        for by in 0..self.per_side() {
            for bx in 0..self.per_side() {
                let [x0, x1, y0, y1] = self.owned(bx, by);
                if x0 <= xmax && y0 <= ymax {
                    let w = (x1.min(self.width - 1) + 1).saturating_sub(x0) as u64;
                    let h = (y1.min(self.height - 1) + 1).saturating_sub(y0) as u64;
                    blocks.push((bx, by, (w * h).max(1)));
                }
            }
        }
        blocks.sort_by_key(|&(bx, by, _)| morton(bx, by));
        blocks
    }

    /// The blocks of shard `shard` of `shards`: a run in Morton order whose posts are about
    /// `1/shards` of all.
    pub fn blocks_of(&self, shard: u32, shards: u32) -> Vec<(u32, u32)> {
        let blocks = self.blocks();
        let total: u128 = blocks.iter().map(|b| b.2 as u128).sum();
        let mut before = 0u128;
        let mut mine = Vec::new();
        for (bx, by, w) in blocks {
            let owner = (((2 * before + w as u128) * shards as u128) / (2 * total)).min(shards as u128 - 1);
            if owner == shard as u128 {
                mine.push((bx, by));
            }
            before += w as u128;
        }
        mine
    }
}

/// What `relief convert --shard` did, for `--json`.
#[derive(Clone, Debug, Serialize)]
pub struct ShardReport {
    pub output: PathBuf,
    pub shard: u32,
    pub shards: u32,
    pub blocks: u32,
    pub block_side: u32,
    /// DEM posts the shard held (its blocks and their reach), of the DEM's `dem_posts`.
    pub window_posts: u64,
    pub dem_posts: u64,
    /// Vertices whose records this shard wrote.
    pub vertices: u64,
    pub foreign: u64,
    pub file_bytes: u64,
    pub seconds: f64,
    pub read_seconds: f64,
    pub vertices_per_s: f64,
    pub peak_rss_anon_bytes: u64,
}

/// Heights of a window of DEM posts `[x0, x1] × [y0, y1]` (grid rows from the south), metres.
struct HeightWindow {
    x0: u32,
    y0: u32,
    w: u32,
    h: u32,
    dem_w: u32,
    dem_h: u32,
    z: Vec<f32>,
}

impl HeightWindow {
    /// Grid post `(x, y)`'s height: beyond the DEM, its nearest edge post's.
    #[inline]
    fn at(&self, x: u32, y: u32) -> f32 {
        let (x, y) = (x.min(self.dem_w - 1) - self.x0, y.min(self.dem_h - 1) - self.y0);
        debug_assert!(x < self.w && y < self.h);
        self.z[y as usize * self.w as usize + x as usize]
    }
}

#[derive(Clone, Copy, Default)]
struct Slot {
    bounds: [f32; 2],
    relevant: bool,
    held: bool,
}

/// One block's pass: bounds over the block and its reach.
struct BlockRows<'a> {
    heights: &'a HeightWindow,
    owned: [u32; 4],
    ax0: u32,
    ay0: u32,
    aw: u32,
    ah: u32,
    slots: Vec<Cell<Slot>>,
}

impl BlockRows<'_> {
    #[inline]
    fn slot(&self, x: u32, y: u32) -> Option<&Cell<Slot>> {
        let (dx, dy) = (x.wrapping_sub(self.ax0), y.wrapping_sub(self.ay0));
        (dx < self.aw && dy < self.ah).then(|| &self.slots[dy as usize * self.aw as usize + dx as usize])
    }
    fn owns(&self, x: u32, y: u32) -> bool {
        let [x0, x1, y0, y1] = self.owned;
        (x0..=x1).contains(&x) && (y0..=y1).contains(&y)
    }
}

impl LevelRows for BlockRows<'_> {
    #[inline]
    fn z(&self, x: u32, y: u32) -> f32 {
        self.heights.at(x, y)
    }
    #[inline]
    fn child(&self, x: u32, y: u32) -> Option<([f32; 2], bool)> {
        let s = self.slot(x, y)?.get();
        s.held.then_some((s.bounds, s.relevant))
    }
    #[inline]
    fn set(&self, x: u32, y: u32, error: f32, radius: f32, relevant: bool) {
        if let Some(slot) = self.slot(x, y) {
            slot.set(Slot { bounds: [error, radius], relevant: relevant || self.owns(x, y), held: true });
        }
    }
}

/// What one block hands on.
#[derive(Default)]
struct BlockOut {
    /// Its vertices' records, in index order, and their runs `(first index, length)`.
    records: Vec<Record>,
    runs: Vec<(u64, u64)>,
    foreign: Vec<(u64, f32, f32)>,
    centres: Vec<(u32, u32, f32, f32, f32)>,
    posts: Vec<(u32, u32, f32)>,
}

/// Layout indices of positions (monomorphised per layout).
fn indices(layout: &AnyLayout, at: &[(u32, u32)]) -> Vec<u64> {
    struct Index<'a>(&'a [(u32, u32)]);
    impl LayoutVisitor for Index<'_> {
        type Output = Vec<u64>;
        fn visit<L: Layout>(self, layout: &L) -> Vec<u64> {
            self.0.iter().map(|&(x, y)| layout.index(x, y)).collect()
        }
    }
    layout.visit(Index(at))
}

/// The coarse lattice's posts along one axis: multiples of `g` below `len`, and `len − 1`.
fn lattice_posts(len: u32, g: u32) -> u32 {
    (len - 1) / g + 1 + !(len - 1).is_multiple_of(g) as u32
}

fn lattice_post_index(p: u32, g: u32, count: u32) -> u32 {
    if p.is_multiple_of(g) {
        p / g
    } else {
        count - 1
    }
}

fn compute_block(
    plan: &ShardPlan,
    stored: &Stored,
    layout: &AnyLayout,
    spacing_m: [f64; 2],
    heights: &HeightWindow,
    (bx, by): (u32, u32),
) -> BlockOut {
    let grid = plan.grid;
    let (m, g) = (grid.max_coord(), plan.g());
    let owned = plan.owned(bx, by);
    let [ox0, ox1, oy0, oy1] = owned;
    let reach = 3 * g / 2; // 3·step at the top fine level (step g/2)
    let (ax0, ay0) = (ox0.saturating_sub(reach), oy0.saturating_sub(reach));
    let (ax1, ay1) = ((ox1 + reach).min(m), (oy1 + reach).min(m));
    let (aw, ah) = (ax1 - ax0 + 1, ay1 - ay0 + 1);
    let rows = BlockRows {
        heights,
        owned,
        ax0,
        ay0,
        aw,
        ah,
        slots: (0..aw as usize * ah as usize).map(|_| Cell::new(Slot::default())).collect(),
    };
    let window = |level: u32| {
        let r = 3 * (1u32 << ((level - 1) / 2));
        [ox0.saturating_sub(r), (ox1 + r).min(m), oy0.saturating_sub(r), (oy1 + r).min(m)]
    };
    for level in 1..=plan.fine_levels() {
        let [x0, x1, y0, y1] = window(level);
        for y in level_rows(grid, stored, level).filter(|y| (y0..=y1).contains(y)) {
            level_row(grid, stored, spacing_m, &rows, level, y, (x0, x1));
        }
    }
    let mut own: Vec<((u32, u32), Record)> = Vec::new();
    let mut foreign_at: Vec<(u32, u32)> = Vec::new();
    let mut foreign_bounds: Vec<[f32; 2]> = Vec::new();
    let mut out = BlockOut::default();
    for level in 1..=plan.fine_levels() {
        for_level(grid, stored, level, window(level), |x, y| {
            let Some(s) = rows.slot(x, y).map(Cell::get).filter(|s| s.held) else { return };
            let [error, radius] = s.bounds;
            if rows.owns(x, y) {
                let z = heights.at(x, y);
                own.push(((x, y), Record { z, error, radius }));
                if level == plan.fine_levels() {
                    out.centres.push((x, y, z, error, radius));
                }
            } else if s.relevant {
                foreign_at.push((x, y));
                foreign_bounds.push(s.bounds);
            }
        });
    }
    let at: Vec<(u32, u32)> = own.iter().map(|o| o.0).collect();
    let mut keyed: Vec<(u64, Record)> = indices(layout, &at).into_iter().zip(own.into_iter().map(|o| o.1)).collect();
    keyed.sort_unstable_by_key(|k| k.0);
    for (i, r) in keyed {
        match out.runs.last_mut() {
            Some(run) if run.0 + run.1 == i => run.1 += 1,
            _ => out.runs.push((i, 1)),
        }
        out.records.push(r);
    }
    out.foreign = indices(layout, &foreign_at).into_iter().zip(foreign_bounds).map(|(i, [e, r])| (i, e, r)).collect();
    // The lattice posts in the block (heights of the coarse levels, clamped as they read them).
    let (nx, ny) = (lattice_posts(plan.width, g), lattice_posts(plan.height, g));
    for j in 0..ny {
        let y = if j == ny - 1 { plan.height - 1 } else { j * g };
        if !(oy0..=oy1).contains(&y) {
            continue;
        }
        for i in 0..nx {
            let x = if i == nx - 1 { plan.width - 1 } else { i * g };
            if (ox0..=ox1).contains(&x) {
                out.posts.push((x, y, heights.at(x, y)));
            }
        }
    }
    out
}

/// Where a shard's blocks read heights: their owned posts and `2g` around, within the DEM.
fn height_window(plan: &ShardPlan, blocks: &[(u32, u32)]) -> Option<[u32; 4]> {
    let reach = 2 * plan.g();
    let (wl, hl) = (plan.width - 1, plan.height - 1);
    blocks.iter().map(|&(bx, by)| plan.owned(bx, by)).fold(None, |acc, [x0, x1, y0, y1]| {
        let w = [
            x0.saturating_sub(reach).min(wl),
            (x1 + reach).min(wl),
            y0.saturating_sub(reach).min(hl),
            (y1 + reach).min(hl),
        ];
        Some(match acc {
            None => w,
            Some([a, b, c, d]) => [a.min(w[0]), b.max(w[1]), c.min(w[2]), d.max(w[3])],
        })
    })
}

/// Opens the conversion's source: one DEM, or a mosaic of tiles (files or directories).
fn open_inputs(inputs: &[PathBuf], opts: &ConvertOptions) -> Result<Box<dyn dem::DemSource>> {
    let Some(first) = inputs.first() else { return Err(Error::InvalidArgument("no input DEM".into())) };
    if inputs.len() == 1 && !first.is_dir() {
        return dem::open_with(first, opts.open_options());
    }
    let tiles = dem::expand_inputs(inputs)?;
    Ok(Box::new(dem::Mosaic::open(&tiles, opts.open_options())?))
}

/// Runs shard `shard` of `shards` of converting `inputs` (as [`super::convert::convert_many`]
/// would) and writes its shard file to `output` (atomically: a shard killed mid-way leaves no
/// file there). `after_block` is called after each batch of blocks is written (tests use it to
/// kill a shard mid-way).
pub fn convert_shard(
    inputs: &[PathBuf],
    output: &Path,
    opts: &ConvertOptions,
    (shard, shards): (u32, u32),
    after_block: &dyn Fn(u32),
) -> Result<ShardReport> {
    let started = Instant::now();
    let sampler = AnonSampler::start();
    if shards == 0 || shard >= shards {
        return Err(Error::InvalidArgument(format!("--shard {shard}/{shards}: expected I/N with 0 <= I < N")));
    }
    let label = inputs.first().cloned().unwrap_or_default();
    let source = open_inputs(inputs, opts)?;
    let p = prepare(&label, Some(source), output, opts)?;
    let mut source = p.source;
    let (width, height) = (p.info.width, p.info.height);
    let plan = ShardPlan::new(p.grid, width, height)?;
    let blocks = plan.blocks_of(shard, shards);
    let (spacing_m, _, flags, centre_lat, spacing_deg) = p.spacing;
    let template = header_template(&p.layout, &p.info, (spacing_m, flags, centre_lat, spacing_deg), p.z_scale, opts);

    // 1. The heights the shard's blocks read.
    let t = Instant::now();
    let window = height_window(&plan, &blocks).unwrap_or([0, 0, 0, 0]);
    let [hx0, hx1, hy0, hy1] = window;
    let (hw, hh) = (hx1 - hx0 + 1, hy1 - hy0 + 1);
    let mut heights = HeightWindow {
        x0: hx0,
        y0: hy0,
        w: hw,
        h: hh,
        dem_w: width,
        dem_h: height,
        z: vec![f32::NAN; hw as usize * hh as usize],
    };
    let (z_scale, z_offset) = (p.z_scale, opts.z_offset);
    let bar = opts.progress.bar("read", width as u64 * height as u64, "samples");
    let mut voids = 0u64;
    if !blocks.is_empty() {
        // Columns x, rows from the north.
        let rows = [hx0, height - 1 - hy1, hx1 + 1, height - hy0];
        source.read_window(rows, &mut |run: Run<'_>| {
            cancel::check()?;
            bar.inc(run.values.len() as u64);
            let end = run.x0 as u64 + run.values.len() as u64;
            if run.row >= height || end > width as u64 {
                return Err(Error::bad_dem(&label, format!("reader produced samples outside {width}x{height}")));
            }
            let y = height - 1 - run.row;
            if !(hy0..=hy1).contains(&y) {
                return Ok(());
            }
            let (a, b) = (run.x0.max(hx0), (end as u32).min(hx1 + 1));
            let row = (y - hy0) as usize * hw as usize;
            for x in a..b {
                let z = run.values[(x - run.x0) as usize] * z_scale + z_offset;
                if z.is_finite() {
                    heights.z[row + (x - hx0) as usize] = z as f32;
                } else {
                    voids += 1;
                }
            }
            Ok(())
        })?;
    }
    bar.finish_and_clear();
    if voids > 0 {
        return Err(Error::InvalidArgument(format!(
            "{}: {voids} nodata posts in shard {shard}/{shards}'s window: sharded conversion needs a DEM without nodata (filling a void reads whole rows and columns); convert it in one process",
            label.display()
        )));
    }
    let read_seconds = t.elapsed().as_secs_f64();

    // 2. The blocks, a batch per round of threads, written as they finish.
    let out_tmp = crate::sys::atomic_file::temp_beside(output)?;
    let mut file = std::io::BufWriter::with_capacity(1 << 20, out_tmp.reopen().at(output)?);
    let mut hasher = xxhash_rust::xxh3::Xxh3::new();
    let mut put = |file: &mut std::io::BufWriter<File>, bytes: &[u8]| -> Result<()> {
        hasher.update(bytes);
        file.write_all(bytes).at(output)
    };
    file.write_all(&[0u8; HEADER_BYTES]).at(output)?;
    put(&mut file, &Format::encode(&template).0)?;
    let stored = p.stored;
    let (mut runs, mut foreign, mut centres, mut posts) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut z_min, mut z_max) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut records = 0u64;
    let bar = opts.progress.bar("blocks", blocks.len() as u64, "blocks");
    let batch = rayon::current_num_threads().max(1);
    for (k, chunk) in blocks.chunks(batch).enumerate() {
        cancel::check()?;
        let outs: Vec<BlockOut> =
            chunk.par_iter().map(|&b| compute_block(&plan, &stored, &p.layout, spacing_m, &heights, b)).collect();
        for (o, &(bx, by)) in outs.into_iter().zip(chunk) {
            put(&mut file, bytemuck::cast_slice(&o.records))?;
            records += o.records.len() as u64;
            runs.extend(o.runs);
            foreign.extend(o.foreign);
            centres.extend(o.centres);
            posts.extend(o.posts);
            let [x0, x1, y0, y1] = plan.owned(bx, by);
            for y in y0..=y1.min(height - 1) {
                for x in x0..=x1.min(width - 1) {
                    let z = heights.at(x, y) as f64;
                    z_min = z_min.min(z);
                    z_max = z_max.max(z);
                }
            }
        }
        bar.inc(chunk.len() as u64);
        after_block(((k + 1) * batch).min(blocks.len()) as u32);
    }
    bar.finish_and_clear();
    let mut table = Vec::with_capacity(runs.len() * 16);
    for (i, n) in &runs {
        table.extend_from_slice(&i.to_le_bytes());
        table.extend_from_slice(&n.to_le_bytes());
    }
    put(&mut file, &table)?;
    let mut table = Vec::with_capacity(foreign.len() * 16);
    for (i, e, r) in &foreign {
        table.extend_from_slice(&i.to_le_bytes());
        table.extend_from_slice(&e.to_le_bytes());
        table.extend_from_slice(&r.to_le_bytes());
    }
    put(&mut file, &table)?;
    let mut table = Vec::with_capacity(centres.len() * 20);
    for (x, y, z, e, r) in &centres {
        for v in [x.to_le_bytes(), y.to_le_bytes(), z.to_le_bytes(), e.to_le_bytes(), r.to_le_bytes()] {
            table.extend_from_slice(&v);
        }
    }
    put(&mut file, &table)?;
    let mut table = Vec::with_capacity(posts.len() * 12);
    for (x, y, z) in &posts {
        for v in [x.to_le_bytes(), y.to_le_bytes(), z.to_le_bytes()] {
            table.extend_from_slice(&v);
        }
    }
    put(&mut file, &table)?;
    let counts = [records, runs.len() as u64, foreign.len() as u64, centres.len() as u64, posts.len() as u64];
    let (sections, file_len) = ShardHeader::layout(counts);
    let header = ShardHeader {
        shard,
        shards,
        block_bits: plan.block_bits,
        lattice_bits: plan.lattice_bits,
        blocks: blocks.len() as u32,
        z_min,
        z_max,
        sections,
        body_checksum: hasher.digest(),
        file_len,
    };
    let file = file.into_inner().map_err(|e| Error::io(output, e.into_error()))?;
    {
        use std::os::unix::fs::FileExt;
        file.write_all_at(&Format::encode(&header).0, 0).at(output)?;
    }
    file.sync_all().at(output)?;
    drop(file);
    out_tmp.persist(output).map_err(|e| Error::io(output, e.error))?;
    let seconds = started.elapsed().as_secs_f64();
    Ok(ShardReport {
        output: output.into(),
        shard,
        shards,
        blocks: blocks.len() as u32,
        block_side: 1 << plan.block_bits,
        window_posts: if blocks.is_empty() { 0 } else { hw as u64 * hh as u64 },
        dem_posts: width as u64 * height as u64,
        vertices: records,
        foreign: foreign.len() as u64,
        file_bytes: file_len,
        seconds,
        read_seconds,
        vertices_per_s: records as f64 / seconds,
        peak_rss_anon_bytes: sampler.finish(),
    })
}

/// What `relief convert --merge` did.
#[derive(Clone, Debug, Serialize)]
pub struct MergeReport {
    pub output: String,
    pub shards: u32,
    pub records: u64,
    pub coarse_vertices: u64,
    pub seam_bounds: u64,
    pub file_bytes: u64,
    pub payload_checksum: String,
    pub seconds: f64,
    pub peak_rss_anon_bytes: u64,
}

/// A shard file opened for the merge.
struct OpenShard {
    path: PathBuf,
    header: ShardHeader,
    map: memmap2::Mmap,
}

impl OpenShard {
    fn open(path: &Path) -> Result<OpenShard> {
        let file = File::open(path).map_err(|e| Error::io(path, e))?;
        let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        if len < SECTIONS_AT {
            return Err(file_error(path, FileKind::Shard, Problem::Truncated { expected: SECTIONS_AT, found: len }));
        }
        // SAFETY: shard files are written once, to a temporary renamed into place, and only
        // read afterwards; a file changed under the merge could give wrong bytes (caught by the
        // body checksum below, read through this same map) but not unsoundness beyond that of
        // any mapped file, which relief accepts for its inputs (ARCHITECTURE.md, "Files").
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|e| Error::io(path, e))?;
        let header: ShardHeader = decode_header(path, &map[..HEADER_BYTES], len)?;
        let computed = xxhash_rust::xxh3::xxh3_64(&map[HEADER_BYTES..]);
        if computed != header.body_checksum {
            let problem = Problem::Checksum { which: "body", stored: header.body_checksum, computed };
            return Err(file_error(path, FileKind::Shard, problem));
        }
        Ok(OpenShard { path: path.into(), header, map })
    }

    fn section(&self, k: usize) -> &[u8] {
        let (offset, count) = self.header.sections[k];
        &self.map[offset as usize..(offset + count * ENTRY_BYTES[k]) as usize]
    }

    fn template(&self) -> &[u8] {
        &self.map[HEADER_BYTES..2 * HEADER_BYTES]
    }

    fn records(&self) -> &[Record] {
        bytemuck::cast_slice(self.section(0))
    }
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}
fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}
fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_bits(u32_at(b, at))
}

/// The coarse levels' pass: lattice heights, the top fine level's merged bounds, and the
/// lattice vertices' bounds as they are computed.
struct CoarseRows {
    g: u32,
    width: u32,
    height: u32,
    /// Lattice posts (`lattice_posts` per axis), row-major.
    posts: Vec<f32>,
    nx: u32,
    /// Top-fine-level vertices `((2i + 1)·g/2, (2j + 1)·g/2)`: z, error, radius.
    centres: Vec<Option<[f32; 3]>>,
    nc: u32,
    /// Lattice vertices' bounds, `(2^n / g + 1)²`.
    lattice: Vec<Cell<Option<[f32; 2]>>>,
    nl: u32,
}

impl CoarseRows {
    fn centre(&self, x: u32, y: u32) -> Option<[f32; 3]> {
        let h = self.g / 2;
        let (i, j) = ((x - h) / self.g, (y - h) / self.g);
        self.centres.get(j as usize * self.nc as usize + i as usize).copied().flatten()
    }
}

impl LevelRows for CoarseRows {
    fn z(&self, x: u32, y: u32) -> f32 {
        if x.is_multiple_of(self.g) && y.is_multiple_of(self.g) {
            let ny = self.posts.len() as u32 / self.nx;
            let i = lattice_post_index(x.min(self.width - 1), self.g, self.nx);
            let j = lattice_post_index(y.min(self.height - 1), self.g, ny);
            self.posts[j as usize * self.nx as usize + i as usize]
        } else {
            self.centre(x, y).map_or(f32::NAN, |c| c[0])
        }
    }
    fn child(&self, x: u32, y: u32) -> Option<([f32; 2], bool)> {
        if x.is_multiple_of(self.g) && y.is_multiple_of(self.g) {
            let k = (y / self.g) as usize * self.nl as usize + (x / self.g) as usize;
            self.lattice[k].get().map(|b| (b, false))
        } else {
            self.centre(x, y).map(|c| ([c[1], c[2]], false))
        }
    }
    fn set(&self, x: u32, y: u32, error: f32, radius: f32, _relevant: bool) {
        let k = (y / self.g) as usize * self.nl as usize + (x / self.g) as usize;
        self.lattice[k].set(Some([error, radius]));
    }
}

/// Merges the shard files of one sharded conversion into the terrain file a single process
/// would have written. Every shard `0..N` must be given once; a missing, duplicated, foreign
/// (another conversion's) or damaged shard is an error naming it, and nothing is written.
///
/// `output` is a path, or `s3://bucket/key` (with `s3`'s endpoint and credentials): then the file
/// is assembled in place by a multipart upload whose parts are uploaded as they are made (the
/// first, holding the header, last), so no machine holds the whole file; on an error the
/// upload is aborted.
pub fn merge(
    shard_paths: &[PathBuf],
    output: &str,
    s3: &crate::pager::remote::S3Config,
    progress: &Progress,
) -> Result<MergeReport> {
    if output.starts_with("s3://") {
        let mut up = crate::pager::upload::MultipartUpload::start(output, s3)?;
        match merge_into(shard_paths, Out::Upload(&mut up, Vec::new(), 0), progress, output) {
            Ok(r) => {
                up.complete()?;
                Ok(r)
            }
            Err(e) => {
                up.abort();
                Err(e)
            }
        }
    } else {
        merge_into(shard_paths, Out::File(Path::new(output)), progress, output)
    }
}

/// Where the merge writes.
enum Out<'a> {
    File(&'a Path),
    /// The upload, the part being filled, parts uploaded.
    Upload(&'a mut crate::pager::upload::MultipartUpload, Vec<u8>, u16),
}

/// Bytes per uploaded part.
const PART_BYTES: usize = 8 << 20;

fn merge_into(shard_paths: &[PathBuf], out: Out<'_>, progress: &Progress, label: &str) -> Result<MergeReport> {
    let started = Instant::now();
    let sampler = AnonSampler::start();
    let Some(first_path) = shard_paths.first() else {
        return Err(Error::InvalidArgument("--merge: no shard files given".into()));
    };
    let mut shards: Vec<OpenShard> = shard_paths.iter().map(|p| OpenShard::open(p)).collect::<Result<_>>()?;
    let count = shards[0].header.shards;
    for s in &shards[1..] {
        if s.template() != shards[0].template() || s.header.shards != count {
            return Err(Error::InvalidArgument(format!(
                "{}: a shard of another conversion than {} (its terrain header or shard count differs)",
                s.path.display(),
                first_path.display()
            )));
        }
    }
    shards.sort_by_key(|s| s.header.shard);
    for w in shards.windows(2) {
        if w[0].header.shard == w[1].header.shard {
            return Err(Error::InvalidArgument(format!(
                "{} and {} are both shard {}/{count}",
                w[0].path.display(),
                w[1].path.display(),
                w[0].header.shard
            )));
        }
    }
    if let Some(missing) = (0..count).find(|&i| shards.get(i as usize).is_none_or(|s| s.header.shard != i)) {
        return Err(Error::InvalidArgument(format!(
            "shard {missing}/{count} is missing (given {} of {count} shards)",
            shards.len()
        )));
    }
    let template: Header = decode_header(&shards[0].path, shards[0].template(), u64::MAX)?;
    let grid = Grid::new(template.n).ok_or_else(|| Error::InvalidArgument("bad grid".into()))?;
    let [_, _, width, height] = template.valid_window;
    let plan = ShardPlan::new(grid, width, height)?;
    for s in &shards {
        if (s.header.block_bits, s.header.lattice_bits) != (plan.block_bits, plan.lattice_bits)
            || s.header.blocks as usize != plan.blocks_of(s.header.shard, count).len()
        {
            return Err(Error::InvalidArgument(format!(
                "{}: its blocks are not those of shard {}/{count} of this grid (made by another version?)",
                s.path.display(),
                s.header.shard
            )));
        }
    }
    let layout =
        AnyLayout::new(template.layout, grid, template.layout_param, RECORD_BYTES).map_err(Error::InvalidArgument)?;
    let stored = Stored::new(grid, width, height);
    let corrupt = |s: &OpenShard, what: String| file_error(&s.path, FileKind::Shard, Problem::Corrupt(what));

    // Runs of every shard, in index order: (first index, length, shard, first record).
    let mut runs: Vec<(u64, u64, usize, usize)> = Vec::new();
    for (k, s) in shards.iter().enumerate() {
        let table = s.section(1);
        let mut at = 0usize;
        for e in table.chunks_exact(16) {
            let (first, len) = (u64_at(e, 0), u64_at(e, 8));
            if first.checked_add(len).is_none_or(|end| end > layout.records()) {
                return Err(corrupt(s, format!("a run of records {first}+{len} outside the layout")));
            }
            runs.push((first, len, k, at));
            at += len as usize;
        }
        if at as u64 != s.header.sections[0].1 {
            return Err(corrupt(s, format!("runs of {at} records, but {} records", s.header.sections[0].1)));
        }
    }
    runs.sort_unstable_by_key(|r| r.0);
    if let Some(w) = runs.windows(2).find(|w| w[0].0 + w[0].1 > w[1].0) {
        return Err(corrupt(&shards[w[1].2], format!("records from index {} given twice", w[1].0)));
    }

    // Partial bounds of seam vertices: the maxima.
    let mut foreign: Vec<(u64, f32, f32)> = Vec::new();
    for s in &shards {
        foreign.extend(s.section(2).chunks_exact(16).map(|e| (u64_at(e, 0), f32_at(e, 8), f32_at(e, 12))));
    }
    foreign.sort_unstable_by_key(|f| f.0);
    foreign.dedup_by(|later, kept| {
        let same = later.0 == kept.0;
        if same {
            kept.1 = kept.1.max(later.1);
            kept.2 = kept.2.max(later.2);
        }
        same
    });
    let seam_of = |i: u64| foreign.binary_search_by_key(&i, |f| f.0).ok().map(|k| [foreign[k].1, foreign[k].2]);

    // 1. The coarse levels, from the lattice posts and the top fine level.
    let g = plan.g();
    let (nx, ny) = (lattice_posts(width, g), lattice_posts(height, g));
    let m = grid.max_coord();
    let (nc, nl) = (m / g, m / g + 1);
    let mut posts = vec![f32::NAN; nx as usize * ny as usize];
    let mut centre_list: Vec<(u32, u32, [f32; 3])> = Vec::new();
    for s in &shards {
        for e in s.section(4).chunks_exact(12) {
            let (x, y, z) = (u32_at(e, 0), u32_at(e, 4), f32_at(e, 8));
            let (i, j) = (lattice_post_index(x.min(width - 1), g, nx), lattice_post_index(y.min(height - 1), g, ny));
            posts[(j * nx + i) as usize] = z;
        }
        for e in s.section(3).chunks_exact(20) {
            let (x, y) = (u32_at(e, 0), u32_at(e, 4));
            if x % g != g / 2 || y % g != g / 2 || x >= m || y >= m {
                return Err(corrupt(s, format!("a top-level vertex at ({x}, {y}) is not one")));
            }
            centre_list.push((x, y, [f32_at(e, 8), f32_at(e, 12), f32_at(e, 16)]));
        }
    }
    if posts.iter().any(|z| z.is_nan()) {
        return Err(Error::InvalidArgument(
            "the shards do not hold every lattice post (a shard is from another plan)".into(),
        ));
    }
    let at: Vec<(u32, u32)> = centre_list.iter().map(|c| (c.0, c.1)).collect();
    let mut centres = vec![None; nc as usize * nc as usize];
    for (i, (x, y, mut c)) in indices(&layout, &at).into_iter().zip(centre_list) {
        if let Some([e, r]) = seam_of(i) {
            (c[1], c[2]) = (c[1].max(e), c[2].max(r));
        }
        centres[((y - g / 2) / g * nc + (x - g / 2) / g) as usize] = Some(c);
    }
    let coarse = CoarseRows {
        g,
        width,
        height,
        posts,
        nx,
        centres,
        nc,
        lattice: (0..nl as usize * nl as usize).map(|_| Cell::new(None)).collect(),
        nl,
    };
    let spacing_m = template.spacing_m;
    let mut coarse_at: Vec<(u32, u32)> = Vec::new();
    for level in plan.fine_levels() + 1..=grid.levels() {
        for y in level_rows(grid, &stored, level) {
            level_row(grid, &stored, spacing_m, &coarse, level, y, (0, u32::MAX));
        }
        for_level(grid, &stored, level, [0, m, 0, m], |x, y| coarse_at.push((x, y)));
    }
    for (x, y) in grid.corners() {
        coarse.set(x, y, f32::INFINITY, 0.0, false);
        coarse_at.push((x, y));
    }
    let mut patches: Vec<(u64, Record)> = indices(&layout, &coarse_at)
        .into_iter()
        .zip(&coarse_at)
        .map(|(i, &(x, y))| {
            let [error, radius] = coarse.child(x, y).map_or([0.0; 2], |c| c.0);
            (i, Record { z: coarse.z(x, y), error, radius })
        })
        .collect();
    patches.sort_unstable_by_key(|p| p.0);

    // 2. The payload, block by block in order: the shards' runs, the seam maxima, the coarse
    // records.
    let payload_bytes = layout.records() * RECORD_BYTES as u64;
    let pages = stored_pages(&layout, &stored, payload_bytes);
    let map_bytes = terrain::encode_page_map(&pages.runs());
    let map_pages = map_bytes.len() as u64 / 4096;
    let first_page = 1 + map_pages;
    let mut out = out;
    let local = match &out {
        Out::File(output) => {
            let out_tmp = crate::sys::atomic_file::temp_beside(output)?;
            let out_file = out_tmp.reopen().at(output)?;
            Some((out_tmp, out_file))
        }
        Out::Upload(..) => None,
    };
    // The first part holds the header page and the page map, written last.
    let first_part = PART_BYTES.max(first_page as usize * 4096);
    let mut part_one: Vec<u8> = vec![0; first_page as usize * 4096];
    let mut next_page = first_page;
    let bar = progress.bar("merge", pages.count, "pages");
    let fill = |first: u64, buf: &mut [Record]| {
        let end = first + buf.len() as u64;
        let mut k = runs.partition_point(|r| r.0 + r.1 <= first);
        while k < runs.len() && runs[k].0 < end {
            let (start, len, s, at) = runs[k];
            let recs = shards[s].records();
            let (a, b) = (start.max(first), (start + len).min(end));
            let src = &recs[at + (a - start) as usize..at + (b - start) as usize];
            buf[(a - first) as usize..(b - first) as usize].copy_from_slice(src);
            k += 1;
        }
        let mut k = foreign.partition_point(|f| f.0 < first);
        while k < foreign.len() && foreign[k].0 < end {
            let r = &mut buf[(foreign[k].0 - first) as usize];
            (r.error, r.radius) = (r.error.max(foreign[k].1), r.radius.max(foreign[k].2));
            k += 1;
        }
        let mut k = patches.partition_point(|p| p.0 < first);
        while k < patches.len() && patches[k].0 < end {
            buf[(patches[k].0 - first) as usize] = patches[k].1;
            k += 1;
        }
    };
    let hashes = write_payload(layout.records(), &pages, &fill, &mut |bytes: &[u8]| {
        use std::os::unix::fs::FileExt;
        match (&mut out, &local) {
            (Out::File(output), Some((_, file))) => file.write_all_at(bytes, next_page * 4096).at(output)?,
            (Out::Upload(up, part, parts), _) => {
                let mut bytes = bytes;
                while !bytes.is_empty() {
                    let (buf, cap) = if *parts == 0 { (&mut part_one, first_part) } else { (&mut *part, PART_BYTES) };
                    let take = (cap - buf.len()).min(bytes.len());
                    buf.extend_from_slice(&bytes[..take]);
                    bytes = &bytes[take..];
                    if buf.len() == cap {
                        if *parts > 0 {
                            up.part(*parts + 1, buf)?;
                            buf.clear();
                        }
                        *parts += 1;
                    }
                }
            }
            _ => unreachable!("a local output has its file"),
        }
        next_page += bytes.len().div_ceil(4096) as u64;
        bar.inc(bytes.len().div_ceil(4096) as u64);
        Ok(())
    })?;
    bar.finish_and_clear();
    let z_min = shards.iter().map(|s| s.header.z_min).fold(f64::INFINITY, f64::min);
    let z_max = shards.iter().map(|s| s.header.z_max).fold(f64::NEG_INFINITY, f64::max);
    let mut header = Header {
        z_min,
        z_max,
        page_map_pages: map_pages as u32,
        payload_checksum: terrain::combine_block_hashes(&hashes),
        ..template
    };
    let file_bytes = match (out, local) {
        (Out::File(output), Some((out_tmp, out_file))) => {
            let out_dir = match output.parent() {
                Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
                _ => PathBuf::from("."),
            };
            finish_file(out_tmp, out_file, output, &out_dir, &mut header, &map_bytes, next_page, None)?
        }
        (Out::Upload(up, part, parts), _) => {
            part_one[..HEADER_BYTES].copy_from_slice(&Format::encode(&header).0);
            part_one[4096..4096 + map_bytes.len()].copy_from_slice(&map_bytes);
            up.part(1, &part_one)?;
            if parts > 0 && !part.is_empty() {
                up.part(parts + 1, &part)?;
            }
            next_page * 4096
        }
        _ => unreachable!("a local output has its file"),
    };
    Ok(MergeReport {
        output: label.to_string(),
        shards: count,
        records: runs.iter().map(|r| r.1).sum(),
        coarse_vertices: patches.len() as u64,
        seam_bounds: foreign.len() as u64,
        file_bytes,
        payload_checksum: format!("{:016x}", header.payload_checksum),
        seconds: started.elapsed().as_secs_f64(),
        peak_rss_anon_bytes: sampler.finish(),
    })
}

/// The payload's present pages, in order, handed to `emit` a run of blocks at a time; blocks
/// are filled (`fill(first record, records)`) and hashed in parallel. Returns the blocks'
/// hashes in order (over every page, absent ones as zeros), as [`terrain::payload_checksum`].
fn write_payload(
    records: u64,
    pages: &PresentPages,
    fill: &(dyn Fn(u64, &mut [Record]) + Sync),
    emit: &mut dyn FnMut(&[u8]) -> Result<()>,
) -> Result<Vec<u64>> {
    let block_bytes = terrain::CHECKSUM_BLOCK_BYTES;
    let per_block = (block_bytes / RECORD_BYTES as usize) as u64;
    let pages_per_block = (block_bytes / 4096) as u64;
    let blocks = records.div_ceil(per_block);
    let mut hashes = Vec::with_capacity(blocks as usize);
    let batch = 4 * rayon::current_num_threads().max(1) as u64;
    let mut b = 0;
    while b < blocks {
        cancel::check()?;
        let done: Vec<(u64, Vec<u8>)> = (b..(b + batch).min(blocks))
            .into_par_iter()
            .map(|k| {
                let first = k * per_block;
                let mut buf = vec![Record::default(); per_block.min(records - first) as usize];
                fill(first, &mut buf);
                let bytes: &[u8] = bytemuck::cast_slice(&buf);
                let mut present = Vec::new();
                for p in 0..bytes.len().div_ceil(4096) {
                    if pages.has(k * pages_per_block + p as u64) {
                        let s = p * 4096;
                        present.extend_from_slice(&bytes[s..(s + 4096).min(bytes.len())]);
                        present.resize(present.len().next_multiple_of(4096), 0);
                    }
                }
                (terrain::block_hash(bytes), present)
            })
            .collect();
        for (hash, present) in done {
            hashes.push(hash);
            if !present.is_empty() {
                emit(&present)?;
            }
        }
        b += batch;
    }
    Ok(hashes)
}
