//! The frame protocol every backend implements, and the one headless flight loop over it.
//!
//! A [`FrameSource`] adapts to a camera each frame and hands over what to draw ([`Frame`]): the
//! terrain's refinement a triangle strip of grid posts ([`super::terrain::TerrainSource`]), the
//! meta-node navigator and the disk-page fetch a triangle list, [`StaticMesh`] a whole mesh. Each
//! update reports the same [`FrameStats`], so the backends' figures can be put side by side.
//!
//! [`fly`] runs a source along cameras, draws each frame through an optional [`Presenter`] (the
//! renderer lives outside this crate), and reports one [`FlightReport`] schema for every
//! backend: per frame the same keys, and per key the mean, median, maximum and total.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::heightcache::HeightCacheStats;
use crate::mesh::{Bounds, Mesh};
use crate::refine::Strip;
use crate::sys::progress::Progress;

/// What a source hands the renderer for one frame.
#[derive(Clone, Copy, Debug)]
pub enum Frame<'a> {
    /// A terrain: one triangle strip of grid posts (the renderer holds the heights).
    Strip(&'a Strip),
    /// A mesh: triangles, three world positions each.
    Triangles(&'a [[f32; 3]]),
}

impl Frame<'_> {
    /// Non-degenerate triangles drawn.
    pub fn triangle_count(&self) -> u64 {
        match self {
            Frame::Strip(s) => s.triangle_counts().0,
            Frame::Triangles(t) => t.len() as u64 / 3,
        }
    }

    /// FNV-1a (64-bit) of what is drawn, in order: the strip's grid posts, or the triangles'
    /// coordinate bits. Equal digests: the same geometry.
    pub fn digest(&self) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |w: u32| {
            for b in w.to_le_bytes() {
                h = (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3);
            }
        };
        match self {
            Frame::Strip(s) => s.vertices.iter().for_each(|v| {
                eat(v.x);
                eat(v.y)
            }),
            Frame::Triangles(t) => t.iter().flatten().for_each(|c| eat(c.to_bits())),
        }
        h
    }
}

/// A backend flown frame by frame.
pub trait FrameSource {
    /// Adapts to `camera` at `tolerance_px` (screen-space error, pixels) and says what happened.
    fn update(&mut self, camera: &Camera, tolerance_px: f64) -> Result<FrameStats>;
    /// What to draw now.
    fn frame(&self) -> Frame<'_>;
    /// The world box of everything the source can draw (paths, the first view).
    fn bounds(&self) -> Bounds;
    /// What the source is, for reports ("terrain, interleaved, map", …).
    fn describe(&self) -> String;
    /// What the source changes from frame to frame, in words for reports (`summary.changes`):
    /// one of [`NODE_CHANGES`] (the default: nodes split and collapsed, [`FrameStats::splits`]
    /// and [`FrameStats::collapses`]), [`PAGE_CHANGES`] ([`FrameStats::pages_gained`] and
    /// [`FrameStats::pages_lost`]), [`STRIP_CHANGES`] or [`NO_CHANGES`]; the summary line
    /// prints the counters it names.
    fn changes(&self) -> &'static str {
        NODE_CHANGES
    }
    /// Whether a flight should converge the first view (and every jump) before drawing it
    /// unless told otherwise: a source whose single update can stop short of the view's front
    /// (the meta-node navigator, whose pool puts off what it misses). The command line then
    /// converges for [`DEFAULT_CONVERGE_TIMEOUT`].
    fn converges_by_default(&self) -> bool {
        false
    }
    /// Updates for `camera` until nothing the view needs is missing (a remote source waiting for
    /// its fetches), at most `timeout`; the number of updates, or `None` for a source that never
    /// misses (every update is already complete).
    fn settle(&mut self, _camera: &Camera, _tolerance_px: f64, _timeout: std::time::Duration) -> Result<Option<u64>> {
        Ok(None)
    }
    /// Updates for `camera` until the view is complete (nothing it needs is missing, and an
    /// update changes nothing), at most `timeout`: the first view of a flight is then as fine as a
    /// still camera's after any number of frames. Returns the updates made, whether the view
    /// converged in time and the I/O the updates did (the flight fills in the time, faults and
    /// triangles). The default, for sources whose every update is complete: one update.
    fn converge(&mut self, camera: &Camera, tolerance_px: f64, _timeout: std::time::Duration) -> Result<Convergence> {
        let s = self.update(camera, tolerance_px)?;
        Ok(Convergence { updates: 1, ..Convergence::default() }.with(&s).ended(ConvergeEnd::Complete))
    }
}

