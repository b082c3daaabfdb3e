//! `relief layouts`: the page-fault experiment, for every backend. A flight is replayed over the
//! same terrain stored in each index layout (the terrain paper's central experiment), and, with
//! the mesh backends, over the same terrain exported as a mesh, as meta-node trees read through
//! the map ("Virt") and through the buffer pool ("Ext"), and as disk pages in each page layout.
//! Every row counts the pages brought in from storage with the same memory:
//!
//! - map and read access: the misses of an LRU model of a page cache of that size, fed by what the
//!   file's pager takes from the file ([`crate::pager::Pager::observe`]): deterministic,
//!   identical on every machine;
//! - pool access: the pool's own loads, the pool being that size (its I/O thread is held while a
//!   frame adapts and drained after it, so the loads do not depend on timing);
//! - with `os`, the process's real major faults and bytes read from storage on cold runs.
//!
//! Lindstrom & Pascucci report that the hierarchical terrain layouts fault several times less
//! than row-major and tiled orders; El-Sana & Chiang that their explicit pool reads less than the
//! OS paging the tree; Sajadi et al. that spatial page orders read fewer pages than the input
//! order. Each row also says how far it is from the lower bound: the distinct bytes read, packed
//! perfectly into pages.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use serde::Serialize;

use crate::camera::Camera;
use crate::diskpages::build::{build_page_file, PageBuildOptions};
use crate::diskpages::fetch::{FetchOptions, PageSource};
use crate::error::{Error, Result};
use crate::flight::frame::FrameSource;
use crate::format::metanode::MetaNodeFile;
use crate::format::pagefile::{PageFile, PageLayout};
use crate::format::terrain::{TerrainFile, RECORD_BYTES};
use crate::layout::LayoutKind;
use crate::metanode::blocking::BlockingOptions;
use crate::metanode::build::BuildOptions;
use crate::metanode::navigate::{NavOptions, Navigator, PagedStore};
use crate::metanode::VdtMetric;
use crate::pager::device::{DeviceSpec, DeviceStats};
use crate::pager::{Access, Granules, LruCache, LruTrace, MemoryCap, OsFaults, PageGeometry};
use crate::pager::{PageObserver, Pager};
use crate::preprocess::convert::{convert, relayout, ConvertOptions};
use crate::refine::{RefineOptions, Refiner, Strip};
use crate::sys::progress::Progress;

/// The backends the experiment can run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Backend {
    /// The terrain's refinement, one row per index layout.
    Terrain,
    /// Meta-node trees of the terrain's mesh, through the map (virt) and the pool (ext).
    MetaNode,
    /// Disk pages of the terrain's mesh, one row per page layout (read access, as the paper).
    Pages,
}

impl Backend {
    pub const ALL: [Backend; 3] = [Backend::Terrain, Backend::MetaNode, Backend::Pages];

    pub fn name(self) -> &'static str {
        match self {
            Backend::Terrain => "terrain",
            Backend::MetaNode => "meta-node",
            Backend::Pages => "pages",
        }
    }

    pub fn from_name(name: &str) -> Option<Backend> {
        Backend::ALL.into_iter().find(|b| b.name() == name || (name == "metanode" && *b == Backend::MetaNode))
    }
}

/// What to measure.
#[derive(Clone, Debug)]
pub struct LayoutsOptions {
    /// Memory of every row (the model's page cache, or the pool), bytes.
    pub memory_bytes: u64,
    pub page_bytes: u64,
    pub tolerances_px: Vec<f64>,
    /// The terrain's index layouts (rows of the terrain backend).
    pub layouts: Vec<LayoutKind>,
    pub backends: Vec<Backend>,
    /// The mesh backends' input: the terrain's valid window as a mesh of every `mesh_step`-th post.
    pub mesh_step: u32,
    pub width_px: u32,
    pub height_px: u32,
    pub fov_x_deg: f64,
    /// Also count the OS's page faults and storage reads on cold, readahead-free runs.
    pub os: bool,
    /// Run the OS runs under a cgroup memory limit of this many bytes (see `pager::MemoryCap`).
    pub os_cap_bytes: Option<u64>,
    /// Run the OS runs with each file served through this emulated device (see
    /// [`crate::pager::device`]); their times are then the device's.
    pub device: Option<DeviceSpec>,
    pub progress: Progress,
}

