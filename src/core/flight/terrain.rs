//! A terrain as a [`FrameSource`]: refinement feeding the renderer, on one thread (synchronous,
//! for benchmarks and headless output) or on its own thread through a mailbox, so the render
//! thread draws the newest finished strip and never waits for refinement.
//!
//! The mailbox holds one value: a newer one replaces an unread older one (latest wins, never a
//! queue), and the replaced strip goes back to the refinement thread for reuse, so steady flight
//! allocates nothing per frame.

use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Instant;

use super::frame::{Frame, FrameSource, FrameStats};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::format::terrain::TerrainFile;
use crate::mesh::Bounds;
use crate::pager::ReadStats;
use crate::pager::RemoteStats;
use crate::refine::progressive::{Progressive, ProgressiveFrame, ProgressiveOptions};
use crate::refine::{RefineOptions, Refiner, Strip};
use crate::sys::mem;

/// A one-slot mailbox: `put` replaces, `take` never blocks, `wait` blocks until a value arrives or
/// the mailbox is closed.
pub struct Mailbox<T> {
    slot: Mutex<(Option<T>, bool)>,
    ready: Condvar,
}

impl<T> Default for Mailbox<T> {
    fn default() -> Self {
        Mailbox { slot: Mutex::new((None, false)), ready: Condvar::new() }
    }
}

impl<T> Mailbox<T> {
    pub fn new() -> Self {
        Self::default()
    }

    fn lock(&self) -> MutexGuard<'_, (Option<T>, bool)> {
        // A panic while holding this lock cannot leave the slot inconsistent: keep going.
        self.slot.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Puts `value`, returning the unread value it replaced.
    pub fn put(&self, value: T) -> Option<T> {
        let old = self.lock().0.replace(value);
        self.ready.notify_one();
        old
    }

    /// The value, if one is there (never blocks).
    pub fn take(&self) -> Option<T> {
        self.lock().0.take()
    }

    /// Blocks until a value is there (returns it) or the mailbox is closed (returns `None`).
    pub fn wait(&self) -> Option<T> {
        let mut slot = self.lock();
        loop {
            if let Some(v) = slot.0.take() {
                return Some(v);
            }
            if slot.1 {
                return None;
            }
            slot = self.ready.wait(slot).unwrap_or_else(|p| p.into_inner());
        }
    }

    /// Wakes every waiter; later `wait`s return what is left, then `None`.
    pub fn close(&self) {
        self.lock().1 = true;
        self.ready.notify_all();
    }
}

/// A refinement request: the newest camera and options.
#[derive(Clone, Copy, Debug)]
pub struct RefineJob {
    pub camera: Camera,
    pub options: RefineOptions,
    /// Caller's sequence number, returned with the result (lag = current − this).
    pub seq: u64,
}

/// A finished strip and how it was made.
#[derive(Debug)]
pub struct Refined {
    pub strip: Strip,
    pub refine_ms: f64,
    pub job: RefineJob,
    /// Page faults (major, minor) of the process during this refinement.
    pub faults: (u64, u64),
    /// A read that failed during the refinement (the strip stops above the records it missed).
    pub error: Option<crate::Error>,
    /// A remote terrain's frame: what it missed and the round of its data.
    pub progress: Option<ProgressiveFrame>,
}

/// What refines a terrain: the refiner, and for a remote terrain its records as far as they
/// have arrived ([`Progressive`]: refinement that never waits for the network).
pub struct Engine {
    refiner: Refiner,
    progressive: Option<Progressive>,
}

impl Engine {
    /// On `threads` threads; progressive when `terrain` is remote.
    pub fn new(terrain: &Arc<TerrainFile>, threads: usize) -> Result<Engine> {
        let progressive = match terrain.is_remote() {
            true => Some(Progressive::new(terrain.clone(), ProgressiveOptions::from_env()?)?),
            false => None,
        };
        Ok(Engine { refiner: Refiner::new(threads)?, progressive })
    }

    pub fn progressive(&mut self) -> Option<&mut Progressive> {
        self.progressive.as_mut()
    }
}

pub fn refine_once(engine: &mut Engine, terrain: &TerrainFile, job: RefineJob, mut strip: Strip) -> Refined {
    let faults0 = mem::page_faults();
    let t0 = Instant::now();
    let mut progress = None;
    let result = match &mut engine.progressive {
        Some(p) => p.refine(&mut engine.refiner, &job.camera, &job.options, &mut strip).map(|f| {
            progress = Some(f);
        }),
        None => {
            let mut result = engine.refiner.refine_file(terrain, &job.camera, &job.options, &mut strip);
            if job.options.heights && job.options.morph_ratio.is_none() {
                result =
                    result.and_then(|()| crate::heightcache::exact_heights(terrain, &strip.vertices, &mut strip.morph));
            }
            result
        }
    };
    let error = result.err();
    let refine_ms = t0.elapsed().as_secs_f64() * 1e3;
    let faults1 = mem::page_faults();
    Refined { strip, refine_ms, job, faults: (faults1.0 - faults0.0, faults1.1 - faults0.1), error, progress }
}

