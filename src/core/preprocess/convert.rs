//! DEM → terrain file conversion with bounded anonymous memory.
//!
//! Steps: stream the DEM into a memory-mapped row-major grid of heights (file-backed scratch, so
//! the kernel may page it out; anonymous memory stays O(row)), fill voids, compute nested errors
//! and radii level by level into a second mapped grid for the vertices a file stores (the DEM's
//! posts and their ancestors in the (2^n + 1)² grid, [`Stored`]; the padding beyond reads the edge
//! heights and is never stored), find the payload pages that hold stored records, then write those
//! pages in the layout's order into a temporary output file with positioned writes (checksumming
//! block by block), write the page map and the header, sync, and rename over the final name.
//! Heights and bounds live in separate scratch grids so that each scratch page is dirtied once:
//! re-dirtying pages the kernel has already written back doubled the I/O on large grids. An error
//! or a Ctrl-C at any point drops the temporary files, so the final name holds either the old file
//! or the complete new one.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use crate::dem::{self, DemFormat, Run, SourceSpacing};
use crate::error::{Error, IoContext, Result};
use crate::format::terrain::{
    self, Header, Record, TerrainFile, VoidMask, FLAG_GEOGRAPHIC, FLAG_SPACING_ASSUMED, FLAG_STORED_PAGES,
    PAYLOAD_OFFSET, RECORD_BYTES,
};
use crate::layout::hierarchy::{Grid, MAX_N};
use crate::layout::{AnyLayout, Layout, LayoutKind, Stored};
use crate::pager::source::MAX_MAPPED_BYTES;
use crate::preprocess;
use crate::preprocess::fill;
use crate::sys::cancel;
use crate::sys::mem::AnonSampler;
use crate::sys::progress::Progress;
use crate::sys::scratch::{file_system_limit, ScratchMap};

/// Mean Earth radius (IUGG), used to turn degrees into metres at the grid's centre latitude.
pub const EARTH_RADIUS_M: f64 = 6_371_008.8;

/// What `relief convert` was asked to do.
#[derive(Clone, Debug)]
pub struct ConvertOptions {
    pub layout: LayoutKind,
    /// Tile side for `tiled` (power of two); `None` picks about one 4 KiB page per tile.
    pub tile: Option<u32>,
    /// Post spacing in metres (x, y); overrides what the file says.
    pub spacing_m: Option<[f64; 2]>,
    /// Heights in metres = source value × z_scale + z_offset.
    pub z_scale: f64,
    pub z_offset: f64,
    pub format: Option<DemFormat>,
    /// Accept lossy-compressed DEMs (see [`dem::OpenOptions::allow_lossy`]).
    pub allow_lossy: bool,
    /// Where the scratch grid lives (default: beside the output).
    pub scratch_dir: Option<PathBuf>,
    pub progress: Progress,
}

impl ConvertOptions {
    pub fn new(layout: LayoutKind) -> Self {
        ConvertOptions {
            layout,
            tile: None,
            spacing_m: None,
            z_scale: 1.0,
            z_offset: 0.0,
            format: None,
            allow_lossy: false,
            scratch_dir: None,
            progress: Progress::hidden(),
        }
    }
}

impl ConvertOptions {
    /// How the input DEMs are opened.
    pub fn open_options(&self) -> dem::OpenOptions {
        dem::OpenOptions { format: self.format, allow_lossy: self.allow_lossy }
    }
}

/// Seconds spent in each step.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StepSeconds {
    pub read: f64,
    pub fill: f64,
    pub bounds: f64,
    pub layout: f64,
    pub write: f64,
}

/// What a conversion did, for `--json` and benchmarks.
#[derive(Clone, Debug, Serialize)]
pub struct ConvertReport {
    pub input: PathBuf,
    pub output: PathBuf,
    pub format: String,
    pub source_width: u32,
    pub source_height: u32,
    pub grid_size: u32,
    pub layout: String,
    pub records: u64,
    pub vertices: u64,
    /// Vertices with records: the DEM's posts and their ancestors in the grid.
    pub stored_vertices: u64,
    /// Payload pages (4 KiB) written, of the index space's.
    pub stored_pages: u64,
    pub payload_pages: u64,
    pub spacing_m: [f64; 2],
    pub spacing_source: &'static str,
    pub nodata_filled: u64,
    pub z_min: f64,
    pub z_max: f64,
    pub file_bytes: u64,
    pub seconds: f64,
    pub steps: StepSeconds,
    pub vertices_per_s: f64,
    pub peak_rss_anon_bytes: u64,
}

