//! Where refinement reads vertex records from, by layout index ([`RecordSource`]): a terrain
//! file's pager, whatever its access. A mapped file is read in place (the plain `[Record]` slice,
//! the fast path, or [`MappedRecords`], which reports every record read to an observer, as the
//! pager reports every block it takes); any other access goes block by block through the pager
//! ([`PagerRecords`]: the pool, or positioned reads), whose observer sees the blocks read.

use std::sync::Mutex;

use crate::error::{Error, Result};
use crate::format::terrain::{Record, TerrainFile, RECORDS_PER_BLOCK, RECORD_BYTES};
use crate::pager::{PageObserver, Pager};
use crate::refine::lanes::lanes_of;

/// Where refinement reads vertex records from, by layout index.
pub trait RecordSource: Sync {
    fn record(&self, index: u64) -> Record;

    /// `record(index)` as lanes `(z, error, radius, anything)`, for the walk's SSE test.
    #[inline(always)]
    fn record4(&self, index: u64) -> [f32; 4] {
        lanes_of(self.record(index))
    }

    /// Hint that `record(index)` will be read soon (a cache prefetch); must not fault.
    #[inline(always)]
    fn prefetch(&self, _index: u64) {}
}

impl RecordSource for [Record] {
    #[inline(always)]
    fn record(&self, index: u64) -> Record {
        self[index as usize]
    }

    #[inline(always)]
    fn record4(&self, index: u64) -> [f32; 4] {
        let i = index as usize;
        if i < self.len().saturating_sub(1) {
            // SAFETY: records `i` and `i + 1` are in the slice, so its 16 bytes from record `i`
            // (12 of them, and 4 of the next) are readable; `[f32; 4]` is read unaligned.
            unsafe { self.as_ptr().add(i).cast::<[f32; 4]>().read_unaligned() }
        } else {
            lanes_of(self[i])
        }
    }

    #[inline(always)]
    fn prefetch(&self, index: u64) {
        #[cfg(target_arch = "x86_64")]
        {
            // No bounds check: a prefetch never faults and reads nothing, so an address past the
            // end (a hint computed for a child that does not exist) only wastes the hint.
            let at = self.as_ptr().wrapping_add(index as usize);
            // SAFETY: `_mm_prefetch` does not dereference its argument (PREFETCHT0 is a hint that
            // cannot fault), so any address is sound.
            unsafe { std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(at.cast()) }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = index;
    }
}

/// A record slice whose 16-byte lane reads test the index against a bound computed once
/// (`len − 2`) rather than `len − 1` each read: the walk reads two records a node. The last
/// record's 16 bytes would run 4 bytes past the slice, so it alone is read as a `Record` (a
/// branch the walk almost never takes).
#[derive(Clone, Copy)]
pub struct RecordSlice<'a> {
    records: &'a [Record],
    /// The last index whose 16 bytes lie in the slice (`len − 2`).
    last: usize,
}

impl<'a> RecordSlice<'a> {
    /// `None` for fewer than two records (no 16-byte read fits).
    pub fn new(records: &'a [Record]) -> Option<Self> {
        (records.len() >= 2).then(|| RecordSlice { records, last: records.len() - 2 })
    }

    pub fn records(&self) -> &'a [Record] {
        self.records
    }
}

impl RecordSource for RecordSlice<'_> {
    #[inline(always)]
    fn record(&self, index: u64) -> Record {
        self.records[index as usize]
    }

    #[inline(always)]
    fn record4(&self, index: u64) -> [f32; 4] {
        let i = index as usize;
        if i <= self.last {
            // SAFETY: `i ≤ len − 2`, so the 16 bytes from record `i` (12 of it, 4 of the next)
            // are in the slice; `[f32; 4]` is read unaligned.
            unsafe { self.records.as_ptr().add(i).cast::<[f32; 4]>().read_unaligned() }
        } else {
            lanes_of(self.records[i])
        }
    }

    #[inline(always)]
    fn prefetch(&self, index: u64) {
        self.records.prefetch(index)
    }
}

/// A mapped terrain's records, every read reported to an observer: record `i` lives at byte
/// `payload_offset + i · 12` of the file.
pub struct MappedRecords<'a, O: PageObserver> {
    records: &'a [Record],
    payload_offset: u64,
    observer: O,
}

impl<'a, O: PageObserver> MappedRecords<'a, O> {
    pub fn new(records: &'a [Record], payload_offset: u64, observer: O) -> Self {
        MappedRecords { records, payload_offset, observer }
    }
}

impl<O: PageObserver> MappedRecords<'_, O> {
    /// Reports the read of record `index` to the observer.
    #[inline(always)]
    fn observe(&self, index: u64) {
        self.observer.read(self.payload_offset + index * RECORD_BYTES as u64, RECORD_BYTES as u64);
    }
}

impl<O: PageObserver> RecordSource for MappedRecords<'_, O> {
    #[inline(always)]
    fn record(&self, index: u64) -> Record {
        self.observe(index);
        self.records[index as usize]
    }

    #[inline(always)]
    fn record4(&self, index: u64) -> [f32; 4] {
        self.observe(index);
        self.records.record4(index)
    }

    #[inline(always)]
    fn prefetch(&self, index: u64) {
        self.records.prefetch(index);
    }
}

/// A terrain's records read block by block through its pager (pool or positioned reads): record
/// `i` is in block `i / RECORDS_PER_BLOCK`. A read that fails gives a record that is never active
/// (so refinement stops above it) and is kept for [`Self::take_error`].
pub struct PagerRecords<'a> {
    pager: &'a Pager,
    error: Mutex<Option<Error>>,
}

impl<'a> PagerRecords<'a> {
    pub fn new(terrain: &'a TerrainFile) -> Self {
        PagerRecords { pager: terrain.pager(), error: Mutex::new(None) }
    }

    /// The first read error since the last call.
    pub fn take_error(&self) -> Result<()> {
        match self.error.lock().unwrap_or_else(|p| p.into_inner()).take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

/// The record no refinement makes active (NaN error and radius fail the active test).
const UNREADABLE: Record = Record { z: 0.0, error: f32::NAN, radius: f32::NAN };

impl RecordSource for PagerRecords<'_> {
    fn record(&self, index: u64) -> Record {
        let at = (index % RECORDS_PER_BLOCK) as usize * RECORD_BYTES as usize;
        match self.pager.block((index / RECORDS_PER_BLOCK) as u32) {
            Ok(block) if at + RECORD_BYTES as usize <= block.len() => {
                bytemuck::pod_read_unaligned(&block[at..at + RECORD_BYTES as usize])
            }
            Ok(_) => UNREADABLE,
            Err(e) => {
                self.error.lock().unwrap_or_else(|p| p.into_inner()).get_or_insert(e);
                UNREADABLE
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every index reads its own record's lanes, the last one included (its 16 bytes would run
    /// past the slice).
    #[test]
    fn record_slice_reads_every_record_as_the_plain_slice_does() {
        let records: Vec<Record> =
            (0..5).map(|k| Record { z: k as f32, error: 10.0 + k as f32, radius: 20.0 + k as f32 }).collect();
        let slice = RecordSlice::new(&records).unwrap();
        for i in 0..records.len() as u64 {
            let (a, b) = (slice.record4(i), records[..].record4(i));
            assert_eq!(&a[..3], &lanes_of(records[i as usize])[..3], "record {i}");
            assert_eq!(&a[..3], &b[..3], "record {i}");
        }
        assert!(RecordSlice::new(&records[..1]).is_none());
    }
}
