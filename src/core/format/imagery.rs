//! The imagery tile file: an image too large to hold whole (in memory or on the GPU) cut once into
//! mip levels of fixed-size tiles, each stored with a one-texel border so that a tile alone
//! filters bilinearly across its edges. The renderer's tile cache (`crate::heightcache`, the
//! mechanism the GPU height cache uses) reads the tiles a strip wants through the pager.
//!
//! # Imagery tile file (little-endian; the container's header block, then the tiles)
//! ```text
//! offset size  field
//!      0    8  magic "\x89RLFIMG\n"
//!      8    4  version (1)
//!     12    4  width of level 0, texels
//!     16    4  height of level 0, texels
//!     20    4  tile texels T (a tile's side without its border; a stored tile is T + 2 a side)
//!     24    4  levels L (level k is ⌈width / 2^k⌉ × ⌈height / 2^k⌉; level L − 1 is one tile)
//!     28    4  flags: bit 0, the placement below is given; bit 1, the image wraps in x (a
//!              world image: 360 units, degrees, wide), so tiles' borders and the levels'
//!              means wrap around its left and right edges
//!     32   32  placement: x of the upper-left texel's centre, texel width, y of that centre,
//!              texel height (f64, the image's CRS units, rows going south), as a world file
//!     64    8  tiles (all levels)
//!     72    8  payload checksum: XXH3-64 of the tiles' bytes
//!     80  168  reserved (0)
//!    248    8  header checksum: XXH3-64 of bytes 0..248
//!   4096    -  tiles in key order (level 0 first; within a level, rows of tiles from the top,
//!              left to right), each (T + 2)² texels of RGBA8 (sRGB), rows from the top. Texel
//!              (i, j) of tile (tx, ty) is level texel (tx·T − 1 + i, ty·T − 1 + j), clamped to
//!              the level (x wrapped instead where the image wraps).
//! ```
//! Level k + 1's texel (i, j) is the rounded mean of level k's texels (2i..2i + 1, 2j..2j + 1),
//! clamped to level k, so level k's texel i covers level 0's texels `i·2^k .. (i + 1)·2^k` and a
//! level-0 texel coordinate `p` is `p / 2^k` on level k.

use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use rayon::prelude::*;
use serde::Serialize;

use super::{read_header, FileKind, Format, HeaderBytes, Problem};
use crate::error::{Error, Result};
use crate::pager::{Access, FixedBlocks, Pager};
use crate::sys::progress::Progress;
#[cfg(feature = "native")]
use crate::sys::scratch::ScratchMap;

/// The version this build writes and reads.
pub const VERSION: u32 = 1;
/// Where the tiles start (a page, so tiles stay page-aligned).
pub const PAYLOAD_OFFSET: u64 = 4096;
/// Tile texels per side unless asked otherwise: a stored tile is then 256² texels (256 KiB).
pub const DEFAULT_TILE_TEXELS: u32 = 254;
/// The largest image side (2^20 texels: 16 levels of 254-texel tiles at most).
pub const MAX_SIDE: u32 = 1 << 20;
/// Levels the shaders address at most (the table header has room for this many).
pub const MAX_LEVELS: u32 = 16;
/// `u32`s before the table's entries: per level its first entry, then its tiles per side.
pub const TABLE_HEADER: u32 = 2 * MAX_LEVELS;
const FLAG_PLACED: u32 = 1;
const FLAG_WRAPS: u32 = 2;

/// One level's size and where its tiles are numbered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Level {
    pub width: u32,
    pub height: u32,
    pub tiles_x: u32,
    pub tiles_y: u32,
    /// The key of its first tile.
    pub first: u32,
}

/// The mip levels of a `width × height` image in tiles of `tile` texels.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ImageGrid {
    pub width: u32,
    pub height: u32,
    pub tile: u32,
    pub levels: Vec<Level>,
}