/// [`FrameSource::changes`] of the meta-node navigator: nodes split and collapsed.
pub const NODE_CHANGES: &str = "splits + collapses";
/// [`FrameSource::changes`] of the disk-page fetch: pages that entered and left the frame's
/// working set ([`FrameStats::pages_gained`], [`FrameStats::pages_lost`]).
pub const PAGE_CHANGES: &str = "pages gained + lost";
/// [`FrameSource::changes`] of terrain refinement: the strip is refined anew each frame, so
/// there is no split or collapse to count; its length ([`FrameStats::strip_len`]) is the figure.
pub const STRIP_CHANGES: &str = "strip vertices";
/// [`FrameSource::changes`] of a source that never changes ([`StaticMesh`]).
pub const NO_CHANGES: &str = "none";

/// How long a flight converges the first view and every jump by default, for sources that
/// [converge by default](FrameSource::converges_by_default).
pub const DEFAULT_CONVERGE_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(2);

/// Why converging the first view stopped.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ConvergeEnd {
    /// Nothing the view needs is missing and an update changes nothing.
    #[default]
    Complete,
    /// The time allowed ran out first.
    Timeout,
    /// Updates stopped making progress: no update in [`STALL_UPDATES`] drew more triangles or
    /// missed fewer blocks than every update before it (the view's front does not fit the memory
    /// given, so loads evict what the next update needs).
    Stalled,
}

/// Updates without a new best (most triangles or fewest misses) after which converging gives up.
pub const STALL_UPDATES: u64 = 32;

/// A jump's convergence: before frame `frame` was updated.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct JumpConvergence {
    pub frame: usize,
    pub convergence: Convergence,
}

/// Whether the view jumps from camera `a` to `b`: the eye moves more than half its distance to
/// what it looks at, or the view direction turns by more than 30°. Steady paths (an orbit of 30
/// frames turns 12° a frame) stay below both; a cut to another place does not.
pub fn is_jump(a: &Camera, b: &Camera) -> bool {
    let (da, db) = (a.look_at_world - a.eye_in_world, b.look_at_world - b.eye_in_world);
    let scale = da.length().max(db.length());
    if scale.is_nan() || scale <= 0.0 {
        return false;
    }
    let moved = a.eye_in_world.distance(b.eye_in_world) > 0.5 * scale;
    let turned = da.normalize_or_zero().dot(db.normalize_or_zero()) < 30f64.to_radians().cos();
    moved || turned
}

/// What converging the first view took ([`FrameSource::converge`], before frame 0).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Convergence {
    /// Updates made, whether the view was complete, and if not why converging stopped.
    pub updates: u64,
    pub complete: bool,
    pub end: ConvergeEnd,
    /// Wall time, ms (device waits included), and major page faults meanwhile.
    pub ms: f64,
    pub major_faults: u64,
    /// The converged view's triangles.
    pub triangles: u64,
    /// What the updates read: pages, and the emulated device's requests and time.
    pub pages_read: u64,
    pub device_requests: u64,
    pub device_ms: f64,
    /// What was left when converging stopped short (0 when complete): the last update's wanted
    /// switches put off because their block was not in memory, and its splits and collapses
    /// (the front was still moving).
    pub misses_left: u64,
    pub changes_left: u64,
}

impl Convergence {
    /// How converging stopped: sets [`end`](Self::end) and `complete` (whether it is
    /// [`ConvergeEnd::Complete`]) together.
    pub fn ended(self, end: ConvergeEnd) -> Convergence {
        Convergence { complete: end == ConvergeEnd::Complete, end, ..self }
    }

    /// Adds one update's reads.
    pub fn with(mut self, s: &FrameStats) -> Convergence {
        self.pages_read += s.pages_read;
        self.device_requests += s.device_requests;
        self.device_ms += s.device_ms;
        self
    }
}