/// Faults a mapped region in, chunk by chunk from its start, on a helper thread
/// (`MADV_POPULATE_WRITE`; a no-op where the kernel lacks it). Only the page tables and page cache
/// are touched: the data is written by the reader, concurrently, through its own slice.
struct Prefault {
    addr: usize,
    len: usize,
    stop: std::sync::atomic::AtomicBool,
}

impl Prefault {
    fn new<T>(region: &mut [T]) -> Self {
        Prefault { addr: region.as_mut_ptr() as usize, len: std::mem::size_of_val(region), stop: false.into() }
    }

    fn run(&self) {
        const CHUNK: usize = 32 << 20;
        let page = 4096;
        let start = self.addr & !(page - 1);
        let end = self.addr + self.len;
        let mut at = start;
        while at < end && !self.stop.load(std::sync::atomic::Ordering::Relaxed) {
            let len = CHUNK.min(end - at);
            // SAFETY: the range lies within a live shared file mapping owned by the caller for
            // the duration of the scope; MADV_POPULATE_WRITE only pre-faults, it does not change
            // contents.
            let rc = unsafe { libc::madvise(at as *mut libc::c_void, len, libc::MADV_POPULATE_WRITE) };
            if rc != 0 {
                return;
            }
            at += len;
        }
    }

    fn stop(&self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
    }
}

/// Spacing in metres and how it was obtained.
fn resolve_spacing(
    opts: &ConvertOptions,
    source: Option<SourceSpacing>,
) -> ([f64; 2], &'static str, u32, f64, [f64; 2]) {
    let nan2 = [f64::NAN, f64::NAN];
    let (lat, deg) = match source {
        Some(SourceSpacing::Degrees { x, y, centre_lat_deg }) => (centre_lat_deg, [x, y]),
        _ => (f64::NAN, nan2),
    };
    let geo_flag = if lat.is_nan() { 0 } else { FLAG_GEOGRAPHIC };
    if let Some(s) = opts.spacing_m {
        return (s, "option", geo_flag, lat, deg);
    }
    match source {
        Some(SourceSpacing::Metres { x, y }) => ([x.abs(), y.abs()], "file", 0, f64::NAN, nan2),
        Some(SourceSpacing::Degrees { x, y, centre_lat_deg }) => {
            let m_per_deg = EARTH_RADIUS_M * std::f64::consts::PI / 180.0;
            let sx = x.abs() * m_per_deg * centre_lat_deg.to_radians().cos();
            let sy = y.abs() * m_per_deg;
            (
                [sx, sy],
                "file (degrees converted at the centre latitude)",
                FLAG_GEOGRAPHIC,
                centre_lat_deg,
                [x.abs(), y.abs()],
            )
        }
        None => {
            ([1.0, 1.0], "assumed 1 m (the file does not say; set the spacing)", FLAG_SPACING_ASSUMED, f64::NAN, nan2)
        }
    }
}

/// Where relief keeps terrains it converts on its own (the bundled terrain, `relief layouts`):
/// `$XDG_CACHE_HOME/relief`, else `~/.cache/relief`, else `./target/relief`.
pub fn cache_dir() -> PathBuf {
    std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
        .unwrap_or_else(|| PathBuf::from("target"))
        .join("relief")
}

/// Converts the DEM at `input` into a terrain file at `output`.
pub fn convert(input: &Path, output: &Path, opts: &ConvertOptions) -> Result<ConvertReport> {
    convert_source(input, None, output, opts)
}

/// Converts several DEM tiles (files, or directories of them: [`dem::expand_inputs`]) into one
/// terrain, each placed by its georeferencing ([`dem::Mosaic`]); one file alone is [`convert`].
pub fn convert_many(inputs: &[PathBuf], output: &Path, opts: &ConvertOptions) -> Result<ConvertReport> {
    let Some(label) = inputs.first() else {
        return Err(Error::InvalidArgument("no input DEM".into()));
    };
    if inputs.len() == 1 && !label.is_dir() {
        return convert(label, output, opts);
    }
    let tiles = dem::expand_inputs(inputs)?;
    let mosaic = dem::Mosaic::open(&tiles, opts.open_options())?;
    convert_source(label, Some(Box::new(mosaic)), output, opts)
}