impl ImageGrid {
    pub fn new(width: u32, height: u32, tile: u32) -> std::result::Result<ImageGrid, String> {
        if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
            return Err(format!("an image of {width} x {height} texels (sides from 1 to {MAX_SIDE})"));
        }
        if !(4..=4094).contains(&tile) {
            return Err(format!("tiles of {tile} texels (from 4 to 4094)"));
        }
        let (mut levels, mut first, mut k) = (Vec::new(), 0u32, 0u32);
        loop {
            let (w, h) = (width.div_ceil(1 << k), height.div_ceil(1 << k));
            let (tx, ty) = (w.div_ceil(tile), h.div_ceil(tile));
            levels.push(Level { width: w, height: h, tiles_x: tx, tiles_y: ty, first });
            first += tx * ty;
            if tx == 1 && ty == 1 {
                break;
            }
            k += 1;
        }
        if levels.len() > MAX_LEVELS as usize {
            return Err(format!("{} levels (at most {})", levels.len(), MAX_LEVELS));
        }
        Ok(ImageGrid { width, height, tile, levels })
    }

    pub fn coarsest_level(&self) -> u32 {
        self.levels.len() as u32 - 1
    }

    pub fn tiles(&self) -> u32 {
        let l = self.levels[self.levels.len() - 1];
        l.first + l.tiles_x * l.tiles_y
    }

    /// Texels per stored tile side (the tile and its border).
    pub fn slot_side(&self) -> u32 {
        self.tile + 2
    }

    /// Bytes of one stored tile.
    pub fn tile_bytes(&self) -> u64 {
        self.slot_side() as u64 * self.slot_side() as u64 * 4
    }

    pub fn key(&self, k: u32, tx: u32, ty: u32) -> u32 {
        let l = &self.levels[k as usize];
        l.first + ty * l.tiles_x + tx
    }

    /// `(level, tx, ty)` of a key.
    pub fn decode(&self, key: u32) -> (u32, u32, u32) {
        let k = self.levels.partition_point(|l| l.first <= key) - 1;
        let l = &self.levels[k];
        let i = key - l.first;
        (k as u32, i % l.tiles_x, i / l.tiles_x)
    }

    /// The key of the level-`k` tile under level-0 texel coordinate `(px, py)` (clamped to the
    /// image): the rule the fragment shader follows.
    pub fn tile_at(&self, k: u32, px: f64, py: f64) -> u32 {
        let l = &self.levels[k as usize];
        let s = (1u64 << k) as f64;
        let cell = |p: f64, n: u32| ((p / s).floor().clamp(0.0, (n - 1) as f64) as u32) / self.tile;
        self.key(k, cell(px, l.width), cell(py, l.height))
    }

    /// The table header the shaders read: per level its first key, then tiles per row.
    pub fn header(&self) -> [u32; TABLE_HEADER as usize] {
        let mut h = [0u32; TABLE_HEADER as usize];
        for (k, l) in self.levels.iter().enumerate() {
            h[k] = l.first;
            h[MAX_LEVELS as usize + k] = l.tiles_x;
        }
        h
    }
}

/// The imagery tile file's header.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ImageryHeader {
    pub width: u32,
    pub height: u32,
    pub tile: u32,
    pub levels: u32,
    /// As a world file places the image: `[x0, dx, y0, dy]` (centre of the upper-left texel, and
    /// texel sizes, positive; rows go south). `None`: the image spans the DEM it is draped on.
    pub placement: Option<[f64; 4]>,
    /// The image wraps in x: a world image, its placement 360 units (degrees) wide.
    pub wraps: bool,
    pub tiles: u64,
    /// XXH3-64 of the tiles (in JSON as 16 hex digits, as terrain files' are).
    #[serde(serialize_with = "hex64")]
    pub payload_checksum: u64,
}

fn hex64<S: serde::Serializer>(v: &u64, s: S) -> std::result::Result<S::Ok, S::Error> {
    s.serialize_str(&format!("{v:016x}"))
}