/// What one update did: the same fields for every backend, zero where a backend has nothing to
/// count.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct FrameStats {
    /// The source's own work this frame (refinement, adaptation or fetch), ms; `null` when it had
    /// nothing new (the refinement thread had no strip ready).
    pub update_ms: Option<f64>,
    /// Whether [`FrameSource::frame`] changed (the renderer uploads it again).
    pub changed: bool,
    /// Non-degenerate triangles to draw.
    pub triangles: u64,
    /// Strip vertices (terrains).
    pub strip_len: u64,
    /// Nodes split and collapsed (meta-node trees; 0 for other backends).
    pub splits: u64,
    pub collapses: u64,
    /// The disk-page fetch: pages in this frame's set that were not in the last one's, and pages
    /// of the last frame's set that this one dropped (0 for other backends).
    pub pages_gained: u64,
    pub pages_lost: u64,
    /// Wanted splits or collapses put off because their block was not in memory (pool access).
    pub misses: u64,
    /// Pool holders taken back off the free list with their block intact.
    pub second_chance_hits: u64,
    /// Pages and bytes the backend's pager read from its file (read and pool access; what a map
    /// reads shows as page faults).
    pub pages_read: u64,
    pub bytes_read: u64,
    /// The disk-page fetch: pages the k-d query named, pages fetched after culling, the seek
    /// distance of the reads in pages, and the time the reads took, ms (the `pread`s with read
    /// access, the lookups and waits with the pool; 0 with map access, whose faults fall in the
    /// decoding).
    pub pages_candidate: u64,
    pub pages_requested: u64,
    pub seek_pages: u64,
    pub read_ms: f64,
    /// Requests an emulated device under the file served during this update (the pool's
    /// background reads included) and their service time, ms (0 without one; see
    /// [`crate::pager::device`]).
    pub device_requests: u64,
    pub device_ms: f64,
    /// Camera updates between this frame's camera and the one its geometry was made for.
    pub lag_frames: u64,
    /// A remote terrain: whether the drawn geometry is coarser than wanted (records or heights
    /// not here yet), the requests and body bytes this update's fetches cost, and the causal
    /// round trips of the data drawn (1: the opening request alone).
    pub coarse: bool,
    pub requests: u64,
    pub net_bytes: u64,
    pub round_trips: u64,
}

impl FrameStats {
    /// 100 × misses / (splits + collapses + misses), 0 when all are 0.
    pub fn miss_pct(&self) -> f64 {
        pct(self.misses, self.splits + self.collapses)
    }
}

/// 100 × `misses` / (`done` + `misses`), 0 when both are 0.
pub fn pct(misses: u64, done: u64) -> f64 {
    let all = misses + done;
    if all == 0 {
        0.0
    } else {
        100.0 * misses as f64 / all as f64
    }
}