/// Writes `terrain` again in another layout (`opts.layout`): the DEM's own posts (its valid
/// window) are read back from the file and converted as if they came from the DEM, so the result
/// equals converting the original DEM (heights are taken as metres: `z_scale` 1, offset 0).
pub fn relayout(terrain: &TerrainFile, output: &Path, opts: &ConvertOptions) -> Result<ConvertReport> {
    if output == terrain.path() {
        return Err(Error::InvalidArgument(format!("{}: re-layout output must be another file", output.display())));
    }
    let opts = ConvertOptions { z_scale: 1.0, z_offset: 0.0, format: None, ..opts.clone() };
    convert_source(terrain.path(), Some(Box::new(TerrainSource::new(terrain))), output, &opts)
}

/// A terrain file's valid window streamed as a DEM (row 0 north), for [`relayout`].
struct TerrainSource<'a> {
    terrain: &'a TerrainFile,
    info: dem::DemInfo,
}

impl<'a> TerrainSource<'a> {
    fn new(terrain: &'a TerrainFile) -> Self {
        let h = terrain.header();
        let [x0, y0, x1, y1] = h.valid_window;
        let info = dem::DemInfo {
            format: DemFormat::ALL.get(h.source_format as usize).copied().unwrap_or(DemFormat::GeoTiff),
            width: x1 - x0,
            height: y1 - y0,
            spacing: Some(dem::SourceSpacing::Metres { x: h.spacing_m[0], y: h.spacing_m[1] }),
            nodata: None,
            sample_type: "float32 (relief terrain file)".into(),
            // Heights here are metres already: the source's vertical unit was applied when it
            // was converted.
            georef: h.georef.map(|g| crate::georef::Georef {
                origin: g.crs_of_post([x0 as f64, y0 as f64]),
                vertical_unit: crate::georef::unit::METRE,
                ..g
            }),
        };
        TerrainSource { terrain, info }
    }
}

impl dem::DemSource for TerrainSource<'_> {
    fn info(&self) -> &dem::DemInfo {
        &self.info
    }

    fn read(&mut self, sink: &mut dyn FnMut(dem::Run<'_>) -> Result<()>) -> Result<()> {
        let [x0, y0, x1, y1] = self.terrain.header().valid_window;
        // Void posts go back as nodata: filled again the same way, they keep their mask.
        let mask = self.terrain.void_mask()?;
        let mut row = vec![0f64; (x1 - x0) as usize];
        for r in 0..(y1 - y0) {
            // Grid row y counts from the south; DEM row 0 is the northernmost.
            let y = y1 - 1 - r;
            for (k, v) in row.iter_mut().enumerate() {
                let x = x0 + k as u32;
                *v = match &mask {
                    Some(m) if m.is_void(x, y) => f64::NAN,
                    _ => self.terrain.record_at(x, y)?.z as f64,
                };
            }
            sink(dem::Run { row: r, x0: 0, values: &row })?;
        }
        Ok(())
    }
}

/// What a conversion knows before reading a sample: the source, its grid, layout and stored
/// vertices, spacing (metres, where from, header flags, centre latitude, degrees), the heights'
/// scale to metres, and the output's length and directory.
pub(crate) struct Prepared<'a> {
    pub source: Box<dyn dem::DemSource + 'a>,
    pub info: dem::DemInfo,
    pub grid: Grid,
    pub layout: AnyLayout,
    pub stored: Stored,
    pub spacing: ([f64; 2], &'static str, u32, f64, [f64; 2]),
    pub z_scale: f64,
    pub file_len: u64,
    pub out_dir: PathBuf,
}

