//! `relief layouts`: the terrain paper's central experiment. A flight is replayed over the same
//! terrain stored in each index layout, and the pages refinement touches are counted: in an LRU
//! model of a page cache (deterministic, machine-independent; [`crate::pager`]) and, with `os`, as
//! the process's real page faults after the file is dropped from the OS page cache.
//!
//! Lindstrom & Pascucci report that the hierarchical layouts fault several times less than
//! row-major and tiled orders; this module measures it and how far each layout is from the lower
//! bound (the distinct records touched, packed perfectly into pages).

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::format::terrain::{TerrainFile, RECORD_BYTES};
use crate::layout::LayoutKind;
use crate::pager::{drop_from_page_cache, Granules, LruCache, LruTrace, MemoryCap, PageGeometry};
use crate::preprocess::convert::{convert, relayout, ConvertOptions};
use crate::refine::{RefineOptions, Refiner, Strip};
use crate::sys::mem;
use crate::sys::progress::Progress;

/// What to measure.
#[derive(Clone, Debug)]
pub struct LayoutsOptions {
    /// Page cache size of the model, bytes.
    pub memory_bytes: u64,
    pub page_bytes: u64,
    pub tolerances_px: Vec<f64>,
    pub layouts: Vec<LayoutKind>,
    pub width_px: u32,
    pub height_px: u32,
    pub fov_x_deg: f64,
    /// Also count the OS's page faults on cold, readahead-free mapped runs.
    pub os: bool,
    /// Run the OS runs under a cgroup memory limit of this many bytes (see `pager::MemoryCap`).
    pub os_cap_bytes: Option<u64>,
    pub progress: Progress,
}

/// OS page faults of one run (mapped file, dropped from the page cache first, `MADV_RANDOM`).
#[derive(Clone, Debug, Serialize)]
pub struct OsFaults {
    pub major: u64,
    pub minor: u64,
    pub major_per_frame_mean: f64,
    pub major_per_frame_max: u64,
    /// Major faults of each frame.
    pub major_per_frame: Vec<u64>,
}

/// One layout at one tolerance.
#[derive(Clone, Debug, Serialize)]
pub struct LayoutRun {
    pub layout: String,
    pub tolerance: f64,
    /// Misses of the LRU model over the whole flight.
    pub faults: u64,
    pub faults_per_frame_mean: f64,
    pub faults_per_frame_max: u64,
    pub distinct_pages: u64,
    /// faults × page size.
    pub bytes_read: u64,
    pub refine_ms_per_frame: f64,
    /// ⌈distinct records read × record size / page size⌉.
    pub lower_bound: u64,
    pub ratio_to_lower_bound: f64,
    /// faults / row-major's faults at the same tolerance (null without a row-major run).
    pub ratio_to_row_major: Option<f64>,
    pub records_read: u64,
    pub file_bytes: u64,
    pub os: Option<OsFaults>,
    /// Faults per frame (for the plots).
    pub faults_per_frame: Vec<u64>,
}

/// The whole experiment.
#[derive(Clone, Debug, Serialize)]
pub struct LayoutsReport {
    pub input: String,
    pub frames: usize,
    pub memory_bytes: u64,
    pub page_bytes: u64,
    pub cache_pages: u64,
    pub layouts: Vec<LayoutRun>,
    /// How the OS counts were taken, or why they could not be.
    pub os_note: Option<String>,
}

/// The terrain file of `input` in layout `kind`: `input` itself if it is a terrain file in that
/// layout; otherwise converted (from a DEM) or re-laid out (from a terrain file) once into
/// `cache_dir`, keyed by the input's name, size and modification time.
pub fn terrain_in_layout(input: &Path, kind: LayoutKind, cache_dir: &Path, progress: Progress) -> Result<PathBuf> {
    let as_terrain = TerrainFile::open(input).ok();
    if let Some(t) = &as_terrain {
        if t.header().layout == kind {
            return Ok(input.to_path_buf());
        }
    }
    let meta = std::fs::metadata(input).map_err(|e| Error::io(input, e))?;
    let mtime =
        meta.modified().ok().and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok()).map_or(0, |d| d.as_secs());
    let key = xxhash_rust::xxh3::xxh3_64(format!("{}:{}:{}", input.display(), meta.len(), mtime).as_bytes());
    let stem = input.file_stem().map_or("terrain".into(), |s| s.to_string_lossy().into_owned());
    let out = cache_dir.join(format!("{stem}-{key:016x}.{}.relief", kind.name()));
    if TerrainFile::open(&out).is_ok() {
        return Ok(out);
    }
    std::fs::create_dir_all(cache_dir).map_err(|e| Error::io(cache_dir, e))?;
    let mut opts = ConvertOptions::new(kind);
    opts.progress = progress;
    match &as_terrain {
        Some(t) => relayout(t, &out, &opts)?,
        None => convert(input, &out, &opts)?,
    };
    Ok(out)
}

