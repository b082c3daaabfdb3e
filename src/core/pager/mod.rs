//! The pager shared by every backend (DESIGN.md, "The pager"): a read-only file seen as
//! fixed-size pages.
//!
//! - **Mapped** ([`crate::format::terrain::TerrainFile`]'s memmap2 view): the OS pages the file in; the
//!   terrain paper's choice. [`drop_from_page_cache`] and `TerrainFile::advise_random` set up cold,
//!   readahead-free runs whose faults [`crate::sys::mem::page_faults`] counts (`getrusage`).
//! - **Instrumented** ([`PagedRecords`] with a [`PageObserver`]): every record read reports its
//!   page to an observer, such as [`LruCache`], a deterministic, machine-independent model of a
//!   page cache of a given size. With [`NoTrace`] the observer compiles to nothing, so the plain
//!   path costs what reading the slice costs.
//! - The **pooled** mode (explicit place holders, second chance, an I/O thread) is
//!   [`crate::pager::pool`], generic over what a block is; the meta-node backend uses it.

pub mod pool;
pub mod source;

use std::collections::{HashMap, HashSet};
use std::path::Path;
use std::sync::Mutex;

use crate::error::{Error, Result};
use crate::format::terrain::Record;
use crate::refine::RecordSource;

/// Page size and memory budget, validated: the page size is a power of two, the budget holds at
/// least one page.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PageGeometry {
    pub page_bytes: u64,
    shift: u32,
}

impl PageGeometry {
    pub fn new(page_bytes: u64) -> Result<PageGeometry> {
        if page_bytes == 0 || !page_bytes.is_power_of_two() {
            return Err(Error::InvalidArgument(format!("page size must be a power of two, got {page_bytes} bytes")));
        }
        Ok(PageGeometry { page_bytes, shift: page_bytes.trailing_zeros() })
    }

    /// The page holding byte `offset`.
    #[inline(always)]
    pub fn page_of(&self, offset: u64) -> u64 {
        offset >> self.shift
    }

    /// Pages needed to hold `bytes` (rounded up).
    pub fn pages_for(&self, bytes: u64) -> u64 {
        bytes.div_ceil(self.page_bytes)
    }
}

/// Counts of a cache model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct CacheStats {
    pub hits: u64,
    /// Misses: page faults.
    pub misses: u64,
    pub evictions: u64,
    /// Different pages ever touched.
    pub distinct_pages: u64,
}

const NIL: u32 = u32::MAX;

/// A least-recently-used page cache of a fixed number of pages: a hash map from page to slot and
/// an intrusive doubly-linked list over the slots, so a touch is O(1).
pub struct LruCache {
    capacity: usize,
    slots: HashMap<u64, u32>,
    page: Vec<u64>,
    prev: Vec<u32>,
    next: Vec<u32>,
    /// Most and least recently used slots.
    head: u32,
    tail: u32,
    seen: HashSet<u64>,
    stats: CacheStats,
}

impl LruCache {
    /// A cache of `memory_bytes / page_bytes` pages (at least one page, else an error).
    pub fn new(memory_bytes: u64, geometry: PageGeometry) -> Result<LruCache> {
        let pages = memory_bytes / geometry.page_bytes;
        if pages == 0 {
            return Err(Error::InvalidArgument(format!(
                "memory budget of {memory_bytes} bytes is smaller than one {}-byte page",
                geometry.page_bytes
            )));
        }
        Ok(Self::with_pages(pages.min(u32::MAX as u64 - 1) as usize))
    }

    /// A cache of `pages` pages (≥ 1).
    pub fn with_pages(pages: usize) -> LruCache {
        let capacity = pages.max(1);
        LruCache {
            capacity,
            slots: HashMap::new(),
            page: Vec::new(),
            prev: Vec::new(),
            next: Vec::new(),
            head: NIL,
            tail: NIL,
            seen: HashSet::new(),
            stats: CacheStats::default(),
        }
    }