/// Checks the options, opens the source (unless given) and sizes the output; refuses what cannot
/// be mapped before anything is created.
pub(crate) fn prepare<'a>(
    input: &Path,
    source: Option<Box<dyn dem::DemSource + 'a>>,
    output: &Path,
    opts: &ConvertOptions,
) -> Result<Prepared<'a>> {
    if opts.z_scale == 0.0 || !opts.z_scale.is_finite() || !opts.z_offset.is_finite() {
        return Err(Error::InvalidArgument(format!(
            "the height scale {} and offset {} must be finite, the scale non-zero",
            opts.z_scale, opts.z_offset
        )));
    }
    if let Some([sx, sy]) = opts.spacing_m {
        if !(sx.is_finite() && sy.is_finite() && sx > 0.0 && sy > 0.0) {
            return Err(Error::OutOfRange {
                what: "post spacing",
                allowed: "positive metres".into(),
                got: format!("{sx},{sy}"),
            });
        }
    }
    let source = match source {
        Some(s) => s,
        None => dem::open_with(input, opts.open_options())?,
    };
    let info = source.info().clone();
    let (width, height) = (info.width, info.height);
    let grid = Grid::covering(width as u64, height as u64).ok_or(Error::GridTooLarge {
        path: input.into(),
        width: width as u64,
        height: height as u64,
        max_n: MAX_N,
    })?;
    let layout =
        AnyLayout::new(opts.layout, grid, opts.tile.unwrap_or(0), RECORD_BYTES).map_err(Error::InvalidArgument)?;
    let spacing = resolve_spacing(opts, info.spacing);
    // Heights in metres: the source's vertical unit (feet, where its GeoKeys say so), then the
    // user's scale.
    let z_scale = opts.z_scale * info.georef.map_or(1.0, |g| g.vertical_metres());
    let out_dir = match output.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if output.is_dir() {
        return Err(Error::io(output, std::io::Error::new(std::io::ErrorKind::IsADirectory, "is a directory")));
    }
    let stored = Stored::new(grid, width, height);
    // In u128 (at n = 31 it overflows u64). The output is mapped whole when read: refuse what
    // cannot be mapped.
    let file_len = layout.records() as u128 * RECORD_BYTES as u128 + PAYLOAD_OFFSET as u128;
    if file_len > MAX_MAPPED_BYTES as u128 {
        let side = grid.size() as u64;
        let what = "terrain file";
        return Err(Error::TooLargeToMap { path: input.into(), side, what, bytes: file_len, limit: MAX_MAPPED_BYTES });
    }
    Ok(Prepared { source, info, grid, layout, stored, spacing, z_scale, file_len: file_len as u64, out_dir })
}

/// The terrain header of a conversion, with what only the samples tell (height range, voids
/// filled, page map, checksum) left zero and the page map at one page.
pub(crate) fn header_template(
    layout: &AnyLayout,
    info: &dem::DemInfo,
    (spacing_m, flags, centre_lat, spacing_deg): ([f64; 2], u32, f64, [f64; 2]),
    z_scale: f64,
    opts: &ConvertOptions,
) -> Header {
    Header {
        version: terrain::VERSION,
        layout: layout.kind(),
        layout_param: layout.param(),
        record_format: terrain::RECORD_FORMAT_F32,
        record_bytes: RECORD_BYTES,
        n: layout.grid().n(),
        flags: flags | FLAG_STORED_PAGES,
        valid_window: [0, 0, info.width, info.height],
        source_format: DemFormat::ALL.iter().position(|f| *f == info.format).unwrap_or(0) as u32,
        records: layout.records(),
        payload_offset: PAYLOAD_OFFSET,
        payload_bytes: layout.records() * RECORD_BYTES as u64,
        spacing_m,
        z_scale,
        z_offset: opts.z_offset,
        z_min: 0.0,
        z_max: 0.0,
        nodata_filled: 0,
        source_centre_lat_deg: centre_lat,
        source_spacing_deg: spacing_deg,
        georef: info.georef,
        void_mask_offset: 0,
        page_map_pages: 1,
        payload_checksum: 0,
    }
}