/// Refinement on its own thread: give it the newest camera with [`Self::request`], collect the
/// newest strip with [`Self::take`].
pub struct RefineThread {
    jobs: Arc<Mailbox<RefineJob>>,
    done: Arc<Mailbox<Refined>>,
    spare: Arc<Mutex<Vec<Strip>>>,
    handle: Option<JoinHandle<()>>,
}

impl RefineThread {
    /// Starts the thread; refinement itself uses `threads` threads.
    pub fn spawn(terrain: Arc<TerrainFile>, threads: usize) -> Result<RefineThread> {
        let mut engine = Engine::new(&terrain, threads)?;
        let jobs = Arc::new(Mailbox::<RefineJob>::new());
        let done = Arc::new(Mailbox::<Refined>::new());
        let spare = Arc::new(Mutex::new(Vec::<Strip>::new()));
        let (j, d, s) = (jobs.clone(), done.clone(), spare.clone());
        let handle = std::thread::Builder::new()
            .name("relief-refine".into())
            .spawn(move || {
                while let Some(job) = j.wait() {
                    let strip = s.lock().unwrap_or_else(|p| p.into_inner()).pop().unwrap_or_default();
                    let refined = refine_once(&mut engine, &terrain, job, strip);
                    if let Some(stale) = d.put(refined) {
                        s.lock().unwrap_or_else(|p| p.into_inner()).push(stale.strip);
                    }
                }
            })
            .map_err(Error::thread("refinement"))?;
        Ok(RefineThread { jobs, done, spare, handle: Some(handle) })
    }

    /// Asks for a strip for `job`, replacing any request not yet started.
    pub fn request(&self, job: RefineJob) {
        self.jobs.put(job);
    }

    /// The newest finished strip, if any (never blocks).
    pub fn take(&self) -> Option<Refined> {
        self.done.take()
    }

    /// Blocks until a strip is finished (first frame, synchronous use).
    pub fn wait(&self) -> Option<Refined> {
        self.done.wait()
    }

    /// Gives a drawn strip back for reuse.
    pub fn recycle(&self, strip: Strip) {
        let mut spare = self.spare.lock().unwrap_or_else(|p| p.into_inner());
        if spare.len() < 4 {
            spare.push(strip);
        }
    }
}