/// Draws frames: the GPU side of a flight, outside this crate.
pub trait Presenter {
    /// Draws `frame` as `camera` sees it, uploading it first when `changed`, and waits for the
    /// GPU; returns the bytes sent to the GPU.
    fn present(&mut self, frame: Frame<'_>, changed: bool, camera: &Camera) -> Result<u64>;
    /// Writes the last image drawn as a PNG.
    fn save(&mut self, path: &Path) -> Result<()>;
    /// The device, for reports.
    fn adapter(&self) -> String;
    /// GPU memory the presenter keeps for the source's data (a terrain's heights), bytes.
    fn resident_bytes(&self) -> u64 {
        0
    }
    /// The GPU height cache's figures of the last frame (zero where there are no heights).
    fn heights(&self) -> HeightCacheStats {
        HeightCacheStats::default()
    }
    /// The paged imagery cache's figures of the last frame (zero where no image is paged).
    fn imagery(&self) -> HeightCacheStats {
        HeightCacheStats::default()
    }
}

/// Settings of a headless flight.
#[derive(Clone, Debug)]
pub struct FlightOptions {
    /// Image size; every camera must have it.
    pub width_px: u32,
    pub height_px: u32,
    /// Screen-space tolerance handed to the source, pixels.
    pub tolerance_px: f64,
    /// Start frames at least this many milliseconds apart (0: back to back). Without rendering
    /// this stands in for a display's frame time, during which an I/O thread can prefetch; the
    /// wait is not counted in `frame_ms`.
    pub pace_ms: f64,
    /// Write every frame as `frame_00000.png` here (with a presenter).
    pub frames_out: Option<PathBuf>,
    /// Write the report as JSON here.
    pub stats_out: Option<PathBuf>,
    /// After the last frame, how long a source that missed data (a remote terrain) may take to
    /// get everything the last view needs ([`FrameSource::settle`]) before the flight fails.
    pub settle_timeout: std::time::Duration,
    /// Converge the first view before frame 0 ([`FrameSource::converge`]) for at most this long
    /// (`None`: frame 0 is the first update).
    pub converge_timeout: Option<std::time::Duration>,
    pub progress: Progress,
}

impl FlightOptions {
    pub fn new(width_px: u32, height_px: u32, tolerance_px: f64) -> FlightOptions {
        FlightOptions {
            width_px,
            height_px,
            tolerance_px,
            pace_ms: 0.0,
            frames_out: None,
            stats_out: None,
            settle_timeout: std::time::Duration::from_secs(120),
            converge_timeout: None,
            progress: Progress::hidden(),
        }
    }
}

/// One frame of a flight: the source's figures and the loop's.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct FrameRecord {
    pub frame: usize,
    #[serde(flatten)]
    pub stats: FrameStats,
    pub miss_pct: f64,
    /// Upload, draw and finish on the GPU (PNG writing excluded), ms; 0 without a presenter.
    pub render_ms: f64,
    /// Wall time of the whole frame (update, render, PNG), ms.
    pub frame_ms: f64,
    /// Bytes sent to the GPU this frame.
    pub upload_bytes: u64,
    /// When the frame ended, seconds from the flight's start (pacing waits included).
    pub end_s: f64,
    /// The process's page faults while the frame's update ran: major (read from storage) and
    /// minor (mapped from memory, readahead included).
    pub major_faults: u64,
    pub minor_faults: u64,
    /// GPU heights: the whole grid resident, or the height cache's frame (bytes in use within
    /// the budget, tiles resident and uploaded, fallbacks to coarser tiles).
    pub gpu_heights: HeightCacheStats,
    /// Paged imagery: the imagery cache's frame, as `gpu_heights` (zero otherwise).
    pub gpu_imagery: HeightCacheStats,
}

/// Mean, median, maximum and total of one figure over a flight's frames.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Summary {
    pub mean: f64,
    pub median: f64,
    pub max: f64,
    pub total: f64,
}

impl Summary {
    /// Over `values` (empty: all zero).
    pub fn of(values: impl IntoIterator<Item = f64>) -> Summary {
        let mut v: Vec<f64> = values.into_iter().collect();
        if v.is_empty() {
            return Summary::default();
        }
        let total: f64 = v.iter().sum();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let median = if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) };
        Summary { mean: total / n as f64, median, max: v[n - 1], total }
    }
}

