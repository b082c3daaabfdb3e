//! Memory figures for benchmarks: peak anonymous resident memory, sampled from `/proc/self/status`
//! (the kernel keeps no high-water mark for it), and the peak total RSS (`VmHWM`), which also
//! counts file pages that are mapped, such as the scratch and output files during conversion.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

fn status_kib(key: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(key))?;
    line[key.len()..].trim().trim_end_matches("kB").trim().parse().ok()
}

/// Current anonymous resident memory in bytes (None where /proc is unavailable).
pub fn rss_anon_bytes() -> Option<u64> {
    status_kib("RssAnon:").map(|k| k * 1024)
}

/// Peak total resident memory in bytes (`VmHWM`).
pub fn peak_rss_bytes() -> Option<u64> {
    status_kib("VmHWM:").map(|k| k * 1024)
}

/// Current total resident memory in bytes (`VmRSS`: anonymous plus mapped file pages).
pub fn rss_bytes() -> Option<u64> {
    status_kib("VmRSS:").map(|k| k * 1024)
}

/// Page faults of this process so far: `(major, minor)` from `getrusage`. Major faults read
/// from disk; minor ones map a page already in memory (including readahead).
pub fn page_faults() -> (u64, u64) {
    #[cfg(not(feature = "native"))]
    return (0, 0);
    #[cfg(feature = "native")]
    {
        // SAFETY: getrusage writes one `rusage` into the zeroed value we pass and reads nothing else.
        let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
        // SAFETY: as above: one `rusage`, ours, written.
        if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
            return (0, 0);
        }
        (usage.ru_majflt.max(0) as u64, usage.ru_minflt.max(0) as u64)
    }
}

/// Samples `RssAnon` every few milliseconds on a background thread until finished.
pub struct AnonSampler {
    stop: Arc<AtomicBool>,
    peak: Arc<AtomicU64>,
    thread: Option<JoinHandle<()>>,
}

impl AnonSampler {
    pub fn start() -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let peak = Arc::new(AtomicU64::new(rss_anon_bytes().unwrap_or(0)));
        let (s, p) = (stop.clone(), peak.clone());
        let thread = std::thread::Builder::new()
            .name("rss-sampler".into())
            .spawn(move || {
                while !s.load(Ordering::Relaxed) {
                    if let Some(v) = rss_anon_bytes() {
                        p.fetch_max(v, Ordering::Relaxed);
                    }
                    std::thread::sleep(Duration::from_millis(5));
                }
            })
            .ok();
        AnonSampler { stop, peak, thread }
    }

    /// Stops sampling and returns the peak anonymous RSS in bytes.
    pub fn finish(mut self) -> u64 {
        self.stop_thread();
        if let Some(v) = rss_anon_bytes() {
            self.peak.fetch_max(v, Ordering::Relaxed);
        }
        self.peak.load(Ordering::Relaxed)
    }

    fn stop_thread(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for AnonSampler {
    fn drop(&mut self) {
        self.stop_thread();
    }
}