impl ImageryHeader {
    pub fn grid(&self) -> ImageGrid {
        ImageGrid::new(self.width, self.height, self.tile).expect("checked when decoded or written")
    }

    pub fn file_len(&self) -> u64 {
        PAYLOAD_OFFSET + self.tiles * self.grid().tile_bytes()
    }
}

impl Format for ImageryHeader {
    const KIND: FileKind = FileKind::Imagery;

    fn decode(h: &HeaderBytes, file_len: u64) -> std::result::Result<ImageryHeader, Problem> {
        let (width, height, tile, levels, flags) = (h.u32(12), h.u32(16), h.u32(20), h.u32(24), h.u32(28));
        let grid = ImageGrid::new(width, height, tile).map_err(|what| Problem::Corrupt(format!("it says {what}")))?;
        if levels as usize != grid.levels.len() || h.u64(64) != grid.tiles() as u64 {
            return Err(Problem::Corrupt(format!(
                "{levels} levels and {} tiles, where a {width} x {height} image in {tile}-texel tiles has {} and {}",
                h.u64(64),
                grid.levels.len(),
                grid.tiles()
            )));
        }
        if flags & !(FLAG_PLACED | FLAG_WRAPS) != 0 {
            return Err(Problem::Corrupt(format!("unknown flags {flags:#x}")));
        }
        let p = [h.f64(32), h.f64(40), h.f64(48), h.f64(56)];
        let placement = if flags & FLAG_PLACED != 0 {
            if !(p.iter().all(|v| v.is_finite()) && p[1] > 0.0 && p[3] > 0.0) {
                return Err(Problem::Corrupt(format!("placement {p:?} (texel sizes must be positive)")));
            }
            Some(p)
        } else {
            None
        };
        if flags & FLAG_WRAPS != 0 && placement.is_none() {
            return Err(Problem::Corrupt("it wraps (flag 2) without a placement".into()));
        }
        let header = ImageryHeader {
            width,
            height,
            tile,
            levels,
            placement,
            wraps: flags & FLAG_WRAPS != 0,
            tiles: grid.tiles() as u64,
            payload_checksum: h.u64(72),
        };
        let expected = header.file_len();
        if file_len != expected {
            return Err(Problem::Truncated { expected, found: file_len });
        }
        Ok(header)
    }

    fn encode_fields(&self, h: &mut HeaderBytes) {
        h.put_u32(12, self.width);
        h.put_u32(16, self.height);
        h.put_u32(20, self.tile);
        h.put_u32(24, self.levels);
        let placed = if self.placement.is_some() { FLAG_PLACED } else { 0 };
        h.put_u32(28, placed | if self.wraps { FLAG_WRAPS } else { 0 });
        let p = self.placement.unwrap_or([0.0; 4]);
        for (i, v) in p.into_iter().enumerate() {
            h.put_f64(32 + 8 * i, v);
        }
        h.put_u64(64, self.tiles);
        h.put_u64(72, self.payload_checksum);
    }
}

/// An open imagery tile file; its tiles are the pager's blocks (block = key).
pub struct ImageryFile {
    path: PathBuf,
    header: ImageryHeader,
    grid: ImageGrid,
    pager: Pager,
}