impl Drop for RefineThread {
    fn drop(&mut self) {
        self.jobs.close();
        self.done.close();
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// Where strips come from: the calling thread, or the refinement thread.
/// Where strips are refined.
enum Mode {
    /// On the calling thread, in [`FrameSource::update`].
    Sync(Engine),
    /// On the refinement thread; `update` asks for the newest camera and takes the newest strip
    /// (and asks again for the same camera while the drawn strip is coarser than wanted).
    Thread { thread: RefineThread, last_request: Option<(Camera, RefineOptions)>, taken: bool },
}

/// A terrain flown frame by frame: its refinement as a [`FrameSource`].
pub struct TerrainSource {
    terrain: Arc<TerrainFile>,
    options: RefineOptions,
    mode: Mode,
    /// The strip [`FrameSource::frame`] hands out.
    strip: Strip,
    /// The request the drawn strip was refined for.
    strip_seq: u64,
    seq: u64,
    reads: ReadStats,
    /// A remote terrain's costs at the last update, and whether the drawn strip missed data.
    remote: RemoteStats,
    coarse: bool,
    round_trips: u64,
}

impl TerrainSource {
    /// Refines `terrain` with `options` (each update's tolerance replaces theirs) on `threads`
    /// threads: on the calling thread, or on a thread of its own with `refine_thread`.
    pub fn new(
        terrain: Arc<TerrainFile>,
        options: RefineOptions,
        threads: usize,
        refine_thread: bool,
    ) -> Result<TerrainSource> {
        let mode = if refine_thread {
            Mode::Thread { thread: RefineThread::spawn(terrain.clone(), threads)?, last_request: None, taken: false }
        } else {
            Mode::Sync(Engine::new(&terrain, threads)?)
        };
        let reads = terrain.pager().reads();
        let remote = terrain.pager().network().unwrap_or_default();
        Ok(TerrainSource {
            terrain,
            options,
            mode,
            strip: Strip::new(),
            strip_seq: 0,
            seq: 0,
            reads,
            remote,
            coarse: false,
            round_trips: 0,
        })
    }

    pub fn terrain(&self) -> &Arc<TerrainFile> {
        &self.terrain
    }

    pub fn options(&self) -> RefineOptions {
        self.options
    }

    /// Culling, metric and geomorphing for the next updates.
    pub fn set_options(&mut self, options: RefineOptions) {
        self.options = options;
    }

    /// The strip drawn now.
    pub fn strip(&self) -> &Strip {
        &self.strip
    }

    /// Whether refinement runs on its own thread.
    pub fn threaded(&self) -> bool {
        matches!(self.mode, Mode::Thread { .. })
    }
}

impl FrameSource for TerrainSource {
    fn update(&mut self, camera: &Camera, tolerance_px: f64) -> Result<FrameStats> {
        self.seq += 1;
        let options = RefineOptions { tolerance_px, ..self.options };
        let job = RefineJob { camera: *camera, options, seq: self.seq };
        let refined = match &mut self.mode {
            Mode::Sync(engine) => Some(refine_once(engine, &self.terrain, job, std::mem::take(&mut self.strip))),
            Mode::Thread { thread, last_request, taken } => {
                if *last_request != Some((job.camera, job.options)) || self.coarse {
                    thread.request(job);
                    *last_request = Some((job.camera, job.options));
                }
                // The first frame waits for its strip; later ones draw the newest finished one.
                let got = if *taken { thread.take() } else { thread.wait() };
                if let Some(r) = got {
                    *taken = true;
                    thread.recycle(std::mem::replace(&mut self.strip, Strip::new()));
                    Some(r)
                } else {
                    None
                }
            }
        };
        let reads = self.terrain.pager().reads();
        let (pages_read, bytes_read) = (reads.pages - self.reads.pages, reads.bytes - self.reads.bytes);
        self.reads = reads;
        let remote = self.terrain.pager().network().unwrap_or_default();
        let (requests, net_bytes) = (remote.requests - self.remote.requests, remote.bytes - self.remote.bytes);
        self.remote = remote;
        let Some(r) = refined else {
            return Ok(FrameStats {
                triangles: self.strip.triangle_counts().0,
                strip_len: self.strip.len() as u64,
                pages_read,
                bytes_read,
                lag_frames: self.seq.saturating_sub(self.strip_seq),
                coarse: self.coarse,
                requests,
                net_bytes,
                round_trips: self.round_trips,
                ..FrameStats::default()
            });
        };
        if let Some(e) = r.error {
            return Err(e);
        }
        self.strip = r.strip;
        self.strip_seq = r.job.seq;
        let (coarse, misses) = match &r.progress {
            Some(p) => (!p.complete(), p.missed_records),
            None => (false, 0),
        };
        self.coarse = coarse;
        self.round_trips = r.progress.map_or(0, |p| p.round_trips);
        Ok(FrameStats {
            update_ms: Some(r.refine_ms),
            changed: true,
            triangles: self.strip.triangle_counts().0,
            strip_len: self.strip.len() as u64,
            misses,
            pages_read,
            bytes_read,
            lag_frames: self.seq.saturating_sub(r.job.seq),
            coarse,
            requests,
            net_bytes,
            round_trips: self.round_trips,
            ..FrameStats::default()
        })
    }

    fn settle(&mut self, camera: &Camera, tolerance_px: f64, timeout: std::time::Duration) -> Result<Option<u64>> {
        if !self.terrain.is_remote() {
            return Ok(None);
        }
        let deadline = Instant::now() + timeout;
        let mut updates = 0;
        loop {
            let stats = self.update(camera, tolerance_px)?;
            updates += 1;
            if stats.changed && !stats.coarse {
                return Ok(Some(updates));
            }
            if Instant::now() >= deadline {
                return Err(Error::remote(
                    &self.terrain.path().display().to_string(),
                    format!("the view did not get all its records within {} s", timeout.as_secs_f64()),
                ));
            }
            match &mut self.mode {
                Mode::Sync(engine) => {
                    if let Some(p) = engine.progressive() {
                        p.wait_arrival(std::time::Duration::from_millis(100))?;
                    }
                }
                Mode::Thread { .. } => std::thread::sleep(std::time::Duration::from_millis(5)),
            }
        }
    }

    fn frame(&self) -> Frame<'_> {
        Frame::Strip(&self.strip)
    }

    fn bounds(&self) -> Bounds {
        let h = self.terrain.header();
        let [ex, ey] = h.extent_m();
        Bounds { min: [0.0, 0.0, h.z_min], max: [ex, ey, h.z_max] }
    }

    fn changes(&self) -> &'static str {
        super::frame::STRIP_CHANGES
    }

    fn describe(&self) -> String {
        let name = self.terrain.path().file_name().map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        format!(
            "terrain {name}, {} layout, {} access, refinement {}",
            self.terrain.header().layout.name(),
            self.terrain.pager().access().name(),
            if self.threaded() { "on its own thread" } else { "synchronous" }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mailbox_keeps_only_the_newest_value() {
        let m = Mailbox::new();
        assert_eq!(m.take(), None::<u32>);
        assert_eq!(m.put(1), None);
        assert_eq!(m.put(2), Some(1), "an unread value is handed back when replaced");
        assert_eq!(m.take(), Some(2));
        assert_eq!(m.take(), None);
    }

    #[test]
    fn mailbox_wait_wakes_on_put_and_on_close() {
        let m = Arc::new(Mailbox::new());
        let m2 = m.clone();
        let t = std::thread::spawn(move || (m2.wait(), m2.wait()));
        std::thread::sleep(std::time::Duration::from_millis(20));
        m.put(7u32);
        std::thread::sleep(std::time::Duration::from_millis(20));
        m.close();
        assert_eq!(t.join().unwrap(), (Some(7), None));
    }
}
