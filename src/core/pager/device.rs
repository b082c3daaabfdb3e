//! An emulated storage device under a file (ARCHITECTURE.md, "Device emulation"): what a device
//! charges ([`DeviceSpec`]) and what it served ([`DeviceStats`]). The device itself, a FUSE file
//! system, is in [`super::fuse`] (the `device` feature): the file is served through a file system
//! of relief's own whose every read request waits as a device of the given latency, queue depth
//! and throughput would before it is answered.
//!
//! Why FUSE: the kernel then issues the requests exactly as for a real disk, for every access
//! (page faults of a map, `pread`s of the read access and the pool), through its own page cache,
//! readahead and memory limits; only the time a request takes is ours. So one mechanism charges
//! one delay per request the kernel actually sends, and major fault counts stay the OS's own.
//!
//! A request's device time is `latency + bytes / throughput`, and never less than the read of the
//! backing file it needs (which is kept warm in the OS page cache, so that it costs microseconds):
//! the emulation cannot be faster than the storage it runs on, and says so in its figures
//! ([`DeviceStats::slow_backing`]). At most `queue_depth` requests are served at once (one event
//! loop thread per slot); the others wait in the kernel's queue, as on a device.

#[cfg(feature = "native")]
use std::fs::File;
#[cfg(feature = "native")]
use std::os::unix::fs::FileExt;
use std::path::Path;
use std::time::Duration;

use serde::Serialize;

use crate::error::{Error, IoContext, Result};

/// The most requests served at once that relief emulates (one thread each).
pub const MAX_QUEUE_DEPTH: u32 = 64;

/// What the emulated device charges a request.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct DeviceSpec {
    /// Time from a request to its first byte, milliseconds.
    pub latency_ms: f64,
    /// Requests served at once (a 7200 rpm disk: 1; an SSD or an object store: many).
    pub queue_depth: u32,
    /// Transfer rate in bytes per second, if capped (None: the latency alone).
    pub bytes_per_s: Option<f64>,
}

impl DeviceSpec {
    /// A device of `latency_ms` per request, queue depth `queue_depth`, optionally capped at
    /// `mb_per_s` (10⁶ bytes a second); refuses values that are not finite and positive.
    pub fn new(latency_ms: f64, queue_depth: u32, mb_per_s: Option<f64>) -> Result<DeviceSpec> {
        if !(0.0..=60_000.0).contains(&latency_ms) {
            return Err(Error::out_of_range("device latency", "between 0 and 60000 ms", latency_ms));
        }
        if queue_depth == 0 || queue_depth > MAX_QUEUE_DEPTH {
            return Err(Error::out_of_range("device queue depth", format!("1 to {MAX_QUEUE_DEPTH}"), queue_depth));
        }
        if let Some(r) = mb_per_s {
            if !(r.is_finite() && r > 0.0) {
                return Err(Error::out_of_range("device throughput", "positive MB/s", r));
            }
        }
        Ok(DeviceSpec { latency_ms, queue_depth, bytes_per_s: mb_per_s.map(|r| r * 1e6) })
    }

    /// The time a request for `bytes` takes on this device.
    pub fn service_time(&self, bytes: u64) -> Duration {
        let s = self.latency_ms * 1e-3 + self.bytes_per_s.map_or(0.0, |r| bytes as f64 / r);
        Duration::from_secs_f64(s)
    }
}

/// "2 ms a request, queue depth 1[, 100 MB/s]".
impl std::fmt::Display for DeviceSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ms a request, queue depth {}", self.latency_ms, self.queue_depth)?;
        match self.bytes_per_s {
            Some(r) => write!(f, ", {} MB/s", r / 1e6),
            None => Ok(()),
        }
    }
}

/// ", on an emulated device (…)" for a source's description, or nothing without one.
pub fn describe(spec: Option<DeviceSpec>) -> String {
    spec.map_or(String::new(), |s| format!(", on an emulated device ({s})"))
}

/// What a device has served so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct DeviceStats {
    /// Read requests the kernel sent.
    pub requests: u64,
    /// Bytes they asked for.
    pub bytes: u64,
    /// Sum of the requests' service times, seconds (overlapping ones each counted).
    pub device_s: f64,
    /// Requests whose backing read alone took longer than the emulated service time (the
    /// emulation was slower than asked for by that much).
    pub slow_backing: u64,
}

impl DeviceStats {
    /// What was served since `earlier` (a snapshot of the same device).
    pub fn since(&self, earlier: DeviceStats) -> DeviceStats {
        DeviceStats {
            requests: self.requests - earlier.requests,
            bytes: self.bytes - earlier.bytes,
            device_s: self.device_s - earlier.device_s,
            slow_backing: self.slow_backing - earlier.slow_backing,
        }
    }
}

#[cfg(feature = "native")]
/// Reads the file at `path` once into the OS page cache (as a device's mount does first): called before
/// a memory cap is applied, so that the device's backing bytes are not charged to it.
pub fn warm_path(path: &Path) -> Result<()> {
    let file = File::open(path).at(path)?;
    let len = file.metadata().at(path)?.len();
    warm(&file, len).at(path)
}

#[cfg(feature = "native")]
/// Reads a file once, sequentially, into the OS page cache.
pub(super) fn warm(file: &File, len: u64) -> std::io::Result<()> {
    let mut buf = vec![0u8; 1 << 20];
    let mut at = 0;
    while at < len {
        let n = file.read_at(&mut buf, at)?;
        if n == 0 {
            break;
        }
        at += n as u64;
    }
    Ok(())
}