    pub fn capacity_pages(&self) -> usize {
        self.capacity
    }

    pub fn stats(&self) -> CacheStats {
        self.stats
    }

    /// Whether `page` is resident (does not count as a touch).
    pub fn contains(&self, page: u64) -> bool {
        self.slots.contains_key(&page)
    }

    fn unlink(&mut self, s: u32) {
        let (p, n) = (self.prev[s as usize], self.next[s as usize]);
        if p != NIL {
            self.next[p as usize] = n;
        } else {
            self.head = n;
        }
        if n != NIL {
            self.prev[n as usize] = p;
        } else {
            self.tail = p;
        }
    }

    fn push_front(&mut self, s: u32) {
        self.prev[s as usize] = NIL;
        self.next[s as usize] = self.head;
        if self.head != NIL {
            self.prev[self.head as usize] = s;
        }
        self.head = s;
        if self.tail == NIL {
            self.tail = s;
        }
    }

    /// References `page`: a hit moves it to the front; a miss (a fault) loads it, evicting the
    /// least recently used page when full. Returns whether it was a hit.
    pub fn touch(&mut self, page: u64) -> bool {
        if let Some(&s) = self.slots.get(&page) {
            self.stats.hits += 1;
            if self.head != s {
                self.unlink(s);
                self.push_front(s);
            }
            return true;
        }
        self.stats.misses += 1;
        if self.seen.insert(page) {
            self.stats.distinct_pages += 1;
        }
        let s = if self.page.len() < self.capacity {
            self.page.push(page);
            self.prev.push(NIL);
            self.next.push(NIL);
            (self.page.len() - 1) as u32
        } else {
            let s = self.tail;
            self.unlink(s);
            self.slots.remove(&self.page[s as usize]);
            self.stats.evictions += 1;
            self.page[s as usize] = page;
            s
        };
        self.slots.insert(page, s);
        self.push_front(s);
        false
    }
}

/// Receives the page of every record read. `&self` because record sources are shared (`Sync`).
pub trait PageObserver: Sync {
    /// Whether anything is observed; `false` lets the compiler drop the page arithmetic.
    const ACTIVE: bool;
    fn touch(&self, page: u64);
}

/// Observes nothing: the plain, zero-cost path.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoTrace;

impl PageObserver for NoTrace {
    const ACTIVE: bool = false;
    #[inline(always)]
    fn touch(&self, _page: u64) {}
}

/// Feeds an [`LruCache`] and records which record slots were read (for the lower bound).
/// Single-threaded refinement is expected; the lock is uncontended.
pub struct LruTrace {
    state: Mutex<TraceState>,
}

struct TraceState {
    cache: LruCache,
    /// The last page touched: repeated reads of one page count once (they cannot fault).
    last_page: u64,
}

impl LruTrace {
    pub fn new(cache: LruCache) -> LruTrace {
        LruTrace { state: Mutex::new(TraceState { cache, last_page: u64::MAX }) }
    }

    pub fn stats(&self) -> CacheStats {
        self.state.lock().unwrap_or_else(|p| p.into_inner()).cache.stats()
    }
}

impl PageObserver for LruTrace {
    const ACTIVE: bool = true;
    fn touch(&self, page: u64) {
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        if s.last_page != page {
            s.last_page = page;
            s.cache.touch(page);
        }
    }
}

/// A bit per record slot: which records a run read.
pub struct RecordSet {
    bits: Vec<std::sync::atomic::AtomicU64>,
}

impl RecordSet {
    pub fn new(records: usize) -> RecordSet {
        RecordSet { bits: (0..records.div_ceil(64)).map(|_| std::sync::atomic::AtomicU64::new(0)).collect() }
    }

    #[inline]
    pub fn insert(&self, index: u64) {
        let w = &self.bits[(index / 64) as usize];
        w.fetch_or(1 << (index % 64), std::sync::atomic::Ordering::Relaxed);
    }