/// A whole flight's figures: the same keys for every backend.
#[derive(Clone, Debug, Serialize)]
pub struct FlightSummary {
    pub frames: usize,
    pub fps: f64,
    pub wall_s: f64,
    pub width: u32,
    pub height: u32,
    pub tolerance_px: f64,
    /// What was flown ([`FrameSource::describe`]).
    pub source: String,
    /// What it changes from frame to frame ([`FrameSource::changes`]): which counters are its own.
    pub changes: &'static str,
    /// The device that drew it, or why none did.
    pub adapter: String,
    /// GPU memory kept for the source's data, bytes.
    pub resident_gpu_bytes: u64,
    /// Over the flight: 100 × Σ misses / (Σ splits + Σ collapses + Σ misses).
    pub miss_pct: f64,
    /// Over the frames that produced something new.
    pub update_ms: Summary,
    pub render_ms: Summary,
    pub frame_ms: Summary,
    pub triangles: Summary,
    pub strip_len: Summary,
    pub upload_bytes: Summary,
    pub splits: Summary,
    pub collapses: Summary,
    pub pages_gained: Summary,
    pub pages_lost: Summary,
    pub misses: Summary,
    pub second_chance_hits: Summary,
    pub pages_read: Summary,
    pub bytes_read: Summary,
    pub pages_candidate: Summary,
    pub pages_requested: Summary,
    pub seek_pages: Summary,
    pub read_ms: Summary,
    pub device_requests: Summary,
    pub device_ms: Summary,
    pub lag_frames: Summary,
    pub major_faults: Summary,
    pub minor_faults: Summary,
    /// GPU height memory in use, height-tile upload bytes, tiles resident and wanted tiles that
    /// fell back to a coarser level, per frame.
    pub gpu_height_bytes: Summary,
    pub height_upload_bytes: Summary,
    pub tiles_resident: Summary,
    pub height_fallbacks: Summary,
    /// The render thread's time in the height cache's step, microseconds.
    pub height_step_us: Summary,
    /// Paged imagery: GPU memory in use, tile upload bytes, tiles resident and wanted tiles that
    /// fell back to a coarser level, per frame.
    pub gpu_imagery_bytes: Summary,
    pub imagery_upload_bytes: Summary,
    pub imagery_tiles_resident: Summary,
    pub imagery_fallbacks: Summary,
    /// The render thread's time in the imagery cache's step, microseconds.
    pub imagery_step_us: Summary,
    /// A remote terrain: frames drawn coarser than wanted (data missing), the first frame that
    /// was not, the causal round trips it waited for and when it ended (seconds from the start);
    /// requests and body bytes over the flight.
    pub coarse_frames: u64,
    pub first_complete_frame: Option<usize>,
    pub first_complete_round_trips: Option<u64>,
    pub first_complete_s: Option<f64>,
    pub requests: u64,
    pub net_bytes: u64,
    /// Updates of the last camera after the flight until nothing was missing (`null`: the
    /// source never misses), and the final frame: triangles and [`Frame::digest`] (hex), equal
    /// for the same geometry from a local or a remote file.
    pub settle_updates: Option<u64>,
    /// The first view converged before frame 0 (`null`: it was not asked for).
    pub converge: Option<Convergence>,
    /// Frames after a jump ([`is_jump`]) converged before their update, with what it took
    /// (with a converge timeout only).
    pub jumps: Vec<JumpConvergence>,
    pub final_triangles: u64,
    pub final_digest: String,
}

/// A flight: `{"frames": […], "summary": {…}}`.
#[derive(Clone, Debug, Serialize)]
pub struct FlightReport {
    pub frames: Vec<FrameRecord>,
    pub summary: FlightSummary,
}