fn convert_source(
    input: &Path,
    source: Option<Box<dyn dem::DemSource + '_>>,
    output: &Path,
    opts: &ConvertOptions,
) -> Result<ConvertReport> {
    let started = Instant::now();
    let sampler = AnonSampler::start();
    let mut steps = StepSeconds::default();

    let Prepared {
        mut source,
        info,
        grid,
        layout,
        stored,
        spacing: (spacing_m, spacing_source, flags, centre_lat, spacing_deg),
        z_scale,
        file_len,
        out_dir,
    } = prepare(input, source, output, opts)?;
    let (width, height) = (info.width, info.height);
    let side = grid.size() as usize;
    let row = width as usize; // the height scratch holds the DEM's posts only
                              // Both scratch grids are mapped whole: refuse what cannot be mapped (in u128: at n = 31 the
                              // sizes overflow u64).
    let z_len = width as u128 * height as u128 * std::mem::size_of::<f32>() as u128;
    let bounds_len = grid.vertices() as u128 * std::mem::size_of::<[f32; 2]>() as u128;
    if z_len + bounds_len > MAX_MAPPED_BYTES as u128 {
        let (side, bytes) = (grid.size() as u64, z_len + bounds_len);
        let what = "conversion scratch";
        return Err(Error::TooLargeToMap { path: input.into(), side, what, bytes, limit: MAX_MAPPED_BYTES });
    }
    let (z_len, bounds_len) = (z_len as u64, bounds_len as u64);
    let payload_bytes = file_len - PAYLOAD_OFFSET;
    let out_tmp = crate::sys::atomic_file::temp_beside(output)?;
    // The output is written once, sequentially, with positioned writes (no page faults, no
    // zero-filling of fresh pages).
    let out_file = out_tmp.reopen().at(output)?;
    // Scratch: heights and bounds in separate row-major grids, so each scratch page is written
    // once (heights while reading, bounds while preprocessing) and never re-dirtied after the
    // kernel has written it back. The bounds grid spans the whole square but only the stored
    // vertices' pages are ever touched: the rest stays holes.
    let scratch_dir = opts.scratch_dir.clone().unwrap_or_else(|| out_dir.clone());
    let mut z_map = ScratchMap::new(&scratch_dir, z_len)?;
    let mut bounds_map = ScratchMap::new(&scratch_dir, bounds_len)?;
    let z_grid: &mut [f32] = z_map.slice_mut();
    let bounds_grid: &mut [[f32; 2]] = bounds_map.slice_mut();

    // 1. Read the DEM into the row-major grid (grid row y = height − 1 − image row).
    let t = Instant::now();
    let bar = opts.progress.bar("read", width as u64 * height as u64, "samples");
    let (mut nan_count, mut z_min, mut z_max) = (0u64, f64::INFINITY, f64::NEG_INFINITY);
    let mut void_mask: Option<VoidMask> = None;
    {
        let (z_scale, z_offset) = (z_scale, opts.z_offset);
        // Readers are mostly sequential; fault the grid's pages in on the other core meanwhile
        // (the kernel zeroes each fresh page-cache page, a large share of this step's cost).
        let prefault = Prefault::new(z_grid);
        std::thread::scope(|scope| -> Result<()> {
            scope.spawn(|| prefault.run());
            let result = source.read(&mut |run: Run<'_>| {
                cancel::check()?;
                let end = run.x0 as u64 + run.values.len() as u64;
                if run.row >= height || end > width as u64 {
                    return Err(Error::bad_dem(
                        input,
                        format!(
                            "reader produced samples outside {width}x{height} (row {}, columns {}..{end})",
                            run.row, run.x0
                        ),
                    ));
                }
                let y = (height - 1 - run.row) as usize;
                let dst = &mut z_grid[y * row + run.x0 as usize..y * row + end as usize];
                for (r, &v) in dst.iter_mut().zip(run.values) {
                    let z = v * z_scale + z_offset;
                    if z.is_finite() {
                        // The range is that of the stored (f32) heights.
                        *r = z as f32;
                        z_min = z_min.min(*r as f64);
                        z_max = z_max.max(*r as f64);
                    } else {
                        nan_count += 1;
                        *r = f32::NAN;
                    }
                }
                bar.inc(run.values.len() as u64);
                Ok(())
            });
            prefault.stop();
            result
        })?;
        bar.finish_and_clear();
        steps.read = t.elapsed().as_secs_f64();
        if z_min > z_max {
            return Err(Error::NoValidSamples { path: input.into() });
        }

        // 2. Keep which posts were void, then fill them and pad.
        let t = Instant::now();
        if nan_count > 0 {
            let mut mask = VoidMask::new([0, 0, width, height]);
            for y in 0..height {
                let posts = &z_grid[y as usize * row..(y as usize + 1) * row];
                for (x, z) in posts.iter().enumerate() {
                    if z.is_nan() {
                        mask.set(x as u32, y);
                    }
                }
            }
            void_mask = Some(mask);
            // The bounds grid is the accumulators' scratch (zero again on return).
            let acc = &mut bounds_grid[..z_grid.len()];
            let filled = fill::fill_voids(z_grid, acc, row, width as usize, height as usize);
            debug_assert_eq!(filled, nan_count);
            // Filled values are weighted means of valid ones, but f32 rounding can step just
            // outside the valid range: take the range of what is stored.
            (z_min, z_max) = fill::height_range(z_grid, row, width as usize, height as usize);
        }
        steps.fill = t.elapsed().as_secs_f64();
        cancel::check()?;

        // 3. Nested errors and radii.
        let t = Instant::now();
        let bar = opts.progress.bar("bounds", stored.count(), "vertices");
        preprocess::compute_bounds(
            grid,
            spacing_m,
            z_grid,
            [width, height],
            bounds_grid,
            &|k| bar.inc(k),
            &cancel::check,
        )?;
        bar.finish_and_clear();
        steps.bounds = t.elapsed().as_secs_f64();
    }

    // 4. The payload pages that hold stored records, then those pages in the layout's order,
    // checksumming block by block.
    let t = Instant::now();
    let pages = stored_pages(&layout, &stored, payload_bytes);
    let map_bytes = terrain::encode_page_map(&pages.runs());
    let map_pages = map_bytes.len() as u64 / 4096;
    let bar = opts.progress.bar("layout", pages.count, "pages");
    let heights = Heights { z: z_grid, width, height };
    let first_page = 1 + map_pages;
    let hashes =
        gather(&layout, &stored, heights, bounds_grid, side, &pages, first_page, &out_file, output, &|k| bar.inc(k))?;
    bar.finish_and_clear();
    let payload_checksum = terrain::combine_block_hashes(&hashes);
    drop((z_map, bounds_map));
    steps.layout = t.elapsed().as_secs_f64();

    // 5. Void mask, header, sync, rename.
    let t = Instant::now();
    let mut header = Header {
        z_min,
        z_max,
        nodata_filled: nan_count,
        page_map_pages: map_pages as u32,
        payload_checksum,
        ..header_template(&layout, &info, (spacing_m, flags, centre_lat, spacing_deg), z_scale, opts)
    };
    cancel::check()?;
    let file_bytes = finish_file(
        out_tmp,
        out_file,
        output,
        &out_dir,
        &mut header,
        &map_bytes,
        first_page + pages.count,
        void_mask.as_ref(),
    )?;
    steps.write = t.elapsed().as_secs_f64();

    let seconds = started.elapsed().as_secs_f64();
    Ok(ConvertReport {
        input: input.into(),
        output: output.into(),
        format: info.format.name().into(),
        source_width: width,
        source_height: height,
        grid_size: grid.size(),
        layout: layout.kind().name().into(),
        records: layout.records(),
        vertices: grid.vertices(),
        stored_vertices: stored.count(),
        stored_pages: pages.count,
        payload_pages: payload_bytes.div_ceil(4096),
        spacing_m,
        spacing_source,
        nodata_filled: nan_count,
        z_min,
        z_max,
        file_bytes,
        seconds,
        steps,
        vertices_per_s: stored.count() as f64 / seconds,
        peak_rss_anon_bytes: sampler.finish(),
    })
}