impl ImageryFile {
    /// Opens and validates an imagery tile file (magic, version, header checksum, fields, exact
    /// size), to be read with `access`. The payload checksum is checked by [`Self::verify`].
    pub fn open(path: &Path, access: Access) -> Result<ImageryFile> {
        let source = crate::pager::open(path, access.source_kind())?;
        let header: ImageryHeader = read_header(&*source)?;
        let grid = header.grid();
        let table = FixedBlocks {
            first: PAYLOAD_OFFSET,
            block_bytes: grid.tile_bytes(),
            end: header.file_len(),
            page_bytes: 4096,
        };
        let pager = Pager::new(source, Arc::new(table), access)?;
        Ok(ImageryFile { path: path.into(), header, grid, pager })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn header(&self) -> &ImageryHeader {
        &self.header
    }

    pub fn grid(&self) -> &ImageGrid {
        &self.grid
    }

    pub fn pager(&self) -> &Pager {
        &self.pager
    }

    /// Tile `key`'s texels (RGBA8 packed little-endian: `r | g << 8 | b << 16 | a << 24`) into
    /// `out`, `slot_side()²` of them.
    pub fn read_tile(&self, key: u32, out: &mut [u32]) -> Result<()> {
        if key >= self.grid.tiles() || out.len() as u64 * 4 != self.grid.tile_bytes() {
            return Err(Error::InvalidArgument(format!(
                "{}: tile {key} of {} into {} texels",
                self.path.display(),
                self.grid.tiles(),
                out.len()
            )));
        }
        let block = self.pager.block(key)?;
        for (t, b) in out.iter_mut().zip(block.chunks_exact(4)) {
            *t = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
        Ok(())
    }

    /// Checks the tiles' bytes against the payload checksum.
    pub fn verify(&self) -> Result<()> {
        let mut hasher = xxhash_rust::xxh3::Xxh3::new();
        for key in 0..self.grid.tiles() {
            hasher.update(&self.pager.block(key)?);
        }
        let computed = hasher.digest();
        if computed != self.header.payload_checksum {
            return Err(super::file_error(
                &self.path,
                FileKind::Imagery,
                Problem::Checksum { which: "payload", stored: self.header.payload_checksum, computed },
            ));
        }
        Ok(())
    }
}

/// What [`write()`] made.
#[derive(Clone, Debug, Serialize)]
pub struct TilingReport {
    pub width: u32,
    pub height: u32,
    pub levels: u32,
    pub tiles: u64,
    pub file_bytes: u64,
    pub seconds: f64,
}

#[cfg(feature = "native")]
/// Writes the imagery tile file `out` of a `width × height` RGBA8 image (`rgba`, rows from the
/// top), placed by `placement` (see [`ImageryHeader::placement`]). Coarser levels are built in
/// scratch files in `scratch_dir`, so memory stays a few rows of tiles whatever the image's size.
/// The file appears whole or not at all.
pub fn write(
    out: &Path,
    rgba: &[[u8; 4]],
    width: u32,
    height: u32,
    placement: Option<[f64; 4]>,
    scratch_dir: &Path,
    progress: Progress,
) -> Result<TilingReport> {
    let started = std::time::Instant::now();
    let grid = ImageGrid::new(width, height, DEFAULT_TILE_TEXELS)
        .map_err(|what| Error::InvalidArgument(format!("{}: cannot tile {what}", out.display())))?;
    if rgba.len() as u64 != width as u64 * height as u64 {
        return Err(Error::InvalidArgument(format!(
            "{}: {} texels for a {width} x {height} image",
            out.display(),
            rgba.len()
        )));
    }
    // A world image (360 units wide: degrees) wraps; renderers wrap it on geographic terrains.
    let wraps = placement.is_some_and(|[_, dx, _, _]| (width as f64 * dx - 360.0).abs() < 1e-6 * 360.0);
    let tmp = crate::sys::atomic_file::temp_beside(out)?;
    let io = |e: std::io::Error| Error::io(out, e);
    let mut w = std::io::BufWriter::with_capacity(1 << 20, tmp.as_file());
    w.write_all(&[0u8; PAYLOAD_OFFSET as usize]).map_err(io)?;
    let mut hasher = xxhash_rust::xxh3::Xxh3::new();
    let bar = progress.bar("tiling imagery", grid.tiles() as u64, "tiles");
    let side = grid.slot_side() as usize;
    let mut coarser: Option<ScratchMap> = None;
    for (k, level) in grid.levels.iter().enumerate() {
        crate::sys::cancel::check()?;
        let texels: &[[u8; 4]] = match &coarser {
            None => rgba,
            Some(m) => m.slice(),
        };
        let (lw, lh) = (level.width as i64, level.height as i64);
        let x_of = |x: i64| if wraps { x.rem_euclid(lw) } else { x.clamp(0, lw - 1) };
        let at = |x: i64, y: i64| texels[(y.clamp(0, lh - 1) * lw + x_of(x)) as usize];
        let t = grid.tile as i64;
        for ty in 0..level.tiles_y {
            let row: Vec<Vec<u8>> = (0..level.tiles_x)
                .into_par_iter()
                .map(|tx| {
                    let mut bytes = Vec::with_capacity(side * side * 4);
                    let (x0, y0) = (tx as i64 * t - 1, ty as i64 * t - 1);
                    for j in 0..side as i64 {
                        for i in 0..side as i64 {
                            bytes.extend_from_slice(&at(x0 + i, y0 + j));
                        }
                    }
                    bytes
                })
                .collect();
            for b in &row {
                hasher.update(b);
                w.write_all(b).map_err(io)?;
            }
            bar.inc(row.len() as u64);
        }
        if let Some(next) = grid.levels.get(k + 1) {
            let mut map = ScratchMap::new(scratch_dir, next.width as u64 * next.height as u64 * 4)?;
            let dst: &mut [[u8; 4]] = map.slice_mut();
            dst.par_chunks_mut(next.width as usize).enumerate().for_each(|(j, row)| {
                for (i, px) in row.iter_mut().enumerate() {
                    let (x, y) = (2 * i as i64, 2 * j as i64);
                    let q = [at(x, y), at(x + 1, y), at(x, y + 1), at(x + 1, y + 1)];
                    for c in 0..4 {
                        let sum: u32 = q.iter().map(|p| p[c] as u32).sum();
                        px[c] = ((sum + 2) / 4) as u8;
                    }
                }
            });
            coarser = Some(map);
        }
    }
    bar.finish_and_clear();
    let header = ImageryHeader {
        width,
        height,
        tile: grid.tile,
        levels: grid.levels.len() as u32,
        placement,
        wraps,
        tiles: grid.tiles() as u64,
        payload_checksum: hasher.digest(),
    };
    w.seek(SeekFrom::Start(0)).map_err(io)?;
    w.write_all(&header.encode().0).map_err(io)?;
    w.flush().map_err(io)?;
    drop(w);
    tmp.as_file().sync_all().map_err(io)?;
    tmp.persist(out).map_err(|e| io(e.error))?;
    let file_bytes = header.file_len();
    Ok(TilingReport {
        width,
        height,
        levels: header.levels,
        tiles: header.tiles,
        file_bytes,
        seconds: started.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_halve_up_to_one_tile_and_keys_are_a_bijection() {
        let g = ImageGrid::new(1000, 300, 254).unwrap();
        let dims: Vec<_> = g.levels.iter().map(|l| (l.width, l.height, l.tiles_x, l.tiles_y)).collect();
        assert_eq!(dims, [(1000, 300, 4, 2), (500, 150, 2, 1), (250, 75, 1, 1)]);
        assert_eq!(g.tiles(), 11);
        for key in 0..g.tiles() {
            let (k, tx, ty) = g.decode(key);
            assert_eq!(g.key(k, tx, ty), key);
        }
        // Texel 999 of level 0 is in tile 3; on level 1 it is texel 499, tile 1.
        assert_eq!(g.decode(g.tile_at(0, 999.5, 299.0)), (0, 3, 1));
        assert_eq!(g.decode(g.tile_at(1, 999.5, 0.0)), (1, 1, 0));
        assert_eq!(g.decode(g.tile_at(2, -5.0, 1e9)), (2, 0, 0));
        assert!(ImageGrid::new(0, 5, 254).is_err() && ImageGrid::new(5, 5, 2).is_err());
        assert_eq!(ImageGrid::new(1, 1, 254).unwrap().tiles(), 1);
    }
}