impl FlightSummary {
    fn of(frames: &[FrameRecord], wall_s: f64, options: &FlightOptions, source: String, adapter: String) -> Self {
        let s = |f: fn(&FrameRecord) -> f64| Summary::of(frames.iter().map(f));
        let total = |f: fn(&FrameRecord) -> u64| frames.iter().map(f).sum::<u64>();
        // Remote sources only: a local one has no round trips.
        let first_complete = frames.iter().find(|f| !f.stats.coarse && f.stats.round_trips > 0);
        FlightSummary {
            frames: frames.len(),
            fps: if wall_s > 0.0 { frames.len() as f64 / wall_s } else { 0.0 },
            wall_s,
            width: options.width_px,
            height: options.height_px,
            tolerance_px: options.tolerance_px,
            source,
            changes: NODE_CHANGES,
            adapter,
            resident_gpu_bytes: 0,
            miss_pct: pct(total(|f| f.stats.misses), total(|f| f.stats.splits + f.stats.collapses)),
            update_ms: Summary::of(frames.iter().filter_map(|f| f.stats.update_ms)),
            render_ms: s(|f| f.render_ms),
            frame_ms: s(|f| f.frame_ms),
            triangles: s(|f| f.stats.triangles as f64),
            strip_len: s(|f| f.stats.strip_len as f64),
            upload_bytes: s(|f| f.upload_bytes as f64),
            splits: s(|f| f.stats.splits as f64),
            collapses: s(|f| f.stats.collapses as f64),
            pages_gained: s(|f| f.stats.pages_gained as f64),
            pages_lost: s(|f| f.stats.pages_lost as f64),
            misses: s(|f| f.stats.misses as f64),
            second_chance_hits: s(|f| f.stats.second_chance_hits as f64),
            pages_read: s(|f| f.stats.pages_read as f64),
            bytes_read: s(|f| f.stats.bytes_read as f64),
            pages_candidate: s(|f| f.stats.pages_candidate as f64),
            pages_requested: s(|f| f.stats.pages_requested as f64),
            seek_pages: s(|f| f.stats.seek_pages as f64),
            read_ms: s(|f| f.stats.read_ms),
            device_requests: s(|f| f.stats.device_requests as f64),
            device_ms: s(|f| f.stats.device_ms),
            lag_frames: s(|f| f.stats.lag_frames as f64),
            major_faults: s(|f| f.major_faults as f64),
            minor_faults: s(|f| f.minor_faults as f64),
            gpu_height_bytes: s(|f| f.gpu_heights.in_use_bytes as f64),
            height_upload_bytes: s(|f| f.gpu_heights.upload_bytes as f64),
            tiles_resident: s(|f| f.gpu_heights.tiles_resident as f64),
            height_fallbacks: s(|f| f.gpu_heights.fallbacks as f64),
            height_step_us: s(|f| f.gpu_heights.step_us as f64),
            gpu_imagery_bytes: s(|f| f.gpu_imagery.in_use_bytes as f64),
            imagery_upload_bytes: s(|f| f.gpu_imagery.upload_bytes as f64),
            imagery_tiles_resident: s(|f| f.gpu_imagery.tiles_resident as f64),
            imagery_fallbacks: s(|f| f.gpu_imagery.fallbacks as f64),
            imagery_step_us: s(|f| f.gpu_imagery.step_us as f64),
            coarse_frames: frames.iter().filter(|f| f.stats.coarse).count() as u64,
            first_complete_frame: first_complete.map(|f| f.frame),
            first_complete_round_trips: first_complete.map(|f| f.stats.round_trips),
            first_complete_s: first_complete.map(|f| f.end_s),
            requests: total(|f| f.stats.requests),
            net_bytes: total(|f| f.stats.net_bytes),
            settle_updates: None,
            converge: None,
            jumps: Vec::new(),
            final_triangles: 0,
            final_digest: String::new(),
        }
    }
}

