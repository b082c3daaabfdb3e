//! What the experiments observe: every byte range a pager takes from its file (a vertex record, a
//! meta-node block, a disk page) is reported to the [`PageObserver`] attached to it
//! ([`super::Pager::observe`]), whichever way it reads. An observer turns that into page faults
//! per frame: [`LruTrace`] by a deterministic model of a page cache, [`OsFaults`] from the
//! operating system's own counters. Without an observer nothing is reported; the terrain's hot
//! path is generic over the observer, and [`NoTrace`] compiles to nothing there.

use std::collections::HashSet;
use std::sync::Mutex;

use serde::Serialize;

use super::lru::{CacheStats, LruCache};
use super::PageGeometry;

/// What an observer counted over a stretch of reads (one frame, or a whole flight).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Faults {
    /// Pages brought in from storage: the model's misses, or the process's major faults.
    pub faults: u64,
    /// Bytes brought in from storage: the model's misses × the page size, or what the kernel
    /// counted (`/proc/self/io`).
    pub bytes_read: u64,
}

impl std::ops::AddAssign for Faults {
    fn add_assign(&mut self, o: Faults) {
        self.faults += o.faults;
        self.bytes_read += o.bytes_read;
    }
}

/// Receives every read from a file. `&self` because readers are shared between threads; the
/// pool's I/O thread reports its loads too.
pub trait PageObserver: Send + Sync {
    /// `len` bytes at byte `offset` of the file were read.
    #[inline(always)]
    fn read(&self, _offset: u64, _len: u64) {}
    /// What was counted since the previous call.
    fn take(&self) -> Faults {
        Faults::default()
    }
}

/// Observes nothing: with it the generic hot paths compile to the plain reads.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoTrace;

impl PageObserver for NoTrace {}

/// How the distinct bytes read are tracked, for the lower bound (the bytes read, packed
/// perfectly into pages).
#[derive(Clone, Copy, Debug)]
pub struct Granules {
    /// Byte offset of granule 0.
    pub first: u64,
    /// Bytes per granule (a record, a page); every read starts on a granule.
    pub bytes: u64,
    pub count: u64,
}

enum Distinct {
    /// A bit per granule.
    Bits { granules: Granules, bits: Vec<u64> },
    /// Offsets of the reads (reads of one offset have one length: a block, a page).
    Offsets(HashSet<u64>),
}

struct TraceState {
    cache: LruCache,
    /// The last page touched: repeated reads of one page count once (they cannot fault).
    last_page: u64,
    distinct: Distinct,
    distinct_bytes: u64,
    misses_taken: u64,
}

/// Feeds the pages of every read to an [`LruCache`] of a given size: a deterministic,
/// machine-independent model of the page cache. Also keeps the distinct bytes read. Meant for one
/// reading thread at a time (the lock is uncontended).
pub struct LruTrace {
    geometry: PageGeometry,
    state: Mutex<TraceState>,
}

impl LruTrace {
    /// A model of `cache`, tracking distinct reads by offset.
    pub fn new(cache: LruCache, geometry: PageGeometry) -> LruTrace {
        LruTrace::with_distinct(cache, geometry, Distinct::Offsets(HashSet::new()))
    }

    /// A model of `cache`, tracking distinct reads as granules (cheaper when reads are small and
    /// many, such as vertex records).
    pub fn with_granules(cache: LruCache, geometry: PageGeometry, granules: Granules) -> LruTrace {
        let bits = vec![0u64; granules.count.div_ceil(64) as usize];
        LruTrace::with_distinct(cache, geometry, Distinct::Bits { granules, bits })
    }