    pub fn len(&self) -> u64 {
        self.bits.iter().map(|w| w.load(std::sync::atomic::Ordering::Relaxed).count_ones() as u64).sum()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// The records of a terrain file's payload read through an observer: record `i` lives at byte
/// `payload_offset + i · record_bytes` of the file.
pub struct PagedRecords<'a, O: PageObserver> {
    records: &'a [Record],
    payload_offset: u64,
    geometry: PageGeometry,
    observer: &'a O,
    read: Option<&'a RecordSet>,
}

impl<'a, O: PageObserver> PagedRecords<'a, O> {
    pub fn new(
        records: &'a [Record],
        payload_offset: u64,
        geometry: PageGeometry,
        observer: &'a O,
        read: Option<&'a RecordSet>,
    ) -> Self {
        PagedRecords { records, payload_offset, geometry, observer, read }
    }
}

impl<O: PageObserver> RecordSource for PagedRecords<'_, O> {
    #[inline(always)]
    fn record(&self, index: u64) -> Record {
        if O::ACTIVE {
            let offset = self.payload_offset + index * std::mem::size_of::<Record>() as u64;
            self.observer.touch(self.geometry.page_of(offset));
            if let Some(r) = self.read {
                r.insert(index);
            }
        }
        self.records[index as usize]
    }
}

/// Evicts `path` from the OS page cache (`posix_fadvise(DONTNEED)`), so the next reads fault.
/// Pages still mapped by a live mapping stay: drop the mapping first.
pub fn drop_from_page_cache(path: &Path) -> Result<()> {
    use std::os::unix::io::AsRawFd;
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    // SAFETY: plain system call on a file descriptor we own for the duration of the call.
    let rc = unsafe { libc::posix_fadvise(file.as_raw_fd(), 0, 0, libc::POSIX_FADV_DONTNEED) };
    if rc != 0 {
        return Err(Error::io(path, std::io::Error::from_raw_os_error(rc)));
    }
    Ok(())
}

/// A cgroup v1 memory limit on this process while the value lives (DESIGN.md: OS counts "under
/// a cgroup memory limit where the machine allows one"). Charges made before the move stay where
/// they were (v1 does not move them by default), so the limit applies to what is allocated and
/// paged in afterwards: chiefly the page cache of the file a cold run maps.
pub struct MemoryCap {
    dir: std::path::PathBuf,
    parent: std::path::PathBuf,
}

impl MemoryCap {
    /// Creates a child of this process's memory cgroup limited to `limit_bytes` and moves the
    /// process into it; says why where the machine has no writable cgroup v1 memory controller.
    pub fn apply(limit_bytes: u64) -> Result<MemoryCap> {
        let unsupported = |why: String| Error::InvalidArgument(format!("cannot set a memory cap: {why}"));
        let cgroups =
            std::fs::read_to_string("/proc/self/cgroup").map_err(|e| unsupported(format!("/proc/self/cgroup: {e}")))?;
        let rel = cgroups
            .lines()
            .find_map(|l| {
                let mut f = l.splitn(3, ':');
                let (_, controllers, path) = (f.next()?, f.next()?, f.next()?);
                controllers.split(',').any(|c| c == "memory").then(|| path.to_string())
            })
            .ok_or_else(|| unsupported("no cgroup v1 memory controller for this process".into()))?;
        let parent = Path::new("/sys/fs/cgroup/memory").join(rel.trim_start_matches('/'));
        let dir = parent.join(format!("relief.{}", std::process::id()));
        std::fs::create_dir(&dir).map_err(|e| unsupported(format!("{}: {e}", dir.display())))?;
        let cap = MemoryCap { dir, parent };
        std::fs::write(cap.dir.join("memory.limit_in_bytes"), limit_bytes.to_string())
            .map_err(|e| unsupported(format!("{}: {e}", cap.dir.join("memory.limit_in_bytes").display())))?;
        std::fs::write(cap.dir.join("cgroup.procs"), std::process::id().to_string())
            .map_err(|e| unsupported(format!("{}: {e}", cap.dir.join("cgroup.procs").display())))?;
        Ok(cap)
    }
}