/// Ends a terrain file whose payload pages are written (header page and map left for last):
/// the void mask after the `pages_end` pages, the length, the page map, the header (its void
/// mask offset set here), sync, and the rename of the temporary over `output`. Returns the
/// file's length.
#[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
pub(crate) fn finish_file(
    out_tmp: tempfile::NamedTempFile,
    out_file: File,
    output: &Path,
    out_dir: &Path,
    header: &mut Header,
    map_bytes: &[u8],
    pages_end: u64,
    void_mask: Option<&VoidMask>,
) -> Result<u64> {
    use std::os::unix::fs::FileExt;
    // On disk: header page, page map, stored pages (whole), void mask.
    let mask_at = 4096 * pages_end;
    let mut stored_len = mask_at;
    if let Some(mask) = void_mask {
        header.void_mask_offset = header.void_mask_start();
        stored_len = mask_at + 8 + mask.bits.len() as u64;
        out_file.write_all_at(&mask.checksum().to_le_bytes(), mask_at).at(output)?;
        out_file.write_all_at(&mask.bits, mask_at + 8).at(output)?;
    }
    out_file.set_len(stored_len).map_err(|e| file_system_limit(e, output, stored_len))?;
    out_file.write_all_at(map_bytes, 4096).at(output)?;
    out_file.write_all_at(&crate::format::Format::encode(&*header).0, 0).at(output)?;
    out_file.sync_all().at(output)?;
    drop(out_file);
    out_tmp.persist(output).map_err(|e| Error::io(output, e.error))?;
    if let Ok(dir) = File::open(out_dir) {
        let _ = dir.sync_all(); // make the rename durable where the platform allows
    }
    Ok(stored_len)
}