/// OS counts of one cold run (the file dropped from the page cache, readahead off).
#[derive(Clone, Debug, Serialize)]
pub struct OsFaultCounts {
    pub major: u64,
    pub major_per_frame_mean: f64,
    pub major_per_frame_max: u64,
    /// Bytes read from storage (`/proc/self/io`), the measure for read and pool access.
    pub read_bytes: u64,
    /// Major faults of each frame.
    pub major_per_frame: Vec<u64>,
    /// Each frame's time, ms: the refinement, adaptation or fetch and, for the pool, waiting for
    /// its reads; with the file cold and its faults and reads served by the storage (or the
    /// emulated device).
    pub ms_per_frame_mean: f64,
    pub ms_per_frame_median: f64,
    pub ms_per_frame: Vec<f64>,
    /// What the emulated device served over the frames (`null` without one).
    pub device: Option<DeviceStats>,
}

/// One backend, layout and access at one tolerance.
#[derive(Clone, Debug, Serialize)]
pub struct FaultRun {
    pub backend: Backend,
    /// The terrain's index layout, "virt" or "ext" for meta-node trees, the page layout.
    pub layout: String,
    pub access: Access,
    pub tolerance: f64,
    /// Pages brought in from storage over the whole flight: the model's misses, or the pool's loads.
    pub faults: u64,
    pub faults_per_frame_mean: f64,
    pub faults_per_frame_max: u64,
    /// Different pages read.
    pub distinct_pages: u64,
    /// faults × page size.
    pub bytes_read: u64,
    /// The backend's own work per frame (refinement, adaptation, fetch), ms.
    pub update_ms_per_frame: f64,
    /// Triangles drawn per frame: a row that reads less because it draws less shows here.
    pub triangles_per_frame_mean: f64,
    /// ⌈distinct bytes read / page size⌉.
    pub lower_bound: u64,
    pub ratio_to_lower_bound: f64,
    /// faults / the faults of the backend's first row at the same tolerance (row-major for
    /// terrains, virt for meta-node trees, raster for pages); null when that row is missing.
    pub ratio_to_first: Option<f64>,
    pub file_bytes: u64,
    pub os: Option<OsFaultCounts>,
    /// Faults per frame (for the plots).
    pub faults_per_frame: Vec<u64>,
}

/// The mesh the mesh backends were run on.
#[derive(Clone, Debug, Serialize)]
pub struct MeshInput {
    pub step: u32,
    pub vertices: u64,
    pub triangles: u64,
}

/// The whole experiment.
#[derive(Clone, Debug, Serialize)]
pub struct LayoutsReport {
    pub input: String,
    pub frames: usize,
    pub memory_bytes: u64,
    pub page_bytes: u64,
    pub cache_pages: u64,
    pub mesh: Option<MeshInput>,
    pub runs: Vec<FaultRun>,
    /// How the OS counts were taken, or why they could not be.
    pub os_note: Option<String>,
}

/// A cache file name for `input` in `what` (keyed by the input's name, size and modification time).
fn cached(input: &Path, cache_dir: &Path, what: &str) -> Result<PathBuf> {
    let meta = std::fs::metadata(input).map_err(|e| Error::io(input, e))?;
    let mtime =
        meta.modified().ok().and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok()).map_or(0, |d| d.as_secs());
    let key = xxhash_rust::xxh3::xxh3_64(format!("{}:{}:{}", input.display(), meta.len(), mtime).as_bytes());
    let stem = input.file_stem().map_or("terrain".into(), |s| s.to_string_lossy().into_owned());
    Ok(cache_dir.join(format!("{stem}-{key:016x}.{what}")))
}