/// Flies `source` along `cameras`, one frame each, drawing every frame with `presenter` when
/// there is one (else the update alone is timed); writes the PNGs and the JSON report where
/// `options` asks, and returns the report.
pub fn fly<'p>(
    source: &mut dyn FrameSource,
    cameras: &[Camera],
    mut presenter: Option<&mut (dyn Presenter + 'p)>,
    options: &FlightOptions,
) -> Result<FlightReport> {
    if cameras.is_empty() {
        return Err(Error::InvalidArgument("a flight needs at least one camera".into()));
    }
    let size = (options.width_px, options.height_px);
    if let Some((k, c)) = cameras.iter().enumerate().find(|(_, c)| (c.width_px, c.height_px) != size) {
        return Err(Error::InvalidArgument(format!(
            "camera {k} is {} x {} pixels, the flight {} x {}",
            c.width_px, c.height_px, size.0, size.1
        )));
    }
    if let (Some(dir), Some(_)) = (&options.frames_out, &presenter) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    // Timed, with the faults it took and the triangles it reached.
    let converge_at = |source: &mut dyn FrameSource, camera: &Camera, timeout| -> Result<Convergence> {
        let (t0, faults0) = (Instant::now(), crate::sys::mem::page_faults());
        let c = source.converge(camera, options.tolerance_px, timeout)?;
        Ok(Convergence {
            ms: t0.elapsed().as_secs_f64() * 1e3,
            major_faults: crate::sys::mem::page_faults().0 - faults0.0,
            triangles: source.frame().triangle_count(),
            ..c
        })
    };
    let converge = match (options.converge_timeout, cameras.first()) {
        (Some(timeout), Some(first)) => Some(converge_at(&mut *source, first, timeout)?),
        _ => None,
    };
    let mut jumps = Vec::new();
    let bar = options.progress.bar("fly", cameras.len() as u64, "frames");
    let mut frames = Vec::with_capacity(cameras.len());
    let t_all = Instant::now();
    let mut next_start = Instant::now();
    for (k, camera) in cameras.iter().enumerate() {
        crate::sys::cancel::check()?;
        if let Some(wait) = next_start.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        if let (Some(timeout), true) = (options.converge_timeout, k > 0 && is_jump(&cameras[k - 1], camera)) {
            // After a cut the view starts over, as frame 0 does; timed apart from the frame.
            jumps.push(JumpConvergence { frame: k, convergence: converge_at(&mut *source, camera, timeout)? });
        }
        next_start = Instant::now() + std::time::Duration::from_secs_f64(options.pace_ms.max(0.0) / 1e3);
        let t0 = Instant::now();
        let faults0 = crate::sys::mem::page_faults();
        let stats = source.update(camera, options.tolerance_px)?;
        let faults1 = crate::sys::mem::page_faults();
        let t_render = Instant::now();
        let (mut upload_bytes, mut gpu_heights, mut gpu_imagery) = (0, Default::default(), Default::default());
        if let Some(p) = presenter.as_deref_mut() {
            upload_bytes = p.present(source.frame(), stats.changed || k == 0, camera)?;
            gpu_heights = p.heights();
            gpu_imagery = p.imagery();
        }
        let render_ms = if presenter.is_some() { t_render.elapsed().as_secs_f64() * 1e3 } else { 0.0 };
        if let (Some(p), Some(dir)) = (presenter.as_deref_mut(), &options.frames_out) {
            p.save(&dir.join(format!("frame_{k:05}.png")))?;
        }
        frames.push(FrameRecord {
            frame: k,
            stats,
            miss_pct: stats.miss_pct(),
            render_ms,
            frame_ms: t0.elapsed().as_secs_f64() * 1e3,
            upload_bytes,
            end_s: t_all.elapsed().as_secs_f64(),
            major_faults: faults1.0 - faults0.0,
            minor_faults: faults1.1 - faults0.1,
            gpu_heights,
            gpu_imagery,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    let wall_s = t_all.elapsed().as_secs_f64();
    let settle_updates = match cameras.last() {
        Some(last) => source.settle(last, options.tolerance_px, options.settle_timeout)?,
        None => None,
    };
    let adapter = presenter.as_ref().map_or_else(|| "none (update only)".to_string(), |p| p.adapter());
    let mut summary = FlightSummary::of(&frames, wall_s, options, source.describe(), adapter);
    summary.changes = source.changes();
    summary.resident_gpu_bytes = presenter.as_ref().map_or(0, |p| p.resident_bytes());
    summary.settle_updates = settle_updates;
    summary.converge = converge;
    summary.jumps = jumps;
    let last = source.frame();
    summary.final_triangles = last.triangle_count();
    summary.final_digest = format!("{:016x}", last.digest());
    let report = FlightReport { frames, summary };
    if let Some(out) = &options.stats_out {
        let text = serde_json::to_string_pretty(&report)
            .map_err(|e| Error::InvalidArgument(format!("cannot encode the flight report: {e}")))?;
        crate::sys::atomic_file::write(out, |w| std::io::Write::write_all(w, text.as_bytes()))?;
    }
    Ok(report)
}

/// The full mesh, never simplified: every update keeps the same triangles.
pub struct StaticMesh {
    triangles: Vec<[f32; 3]>,
    bounds: Bounds,
    shown: bool,
}

impl StaticMesh {
    /// All triangles of `mesh`, as f32 world positions (an index out of range is an error).
    pub fn new(mesh: &Mesh) -> Result<StaticMesh> {
        let mut triangles = Vec::with_capacity(3 * mesh.triangles.len());
        for (k, t) in mesh.triangles.iter().enumerate() {
            for &i in t {
                let p = mesh.positions.get(i as usize).ok_or_else(|| {
                    Error::InvalidArgument(format!(
                        "triangle {k}: vertex index {i} out of range ({} vertices)",
                        mesh.positions.len()
                    ))
                })?;
                triangles.push(p.map(|c| c as f32));
            }
        }
        StaticMesh::from_triangles(triangles)
    }

    /// A triangle list (3 positions per triangle); its bounds are those of the positions.
    pub fn from_triangles(triangles: Vec<[f32; 3]>) -> Result<StaticMesh> {
        if triangles.is_empty() || !triangles.len().is_multiple_of(3) {
            return Err(Error::InvalidArgument(format!(
                "a static mesh needs at least one triangle (3 positions each), got {} positions",
                triangles.len()
            )));
        }
        let mut bounds = Bounds { min: [f64::INFINITY; 3], max: [f64::NEG_INFINITY; 3] };
        for p in &triangles {
            for (k, &c) in p.iter().enumerate() {
                bounds.min[k] = bounds.min[k].min(c as f64);
                bounds.max[k] = bounds.max[k].max(c as f64);
            }
        }
        Ok(StaticMesh { triangles, bounds, shown: false })
    }

    /// The triangles, three world positions each.
    pub fn triangles(&self) -> &[[f32; 3]] {
        &self.triangles
    }
}

impl FrameSource for StaticMesh {
    fn update(&mut self, _camera: &Camera, _tolerance_px: f64) -> Result<FrameStats> {
        let changed = !std::mem::replace(&mut self.shown, true);
        Ok(FrameStats {
            update_ms: Some(0.0),
            changed,
            triangles: self.triangles.len() as u64 / 3,
            ..Default::default()
        })
    }

    fn frame(&self) -> Frame<'_> {
        Frame::Triangles(&self.triangles)
    }

    fn bounds(&self) -> Bounds {
        self.bounds
    }

    fn describe(&self) -> String {
        "whole mesh".into()
    }

    fn changes(&self) -> &'static str {
        NO_CHANGES
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn miss_percentage_counts_misses_among_all_requests() {
        let s = FrameStats { splits: 6, collapses: 2, misses: 2, ..Default::default() };
        assert_eq!(s.miss_pct(), 20.0);
        assert_eq!(FrameStats::default().miss_pct(), 0.0);
    }

    #[test]
    fn summaries_are_means_medians_maxima_and_totals() {
        let s = Summary::of([3.0, 1.0, 2.0, 10.0]);
        assert_eq!(s, Summary { mean: 4.0, median: 2.5, max: 10.0, total: 16.0 });
        assert_eq!(Summary::of([5.0]).median, 5.0);
        assert_eq!(Summary::of(std::iter::empty()), Summary::default());
    }

    #[test]
    fn a_static_mesh_reports_its_triangles_and_box_and_changes_once() {
        let mut m = StaticMesh::from_triangles(vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 3.0, -1.0]]).unwrap();
        assert_eq!(m.bounds(), Bounds { min: [0.0, 0.0, -1.0], max: [2.0, 3.0, 0.0] });
        let cam = Camera::new(glam::DVec3::Z * 5.0, glam::DVec3::ZERO, glam::DVec3::Y, 60.0, 8, 8).unwrap();
        let s = m.update(&cam, 1.0).unwrap();
        assert_eq!((s.triangles, s.changed), (1, true));
        assert!(!m.update(&cam, 1.0).unwrap().changed);
        assert!(StaticMesh::from_triangles(vec![[0.0; 3]; 4]).is_err());
        assert!(StaticMesh::from_triangles(Vec::new()).is_err());
    }

    /// The loop over a source without a presenter: one record per camera with the same keys,
    /// the report written where asked.
    #[test]
    fn the_loop_records_every_frame_and_writes_the_report() {
        let mut m = StaticMesh::from_triangles(vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 3.0, -1.0]]).unwrap();
        let cam = Camera::new(glam::DVec3::Z * 5.0, glam::DVec3::ZERO, glam::DVec3::Y, 60.0, 8, 8).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let mut options = FlightOptions::new(8, 8, 1.0);
        options.stats_out = Some(dir.path().join("s.json"));
        let r = fly(&mut m, &[cam, cam, cam], None, &options).unwrap();
        assert_eq!(r.frames.len(), 3);
        assert_eq!(r.summary.triangles.total, 3.0);
        assert_eq!(r.summary.source, "whole mesh");
        let text = std::fs::read_to_string(dir.path().join("s.json")).unwrap();
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["frames"].as_array().unwrap().len(), 3);
        assert!(v["summary"]["update_ms"]["median"].is_number());
        let wrong = Camera::new(glam::DVec3::Z * 5.0, glam::DVec3::ZERO, glam::DVec3::Y, 60.0, 9, 8).unwrap();
        assert!(fly(&mut m, &[cam, wrong], None, &options).is_err());
        assert!(fly(&mut m, &[], None, &options).is_err());
    }
}