/// The DEM's heights, row-major from the south; a post beyond them has its nearest edge post's.
#[derive(Clone, Copy)]
struct Heights<'a> {
    z: &'a [f32],
    width: u32,
    height: u32,
}

impl Heights<'_> {
    #[inline]
    fn at(&self, x: u32, y: u32) -> f32 {
        self.z[y.min(self.height - 1) as usize * self.width as usize + x.min(self.width - 1) as usize]
    }
}

/// Which payload pages (4 KiB, from the payload's start) hold a stored record.
pub(crate) struct PresentPages {
    /// One bit per payload page.
    pub bits: Vec<u64>,
    pub count: u64,
}

impl PresentPages {
    pub fn has(&self, page: u64) -> bool {
        self.bits.get((page / 64) as usize).is_some_and(|w| w >> (page % 64) & 1 == 1)
    }

    /// Runs of present pages `(first, pages)`.
    pub fn runs(&self) -> Vec<(u64, u64)> {
        let mut runs: Vec<(u64, u64)> = Vec::new();
        for (k, &w) in self.bits.iter().enumerate() {
            let mut w = w;
            while w != 0 {
                let p = k as u64 * 64 + w.trailing_zeros() as u64;
                w &= w - 1;
                match runs.last_mut() {
                    Some(last) if last.0 + last.1 == p => last.1 += 1,
                    _ => runs.push((p, 1)),
                }
            }
        }
        runs
    }
}

/// Marks the pages of every stored vertex's record (level by level, rows in parallel).
pub(crate) fn stored_pages(layout: &AnyLayout, stored: &Stored, payload_bytes: u64) -> PresentPages {
    use std::sync::atomic::{AtomicU64, Ordering};
    struct Mark<'a> {
        stored: &'a Stored,
        words: &'a [AtomicU64],
    }
    impl crate::layout::LayoutVisitor for Mark<'_> {
        type Output = ();
        fn visit<L: Layout>(self, layout: &L) {
            let grid = layout.grid();
            let mark = |x: u32, y: u32| {
                let at = layout.index(x, y) * RECORD_BYTES as u64;
                for page in [at / 4096, (at + RECORD_BYTES as u64 - 1) / 4096] {
                    self.words[(page / 64) as usize].fetch_or(1 << (page % 64), Ordering::Relaxed);
                }
            };
            for (x, y) in grid.corners() {
                mark(x, y);
            }
            for level in 1..=grid.levels() {
                let step = 1u32 << ((level - 1) / 2);
                let (xmax, ymax) = self.stored.max_at(level);
                let (first, stride) = if level % 2 == 1 { (0, step) } else { (step, 2 * step) };
                let rows: Vec<u32> = (first..=ymax).step_by(stride as usize).collect();
                rows.par_iter().for_each(|&y| {
                    // Square centres and horizontal-edge midpoints start at step, vertical-edge
                    // midpoints at 0; all go by 2·step.
                    let x0 = if level % 2 == 0 || (y / step).is_multiple_of(2) { step } else { 0 };
                    let mut x = x0;
                    while x <= xmax {
                        if !(grid.kind(x, y) == crate::layout::hierarchy::VertexKind::Corner) {
                            mark(x, y);
                        }
                        x += 2 * step;
                    }
                });
            }
        }
    }
    let pages = payload_bytes.div_ceil(4096);
    let words: Vec<AtomicU64> = (0..pages.div_ceil(64)).map(|_| AtomicU64::new(0)).collect();
    layout.visit(Mark { stored, words: &words });
    let bits: Vec<u64> = words.into_iter().map(AtomicU64::into_inner).collect();
    let count = bits.iter().map(|w| w.count_ones() as u64).sum();
    PresentPages { bits, count }
}

