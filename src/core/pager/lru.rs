//! A deterministic model of a page cache: least recently used replacement over a fixed number of
//! pages. Its misses are the page faults the experiments report, identical on every machine.

use std::collections::{HashMap, HashSet};

use crate::error::{Error, Result};
use crate::pager::PageGeometry;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pager::PageGeometry;

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