    fn with_distinct(cache: LruCache, geometry: PageGeometry, distinct: Distinct) -> LruTrace {
        LruTrace {
            geometry,
            state: Mutex::new(TraceState { cache, last_page: u64::MAX, distinct, distinct_bytes: 0, misses_taken: 0 }),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, TraceState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The model's counts so far.
    pub fn stats(&self) -> CacheStats {
        self.lock().cache.stats()
    }

    /// Distinct bytes read so far.
    pub fn distinct_bytes(&self) -> u64 {
        self.lock().distinct_bytes
    }

    /// The fewest pages the distinct bytes read could have come from.
    pub fn lower_bound_pages(&self) -> u64 {
        self.geometry.pages_for(self.distinct_bytes())
    }

    pub fn geometry(&self) -> PageGeometry {
        self.geometry
    }
}

impl PageObserver for LruTrace {
    fn read(&self, offset: u64, len: u64) {
        let mut s = self.lock();
        let first = self.geometry.page_of(offset);
        let last = self.geometry.page_of(offset + len.max(1) - 1);
        for page in first..=last {
            if s.last_page != page {
                s.last_page = page;
                s.cache.touch(page);
            }
        }
        let new = match &mut s.distinct {
            Distinct::Bits { granules, bits } => {
                let g = (offset - granules.first) / granules.bytes;
                let (w, b) = ((g / 64) as usize, 1u64 << (g % 64));
                match bits.get_mut(w) {
                    Some(word) if *word & b == 0 => {
                        *word |= b;
                        true
                    }
                    _ => false,
                }
            }
            Distinct::Offsets(set) => set.insert(offset),
        };
        if new {
            s.distinct_bytes += len;
        }
    }

    fn take(&self) -> Faults {
        let mut s = self.lock();
        let misses = s.cache.stats().misses;
        let faults = misses - s.misses_taken;
        s.misses_taken = misses;
        Faults { faults, bytes_read: faults * self.geometry.page_bytes }
    }
}

/// The operating system's counts for this process: major page faults (`getrusage`) and the bytes
/// read from storage (`/proc/self/io`), both over all threads. Nothing is traced per read; run
/// the reads cold (the file evicted from the page cache, readahead off) for them to mean faults.
pub struct OsFaults {
    last: Mutex<(u64, u64)>,
}

impl OsFaults {
    /// Starts counting now.
    pub fn start() -> OsFaults {
        OsFaults { last: Mutex::new(Self::now()) }
    }

    fn now() -> (u64, u64) {
        (crate::sys::mem::page_faults().0, super::os::storage_read_bytes().unwrap_or(0))
    }
}

impl PageObserver for OsFaults {
    fn take(&self) -> Faults {
        let now = Self::now();
        let mut last = self.last.lock().unwrap_or_else(|p| p.into_inner());
        let f = Faults { faults: now.0.saturating_sub(last.0), bytes_read: now.1.saturating_sub(last.1) };
        *last = now;
        f
    }
}

/// A shared reference observes as what it points to (so one observer can serve several readers).
impl<O: PageObserver + ?Sized> PageObserver for &O {
    #[inline(always)]
    fn read(&self, offset: u64, len: u64) {
        (**self).read(offset, len)
    }
    fn take(&self) -> Faults {
        (**self).take()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geometry() -> PageGeometry {
        PageGeometry::new(4096).unwrap()
    }

    #[test]
    fn the_model_counts_each_page_of_a_read_and_repeated_pages_once() {
        let t = LruTrace::new(LruCache::with_pages(2), geometry());
        t.read(0, 12);
        t.read(12, 12); // same page: not even a touch
        t.read(4090, 12); // straddles pages 0 and 1: one new page
        assert_eq!(t.take(), Faults { faults: 2, bytes_read: 8192 });
        t.read(3 * 4096, 4096); // page 3 evicts page 0
        t.read(0, 4); // page 0 again: a fault
        assert_eq!(t.take().faults, 2);
        assert_eq!(t.stats().distinct_pages, 3);
        assert_eq!(t.distinct_bytes(), 12 + 12 + 12 + 4096);
        assert_eq!(t.lower_bound_pages(), 2);
    }

    #[test]
    fn granules_and_offsets_agree_on_the_distinct_bytes() {
        let g = Granules { first: 4096, bytes: 12, count: 1000 };
        let a = LruTrace::with_granules(LruCache::with_pages(4), geometry(), g);
        let b = LruTrace::new(LruCache::with_pages(4), geometry());
        for k in [5u64, 7, 5, 999, 0, 7, 640] {
            a.read(4096 + 12 * k, 12);
            b.read(4096 + 12 * k, 12);
        }
        assert_eq!((a.distinct_bytes(), b.distinct_bytes()), (60, 60));
        assert_eq!(a.stats(), b.stats());
    }

    #[test]
    fn nothing_is_counted_without_tracing() {
        NoTrace.read(0, 4096);
        assert_eq!(NoTrace.take(), Faults::default());
    }
}