/// Writes the payload's present pages in layout order: record `i` = the grid's `coords(i)` post
/// where it is stored, zero otherwise, in parallel blocks of [`terrain::CHECKSUM_BLOCK_BYTES`] with
/// positioned writes, present page `k` (in order) at file page `first_page + k`. Returns the
/// blocks' hashes in order, over every page of the payload as read (left-out pages are zeros).
#[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
fn gather(
    layout: &AnyLayout,
    stored: &Stored,
    heights: Heights<'_>,
    bounds: &[[f32; 2]],
    side: usize,
    pages: &PresentPages,
    first_page: u64,
    out: &File,
    output: &Path,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<u64>> {
    struct Gather<'a> {
        stored: &'a Stored,
        heights: Heights<'a>,
        bounds: &'a [[f32; 2]],
        side: usize,
        pages: &'a PresentPages,
        first_page: u64,
        out: &'a File,
        output: &'a Path,
        progress: &'a (dyn Fn(u64) + Sync),
    }
    impl crate::layout::LayoutVisitor for Gather<'_> {
        type Output = Result<Vec<u64>>;
        fn visit<L: Layout>(self, layout: &L) -> Result<Vec<u64>> {
            use std::os::unix::fs::FileExt;
            let block_bytes = terrain::CHECKSUM_BLOCK_BYTES;
            let pages_per_block = (block_bytes / 4096) as u64;
            let per_block = block_bytes / RECORD_BYTES as usize;
            let records = layout.records() as usize;
            let blocks = records.div_ceil(per_block);
            // Present pages before each block: where its pages go in the file.
            let mut before = Vec::with_capacity(blocks);
            let mut total = 0u64;
            for b in 0..blocks as u64 {
                before.push(total);
                total += (b * pages_per_block..(b + 1) * pages_per_block).filter(|&p| self.pages.has(p)).count() as u64;
            }
            let zero_hash = terrain::block_hash(&vec![0u8; block_bytes]);
            let (stored, heights, bounds, side) = (self.stored, self.heights, self.bounds, self.side);
            (0..blocks)
                .into_par_iter()
                .map_init(
                    || vec![Record::default(); per_block],
                    |buf, b| {
                        cancel::check()?;
                        let first = b * per_block;
                        let buf = &mut buf[..per_block.min(records - first)];
                        let bytes_len = std::mem::size_of_val(buf);
                        let page0 = b as u64 * pages_per_block;
                        let present: Vec<u64> =
                            (0..bytes_len.div_ceil(4096) as u64).filter(|&k| self.pages.has(page0 + k)).collect();
                        if present.is_empty() {
                            return Ok(if bytes_len == block_bytes {
                                zero_hash
                            } else {
                                terrain::block_hash(&vec![0u8; bytes_len])
                            });
                        }
                        buf.fill(Record::default());
                        for &k in &present {
                            let lo = (k as usize * 4096) / RECORD_BYTES as usize;
                            let hi = ((k as usize + 1) * 4096).div_ceil(RECORD_BYTES as usize).min(buf.len());
                            for (j, r) in buf[lo..hi].iter_mut().enumerate() {
                                if let Some((x, y)) = layout.coords((first + lo + j) as u64) {
                                    if stored.contains(x, y) {
                                        let [error, radius] = bounds[y as usize * side + x as usize];
                                        *r = Record { z: heights.at(x, y), error, radius };
                                    }
                                }
                            }
                        }
                        let bytes: &[u8] = bytemuck::cast_slice(buf);
                        // Consecutive present pages in one write.
                        let mut i = 0;
                        let mut slot = before[b];
                        while i < present.len() {
                            let mut j = i + 1;
                            while j < present.len() && present[j] == present[j - 1] + 1 {
                                j += 1;
                            }
                            let (s, e) =
                                (present[i] as usize * 4096, ((present[j - 1] as usize + 1) * 4096).min(bytes_len));
                            let at = (self.first_page + slot) * 4096;
                            self.out.write_all_at(&bytes[s..e], at).at(self.output)?;
                            slot += (j - i) as u64;
                            i = j;
                        }
                        (self.progress)(present.len() as u64);
                        Ok(terrain::block_hash(bytes))
                    },
                )
                .collect()
        }
    }
    layout.visit(Gather { stored, heights, bounds, side, pages, first_page, out, output, progress })
}