/// Replays `cameras` over `terrain` at `tolerance_px` through the LRU model.
pub fn run_model(
    terrain: &TerrainFile,
    cameras: &[Camera],
    tolerance_px: f64,
    memory_bytes: u64,
    geometry: PageGeometry,
) -> Result<LayoutRun> {
    let h = terrain.header();
    let granules = Granules { first: h.payload_offset, bytes: RECORD_BYTES as u64, count: h.records };
    let trace = LruTrace::with_granules(LruCache::new(memory_bytes, geometry)?, geometry, granules);
    let options = RefineOptions { tolerance_px, ..Default::default() };
    let mut refiner = Refiner::new(1)?;
    let mut strip = Strip::new();
    let mut per_frame = Vec::with_capacity(cameras.len());
    let mut refine_s = 0.0;
    for camera in cameras {
        crate::sys::cancel::check()?;
        let t0 = Instant::now();
        refiner.refine_observed(terrain, &trace, camera, &options, &mut strip)?;
        refine_s += t0.elapsed().as_secs_f64();
        per_frame.push(crate::pager::PageObserver::take(&trace).faults);
    }
    let stats = trace.stats();
    let records_read = trace.distinct_bytes() / RECORD_BYTES as u64;
    let lower_bound = trace.lower_bound_pages();
    let frames = cameras.len().max(1) as f64;
    Ok(LayoutRun {
        layout: terrain.header().layout.name().into(),
        tolerance: tolerance_px,
        faults: stats.misses,
        faults_per_frame_mean: stats.misses as f64 / frames,
        faults_per_frame_max: per_frame.iter().copied().max().unwrap_or(0),
        distinct_pages: stats.distinct_pages,
        bytes_read: stats.misses * geometry.page_bytes,
        refine_ms_per_frame: refine_s * 1e3 / frames,
        lower_bound,
        ratio_to_lower_bound: if lower_bound > 0 { stats.misses as f64 / lower_bound as f64 } else { 0.0 },
        ratio_to_row_major: None,
        records_read,
        file_bytes: terrain.header().payload_offset + terrain.header().payload_bytes,
        os: None,
        faults_per_frame: per_frame,
    })
}

/// Replays `cameras` over the mapped file at `path`, cold: the file is dropped from the page
/// cache, mapped afresh with readahead off, and the process's faults counted per frame.
pub fn run_os(path: &Path, cameras: &[Camera], tolerance_px: f64) -> Result<OsFaults> {
    drop_from_page_cache(path)?;
    let terrain = TerrainFile::open(path)?;
    terrain.advise_random()?;
    let options = RefineOptions { tolerance_px, ..Default::default() };
    let mut refiner = Refiner::new(1)?;
    let mut strip = Strip::new();
    let (major0, minor0) = mem::page_faults();
    let mut per_frame = Vec::with_capacity(cameras.len());
    let mut last = major0;
    for camera in cameras {
        crate::sys::cancel::check()?;
        refiner.refine_file(&terrain, camera, &options, &mut strip)?;
        let (major, _) = mem::page_faults();
        per_frame.push(major - last);
        last = major;
    }
    let (major1, minor1) = mem::page_faults();
    let major = major1 - major0;
    Ok(OsFaults {
        major,
        minor: minor1 - minor0,
        major_per_frame_mean: major as f64 / cameras.len().max(1) as f64,
        major_per_frame_max: per_frame.iter().copied().max().unwrap_or(0),
        major_per_frame: per_frame,
    })
}

/// Runs every layout at every tolerance over `cameras`.
pub fn run_layouts(
    input: &Path,
    cameras: &[Camera],
    cache_dir: &Path,
    options: &LayoutsOptions,
) -> Result<LayoutsReport> {
    let geometry = PageGeometry::new(options.page_bytes)?;
    let cache_pages = options.memory_bytes / geometry.page_bytes;
    if cache_pages == 0 {
        return Err(Error::InvalidArgument(format!(
            "memory budget of {} bytes is smaller than one {}-byte page",
            options.memory_bytes, geometry.page_bytes
        )));
    }
    if options.tolerances_px.iter().any(|t| !(t.is_finite() && *t > 0.0)) || options.tolerances_px.is_empty() {
        return Err(Error::InvalidArgument("tolerances must be positive pixels".into()));
    }
    let mut runs = Vec::new();
    let mut os_note = None;
    let bar = options.progress.bar("layouts", (options.layouts.len() * options.tolerances_px.len()) as u64, "runs");
    for &kind in &options.layouts {
        let path = terrain_in_layout(input, kind, cache_dir, options.progress)?;
        for &tolerance in &options.tolerances_px {
            let mut run = {
                let terrain = TerrainFile::open(&path)?;
                run_model(&terrain, cameras, tolerance, options.memory_bytes, geometry)?
            };
            if options.os {
                let cap = match options.os_cap_bytes {
                    Some(b) => match MemoryCap::apply(b) {
                        Ok(c) => Some(c),
                        Err(e) => {
                            os_note = Some(format!("OS faults not measured: {e}"));
                            runs.push(run);
                            bar.inc(1);
                            continue;
                        }
                    },
                    None => None,
                };
                let measured = run_os(&path, cameras, tolerance);
                drop(cap);
                match measured {
                    Ok(os) => {
                        run.os = Some(os);
                        os_note.get_or_insert_with(|| {
                            let cap = match options.os_cap_bytes {
                                Some(b) => format!("under a cgroup v1 memory cap of {b} bytes"),
                                None => "without a memory cap (--os-cap sets one)".into(),
                            };
                            format!(
                                "OS faults: file dropped from the page cache (posix_fadvise DONTNEED), mapped \
                                 afresh with madvise(MADV_RANDOM), major faults from getrusage, {cap}"
                            )
                        });
                    }
                    Err(e) => os_note = Some(format!("OS faults not measured: {e}")),
                }
            }
            runs.push(run);
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    // Ratios to row-major at the same tolerance.
    let row_major: Vec<(f64, u64)> =
        runs.iter().filter(|r| r.layout == LayoutKind::RowMajor.name()).map(|r| (r.tolerance, r.faults)).collect();
    for r in &mut runs {
        r.ratio_to_row_major =
            row_major
                .iter()
                .find(|(t, _)| *t == r.tolerance)
                .map(|&(_, f)| if f > 0 { r.faults as f64 / f as f64 } else { 0.0 });
    }
    Ok(LayoutsReport {
        input: input.display().to_string(),
        frames: cameras.len(),
        memory_bytes: options.memory_bytes,
        page_bytes: options.page_bytes,
        cache_pages,
        layouts: runs,
        os_note,
    })
}