/// The terrain file of `input` in layout `kind`: `input` itself if it is a local terrain file in
/// that layout; otherwise converted (from a DEM) or re-laid out (from a terrain file) once into
/// `cache_dir`, keyed by the input's name, size and modification time. A remote terrain file is
/// first copied into `cache_dir` whole (keyed by its location, payload checksum and ETag): the
/// experiment counts the faults of local files.
pub fn terrain_in_layout(input: &Path, kind: LayoutKind, cache_dir: &Path, progress: Progress) -> Result<PathBuf> {
    if crate::pager::remote::is_remote(input) {
        let copy = local_copy(input, cache_dir, &progress)?;
        return terrain_in_layout(&copy, kind, cache_dir, progress);
    }
    let as_terrain = TerrainFile::open(input).ok();
    if let Some(t) = &as_terrain {
        if t.header().layout == kind {
            return Ok(input.to_path_buf());
        }
    }
    let out = cached(input, cache_dir, &format!("{}.relief", kind.name()))?;
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

/// A remote terrain file copied whole into `cache_dir` (once: kept while its location, payload
/// checksum and ETag stay the same), read in the largest requests the remote source makes.
fn local_copy(location: &Path, cache_dir: &Path, progress: &Progress) -> Result<PathBuf> {
    // The bytes as stored (a file with pages left out is copied as it is, page map and all): the
    // remote file itself, not the terrain's logical view of it. A download, not a backend's read,
    // so it goes around the pager.
    let remote = match crate::pager::remote::is_remote(location) {
        true => Some(std::sync::Arc::new(crate::pager::remote::RemoteFile::open(
            &location.to_string_lossy(),
            crate::pager::remote::RemoteOptions::from_env()?,
        )?)),
        false => None,
    };
    let t = match &remote {
        Some(r) => TerrainFile::from_source(location, r.clone(), Access::Read)?,
        None => TerrainFile::open(location)?,
    };
    let etag = remote.as_ref().and_then(|r| r.etag()).unwrap_or("");
    let checksum = t.header().payload_checksum;
    let key = xxhash_rust::xxh3::xxh3_64(format!("{}:{checksum:016x}:{etag}", location.display()).as_bytes());
    let stem = location.file_stem().map_or("terrain".into(), |s| s.to_string_lossy().into_owned());
    let copy = cache_dir.join(format!("{stem}-{key:016x}.relief"));
    if TerrainFile::open(&copy).is_ok_and(|c| c.header().payload_checksum == checksum) {
        return Ok(copy);
    }
    std::fs::create_dir_all(cache_dir).map_err(|e| Error::io(cache_dir, e))?;
    let source: &dyn crate::pager::source::Source = match &remote {
        Some(r) => &**r,
        None => t.pager().source(),
    };
    let len = source.len();
    let chunk = remote.as_ref().map_or(4 << 20, |r| r.options().max_request).max(4096);
    let bar = progress.bar("download", len, "bytes");
    let mut failed = None;
    crate::sys::atomic_file::write(&copy, |w| {
        let mut buf = vec![0u8; chunk as usize];
        let mut at = 0;
        while at < len {
            let n = (len - at).min(chunk) as usize;
            if let Err(e) = source.read_at(at, &mut buf[..n]) {
                failed = Some(e);
                return Err(std::io::Error::other("remote read failed"));
            }
            std::io::Write::write_all(w, &buf[..n])?;
            at += n as u64;
            bar.inc(n as u64);
        }
        Ok(())
    })
    .map_err(|e| failed.take().unwrap_or(e))?;
    bar.finish_and_clear();
    Ok(copy)
}

/// The LRU model of `memory_bytes` observing `pager`.
fn attach_model(
    pager: &Pager,
    memory_bytes: u64,
    geometry: PageGeometry,
    granules: Option<Granules>,
) -> Result<Arc<LruTrace>> {
    let cache = LruCache::new(memory_bytes, geometry)?;
    let trace = Arc::new(match granules {
        Some(g) => LruTrace::with_granules(cache, geometry, g),
        None => LruTrace::new(cache, geometry),
    });
    pager.observe(trace.clone())?;
    Ok(trace)
}

/// The figures of a run from its per-frame faults and the model's distinct reads.
#[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
fn run_of(
    backend: Backend,
    layout: &str,
    access: Access,
    tolerance: f64,
    per_frame: Vec<u64>,
    trace: &LruTrace,
    update_s: f64,
    triangles: u64,
    file_bytes: u64,
) -> FaultRun {
    let faults: u64 = per_frame.iter().sum();
    let frames = per_frame.len().max(1) as f64;
    let lower_bound = trace.lower_bound_pages();
    FaultRun {
        backend,
        layout: layout.into(),
        access,
        tolerance,
        faults,
        faults_per_frame_mean: faults as f64 / frames,
        faults_per_frame_max: per_frame.iter().copied().max().unwrap_or(0),
        distinct_pages: trace.stats().distinct_pages,
        bytes_read: faults * trace.geometry().page_bytes,
        update_ms_per_frame: update_s * 1e3 / frames,
        triangles_per_frame_mean: triangles as f64 / frames,
        lower_bound,
        ratio_to_lower_bound: if lower_bound > 0 { faults as f64 / lower_bound as f64 } else { 0.0 },
        ratio_to_first: None,
        file_bytes,
        os: None,
        faults_per_frame: per_frame,
    }
}

/// Replays `cameras` over the terrain at `path` at `tolerance_px` through the LRU model.
pub fn run_terrain(
    path: &Path,
    cameras: &[Camera],
    tolerance_px: f64,
    memory_bytes: u64,
    geometry: PageGeometry,
) -> Result<FaultRun> {
    let terrain = TerrainFile::open(path)?;
    let h = terrain.header();
    let granules = Granules { first: h.payload_offset, bytes: RECORD_BYTES as u64, count: h.records };
    let trace = attach_model(terrain.pager(), memory_bytes, geometry, Some(granules))?;
    let options = RefineOptions { tolerance_px, ..Default::default() };
    let (mut refiner, mut strip) = (Refiner::new(1)?, Strip::new());
    let mut per_frame = Vec::with_capacity(cameras.len());
    let (mut update_s, mut triangles) = (0.0, 0);
    for camera in cameras {
        crate::sys::cancel::check()?;
        let t0 = Instant::now();
        refiner.refine_file(&terrain, camera, &options, &mut strip)?;
        update_s += t0.elapsed().as_secs_f64();
        per_frame.push(trace.take().faults);
        triangles += strip.triangle_counts().0;
    }
    // On disk (pages left out do not count, see `format::terrain`).
    let file_bytes = terrain.stored_bytes();
    let layout = h.layout.name();
    Ok(run_of(Backend::Terrain, layout, Access::Map, tolerance_px, per_frame, &trace, update_s, triangles, file_bytes))
}

/// Replays `cameras` over the meta-node file at `path` with `access` (map: the model of the OS
/// page cache; pool: the pool's loads, the pool held during each frame and drained after it).
pub fn run_metanode(
    path: &Path,
    access: Access,
    cameras: &[Camera],
    tolerance_px: f64,
    memory_bytes: u64,
    geometry: PageGeometry,
) -> Result<FaultRun> {
    let file = MetaNodeFile::open_with(path, access)?;
    let trace = attach_model(file.pager(), memory_bytes, geometry, None)?;
    let mut nav = Navigator::new(&file, PagedStore::new(&file), nav_options())?;
    let pool = file.pager().pool();
    // The root meta-nodes loaded at start are not the flight's.
    trace.take();
    let mut loaded = file.pager().reads().pages;
    let mut per_frame = Vec::with_capacity(cameras.len());
    let (mut update_s, mut triangles) = (0.0, 0);
    for camera in cameras {
        crate::sys::cancel::check()?;
        let t0 = Instant::now();
        if let Some(p) = pool {
            p.hold(true);
        }
        nav.update(camera, tolerance_px)?;
        update_s += t0.elapsed().as_secs_f64();
        triangles += nav.triangle_count() as u64;
        let model = trace.take().faults;
        per_frame.push(match pool {
            Some(p) => {
                p.hold(false);
                p.drain()?;
                let now = file.pager().reads().pages;
                let frame = now - loaded;
                loaded = now;
                frame
            }
            None => model,
        });
    }
    let layout = if pool.is_some() { "ext" } else { "virt" };
    let file_bytes = file.pager().source().len();
    Ok(run_of(Backend::MetaNode, layout, access, tolerance_px, per_frame, &trace, update_s, triangles, file_bytes))
}

/// The navigation of the experiment: `relief mesh fly`'s default prefetch (the frontier's blocks).
fn nav_options() -> NavOptions {
    NavOptions { prefetch: crate::metanode::navigate::Prefetch::Frontier, ..NavOptions::default() }
}

/// Replays `cameras` over the page file at `path` (read access, as the paper's fetch).
pub fn run_pages(
    path: &Path,
    cameras: &[Camera],
    tolerance_px: f64,
    memory_bytes: u64,
    geometry: PageGeometry,
) -> Result<FaultRun> {
    let file = PageFile::open_with(path, Access::Read)?;
    let layout = file.header().layout.name();
    let file_bytes = file.pager().source().len();
    let trace = attach_model(file.pager(), memory_bytes, geometry, None)?;
    let mut source = PageSource::new(file, FetchOptions::default());
    let mut per_frame = Vec::with_capacity(cameras.len());
    let (mut update_s, mut triangles) = (0.0, 0);
    for camera in cameras {
        crate::sys::cancel::check()?;
        let t0 = Instant::now();
        let stats = source.update(camera, tolerance_px)?;
        update_s += t0.elapsed().as_secs_f64();
        per_frame.push(trace.take().faults);
        triangles += stats.triangles;
    }
    Ok(run_of(Backend::Pages, layout, Access::Read, tolerance_px, per_frame, &trace, update_s, triangles, file_bytes))
}

/// The same flight cold: `path` opened afresh, readahead off, dropped from the page cache,
/// the process's major faults and storage reads counted per frame.
fn run_os(
    backend: Backend,
    path: &Path,
    access: Access,
    cameras: &[Camera],
    tolerance_px: f64,
    device: Option<DeviceSpec>,
) -> Result<OsFaultCounts> {
    let os = OsFaults::start();
    let mut per_frame = Vec::with_capacity(cameras.len());
    let mut ms_per_frame = Vec::with_capacity(cameras.len());
    let mut read_bytes = 0;
    let mut frame = |f: crate::pager::Faults, started: Instant| {
        ms_per_frame.push(started.elapsed().as_secs_f64() * 1e3);
        per_frame.push(f.faults);
        read_bytes += f.bytes_read;
    };
    let served = match backend {
        Backend::Terrain => {
            let terrain = TerrainFile::open_on(path, Access::Map, device)?;
            terrain.start_cold()?;
            let options = RefineOptions { tolerance_px, ..Default::default() };
            let (mut refiner, mut strip) = (Refiner::new(1)?, Strip::new());
            os.take();
            let first = terrain.pager().device_or_zero();
            for camera in cameras {
                crate::sys::cancel::check()?;
                let t = Instant::now();
                refiner.refine_file(&terrain, camera, &options, &mut strip)?;
                frame(os.take(), t);
            }
            terrain.pager().device().map(|d| d.since(first))
        }
        Backend::MetaNode => {
            let file = MetaNodeFile::open_on(path, access, device)?;
            file.start_cold()?;
            let mut nav = Navigator::new(&file, PagedStore::new(&file), nav_options())?;
            os.take();
            let first = file.pager().device_or_zero();
            for camera in cameras {
                crate::sys::cancel::check()?;
                let t = Instant::now();
                if let Some(p) = file.pager().pool() {
                    p.hold(true);
                }
                nav.update(camera, tolerance_px)?;
                if let Some(p) = file.pager().pool() {
                    p.hold(false);
                    p.drain()?;
                }
                frame(os.take(), t);
            }
            file.pager().device().map(|d| d.since(first))
        }
        Backend::Pages => {
            let file = PageFile::open_on(path, access, device)?;
            file.start_cold()?;
            let first = file.pager().device_or_zero();
            let mut source = PageSource::new(file, FetchOptions::default());
            os.take();
            for camera in cameras {
                crate::sys::cancel::check()?;
                let t = Instant::now();
                source.update(camera, tolerance_px)?;
                frame(os.take(), t);
            }
            source.file().pager().device().map(|d| d.since(first))
        }
    };
    let major: u64 = per_frame.iter().sum();
    let n = cameras.len().max(1) as f64;
    let ms = crate::flight::frame::Summary::of(ms_per_frame.iter().copied());
    Ok(OsFaultCounts {
        major,
        major_per_frame_mean: major as f64 / n,
        major_per_frame_max: per_frame.iter().copied().max().unwrap_or(0),
        read_bytes,
        major_per_frame: per_frame,
        ms_per_frame_mean: ms.mean,
        ms_per_frame_median: ms.median,
        ms_per_frame,
        device: served,
    })
}

/// The mesh backends' files for `input`: the terrain (in `layout_file`) as a mesh of every
/// `step`-th post, its meta-node trees and its page files in every page layout, built once into
/// `cache_dir`.
fn mesh_files(
    input: &Path,
    layout_file: &Path,
    step: u32,
    cache_dir: &Path,
    backends: &[Backend],
    progress: Progress,
) -> Result<(MeshInput, Option<PathBuf>, Vec<PathBuf>)> {
    let terrain = TerrainFile::open(layout_file)?;
    let mesh = crate::mesh::terrain_mesh(&terrain, step)?;
    let info = MeshInput { step, vertices: mesh.positions.len() as u64, triangles: mesh.triangles.len() as u64 };
    let mut tree = None;
    if backends.contains(&Backend::MetaNode) {
        let out = cached(input, cache_dir, &format!("step{step}.rmn"))?;
        if MetaNodeFile::open(&out).is_err() {
            let mut build = BuildOptions::new(u64::MAX / 4, VdtMetric::Length);
            build.progress = progress;
            crate::metanode::build_tree(mesh.clone(), &out, None, &build, BlockingOptions::default())?;
        }
        tree = Some(out);
    }
    let mut pages = Vec::new();
    if backends.contains(&Backend::Pages) {
        for layout in PageLayout::ALL {
            let out = cached(input, cache_dir, &format!("step{step}.{}.rpg", layout.name()))?;
            if PageFile::open(&out).is_err() {
                let mut options = PageBuildOptions::new(4096, layout);
                options.progress = progress;
                build_page_file(&mesh, &out, &options)?;
            }
            pages.push(out);
        }
    }
    Ok((info, tree, pages))
}

/// Runs every backend's rows at every tolerance over `cameras`.
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
    if options.backends.is_empty() {
        return Err(Error::InvalidArgument("no backend to run".into()));
    }
    std::fs::create_dir_all(cache_dir).map_err(|e| Error::io(cache_dir, e))?;
    // Every run of the flight: (backend, file, access).
    let mut plan: Vec<(Backend, PathBuf, Access)> = Vec::new();
    let mut first_layout = None;
    if options.backends.contains(&Backend::Terrain) {
        for &kind in &options.layouts {
            let path = terrain_in_layout(input, kind, cache_dir, options.progress)?;
            first_layout.get_or_insert(path.clone());
            plan.push((Backend::Terrain, path, Access::Map));
        }
    }
    let mut mesh = None;
    if options.backends.iter().any(|b| *b != Backend::Terrain) {
        let layout_file = match &first_layout {
            Some(p) => p.clone(),
            None => terrain_in_layout(input, LayoutKind::Interleaved, cache_dir, options.progress)?,
        };
        let (info, tree, pages) =
            mesh_files(input, &layout_file, options.mesh_step, cache_dir, &options.backends, options.progress)?;
        mesh = Some(info);
        if let Some(t) = tree {
            plan.push((Backend::MetaNode, t.clone(), Access::Map));
            plan.push((Backend::MetaNode, t, Access::Pool { bytes: options.memory_bytes }));
        }
        plan.extend(pages.into_iter().map(|p| (Backend::Pages, p, Access::Read)));
    }
    let mut runs = Vec::new();
    let mut os_note = None;
    let bar = options.progress.bar("layouts", (plan.len() * options.tolerances_px.len()) as u64, "runs");
    for (backend, path, access) in &plan {
        for &tolerance in &options.tolerances_px {
            let m = options.memory_bytes;
            let mut run = match backend {
                Backend::Terrain => run_terrain(path, cameras, tolerance, m, geometry)?,
                Backend::MetaNode => run_metanode(path, *access, cameras, tolerance, m, geometry)?,
                Backend::Pages => run_pages(path, cameras, tolerance, m, geometry)?,
            };
            if options.os {
                if options.device.is_some() {
                    // The device's backing file is read into the page cache before the cap, so
                    // that it is not charged to the capped run (a device's storage is not memory).
                    crate::pager::device::warm_path(path)?;
                }
                let cap = match options.os_cap_bytes.map(MemoryCap::apply).transpose() {
                    Ok(c) => Some(c),
                    Err(e) => {
                        os_note = Some(format!("OS faults not measured: {e}"));
                        None
                    }
                };
                if let Some(cap) = cap {
                    let measured = run_os(*backend, path, *access, cameras, tolerance, options.device);
                    drop(cap);
                    match measured {
                        Ok(os) => {
                            run.os = Some(os);
                            os_note.get_or_insert_with(|| {
                                let cap = match options.os_cap_bytes {
                                    Some(b) => format!("under a cgroup v1 memory cap of {b} bytes"),
                                    None => "without a memory cap".into(),
                                } + &match options.device {
                                    Some(d) => format!(
                                        "; each file served through an emulated device ({d}) (its reads \
                                         are the device's requests, not in /proc/self/io)"
                                    ),
                                    None => String::new(),
                                };
                                format!(
                                    "OS counts: each file opened afresh, readahead turned off (MADV_RANDOM, \
                                     POSIX_FADV_RANDOM), then dropped from the page cache (MADV_DONTNEED, \
                                     posix_fadvise DONTNEED); major faults from getrusage, storage reads from \
                                     /proc/self/io, {cap}"
                                )
                            });
                        }
                        Err(e) => os_note = Some(format!("OS faults not measured: {e}")),
                    }
                }
            }
            runs.push(run);
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    // Ratios to each backend's first row at the same tolerance.
    for k in 0..runs.len() {
        let first =
            runs.iter().find(|r| r.backend == runs[k].backend && r.tolerance == runs[k].tolerance).map(|r| r.faults);
        runs[k].ratio_to_first = first.map(|f| if f > 0 { runs[k].faults as f64 / f as f64 } else { 0.0 });
    }
    Ok(LayoutsReport {
        input: input.display().to_string(),
        frames: cameras.len(),
        memory_bytes: options.memory_bytes,
        page_bytes: options.page_bytes,
        cache_pages,
        mesh,
        runs,
        os_note,
    })
}