impl Drop for MemoryCap {
    fn drop(&mut self) {
        // Back to the parent group, then remove ours (empty once we left).
        let _ = std::fs::write(self.parent.join("cgroup.procs"), std::process::id().to_string());
        let _ = std::fs::remove_dir(&self.dir);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn geometry_rejects_pages_that_are_not_powers_of_two() {
        assert!(PageGeometry::new(4096).is_ok());
        for bad in [0, 3, 4095, 6000] {
            let e = PageGeometry::new(bad).unwrap_err().to_string();
            assert!(e.contains("power of two"), "{e}");
        }
        let g = PageGeometry::new(4096).unwrap();
        assert_eq!((g.page_of(4095), g.page_of(4096), g.pages_for(4097)), (0, 1, 2));
    }

    #[test]
    fn budget_must_hold_a_page() {
        let g = PageGeometry::new(4096).unwrap();
        let e = LruCache::new(4095, g).err().unwrap().to_string();
        assert!(e.contains("smaller than one 4096-byte page"), "{e}");
        assert_eq!(LruCache::new(3 * 4096 + 5, g).unwrap().capacity_pages(), 3);
    }

    /// Worked by hand: capacity 3, references 1 2 3 1 4 2 5 1 2 3.
    ///  1 miss [1]; 2 miss [2 1]; 3 miss [3 2 1]; 1 hit [1 3 2]; 4 miss, evict 2 [4 1 3];
    ///  2 miss, evict 3 [2 4 1]; 5 miss, evict 1 [5 2 4]; 1 miss, evict 4 [1 5 2];
    ///  2 hit [2 1 5]; 3 miss, evict 5 [3 2 1].
    #[test]
    fn lru_matches_a_hand_worked_trace() {
        let mut c = LruCache::with_pages(3);
        let hits: Vec<bool> = [1, 2, 3, 1, 4, 2, 5, 1, 2, 3].iter().map(|&p| c.touch(p)).collect();
        assert_eq!(hits, [false, false, false, true, false, false, false, false, true, false]);
        assert_eq!(c.stats(), CacheStats { hits: 2, misses: 8, evictions: 5, distinct_pages: 5 });
        for (p, resident) in [(3, true), (2, true), (1, true), (5, false), (4, false)] {
            assert_eq!(c.contains(p), resident, "page {p}");
        }
    }

    #[test]
    fn one_page_cache_faults_on_every_change() {
        let mut c = LruCache::with_pages(1);
        let trace = [7, 7, 8, 7, 7, 9];
        let misses = trace.iter().filter(|&&p| !c.touch(p)).count();
        assert_eq!(misses, 4);
        assert_eq!(c.stats().evictions, 3);
    }

    #[test]
    fn lru_agrees_with_a_naive_model_on_random_traces() {
        // Naive LRU: a vector ordered by recency.
        let mut seed = 0x9e3779b97f4a7c15u64;
        for capacity in [1usize, 2, 5, 17] {
            let mut c = LruCache::with_pages(capacity);
            let mut naive: Vec<u64> = Vec::new();
            for _ in 0..5000 {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                let p = seed % 40;
                let hit = c.touch(p);
                let pos = naive.iter().position(|&q| q == p);
                assert_eq!(hit, pos.is_some());
                if let Some(i) = pos {
                    naive.remove(i);
                } else if naive.len() == capacity {
                    naive.pop();
                }
                naive.insert(0, p);
            }
            for p in 0..40 {
                assert_eq!(c.contains(p), naive.contains(&p));
            }
        }
    }
}
