//! The navigator as a [`FrameSource`]: what `relief mesh fly` draws.

use std::time::Instant;

use super::navigate::{MetaStore, Navigator, PagedStore};
use crate::camera::Camera;
use crate::error::Result;
use crate::flight::frame::{ConvergeEnd, Convergence, Frame, FrameSource, FrameStats, STALL_UPDATES};
use crate::format::metanode::MetaNodeFile;
use crate::mesh::Bounds;
use crate::pager::device::DeviceStats;
use crate::pager::{Access, ReadStats};

/// A [`Navigator`] over a meta-node file's pager, flown frame by frame.
pub struct NavSource<'a> {
    pub navigator: Navigator<PagedStore<'a>>,
    file: &'a MetaNodeFile,
    reads: ReadStats,
    device: DeviceStats,
    second_chance_hits: u64,
    shown: bool,
}

impl<'a> NavSource<'a> {
    pub fn new(navigator: Navigator<PagedStore<'a>>) -> NavSource<'a> {
        let file = navigator.store().file();
        let second_chance_hits = navigator.store().second_chance_hits();
        let (reads, device) = (file.pager().reads(), file.pager().device_or_zero());
        NavSource { reads, device, file, navigator, second_chance_hits, shown: false }
    }
}

impl FrameSource for NavSource<'_> {
    fn update(&mut self, camera: &Camera, tolerance_px: f64) -> Result<FrameStats> {
        let started = Instant::now();
        let s = self.navigator.update(camera, tolerance_px)?;
        let update_ms = started.elapsed().as_secs_f64() * 1e3;
        let (reads, device) = (self.file.pager().reads(), self.file.pager().device_or_zero());
        let served = device.since(self.device);
        let second = self.navigator.store().second_chance_hits();
        let stats = FrameStats {
            update_ms: Some(update_ms),
            changed: s.splits + s.collapses > 0 || !self.shown,
            triangles: s.triangles,
            splits: s.splits,
            collapses: s.collapses,
            misses: s.misses,
            second_chance_hits: second - self.second_chance_hits,
            pages_read: reads.pages - self.reads.pages,
            bytes_read: reads.bytes - self.reads.bytes,
            device_requests: served.requests,
            device_ms: served.device_s * 1e3,
            ..FrameStats::default()
        };
        self.shown = true;
        self.reads = reads;
        self.device = device;
        self.second_chance_hits = second;
        Ok(stats)
    }

    /// Updates, letting the buffer pool finish its loads between updates (waiting for them, up
    /// to the deadline), until an update has no misses and changes nothing (map and read access:
    /// the second update), the time runs out, or [`STALL_UPDATES`] updates in a row neither draw
    /// more triangles nor miss fewer blocks than the best before them. Short of complete, the
    /// last update's misses and changes say what was left.
    fn converge(&mut self, camera: &Camera, tolerance_px: f64, timeout: std::time::Duration) -> Result<Convergence> {
        let deadline = Instant::now() + timeout;
        let mut c = Convergence::default();
        let (mut most_triangles, mut fewest_misses, mut best_at) = (0, u64::MAX, 0);
        loop {
            let s = self.update(camera, tolerance_px)?;
            c = c.with(&s);
            c.updates += 1;
            (c.misses_left, c.changes_left) = (s.misses, s.splits + s.collapses);
            if s.misses == 0 && s.splits + s.collapses == 0 && c.updates > 1 {
                return Ok(c.ended(ConvergeEnd::Complete));
            }
            if s.triangles > most_triangles || s.misses < fewest_misses {
                most_triangles = most_triangles.max(s.triangles);
                fewest_misses = fewest_misses.min(s.misses);
                best_at = c.updates;
            }
            if c.updates - best_at >= STALL_UPDATES {
                return Ok(c.ended(ConvergeEnd::Stalled));
            }
            if Instant::now() >= deadline {
                return Ok(c.ended(ConvergeEnd::Timeout));
            }
            if let Some(pool) = self.file.pager().pool() {
                // The loads the misses asked for, within the time left (an update before them
                // would miss again).
                if !pool.drain_until(deadline)? {
                    return Ok(c.ended(ConvergeEnd::Timeout));
                }
            }
        }
    }

    fn converges_by_default(&self) -> bool {
        true
    }

    fn frame(&self) -> Frame<'_> {
        Frame::Triangles(self.navigator.triangles())
    }

    fn bounds(&self) -> Bounds {
        self.file.header().bounds
    }

    fn describe(&self) -> String {
        let pager = self.file.pager();
        let what: String = match (pager.access(), pager.pool()) {
            (Access::Pool { .. }, Some(pool)) => format!(
                "meta-node trees, pool access (ext), {} holders of {} B",
                pool.holders(),
                self.file.header().holder_bytes
            ),
            (Access::Map, _) => "meta-node trees, map access (virt)".into(),
            (access, _) => format!("meta-node trees, {} access", access.name()),
        };
        what + &crate::pager::device::describe(pager.device_spec())
    }
}
