//! A file whose logical bytes are stored with whole 4 KiB pages left out: the pages a [`PageMap`]
//! does not name read as zeros (a terrain file's padding, ARCHITECTURE.md "Padding that is never
//! stored"). [`SparseFile`] is a [`Source`] of the *logical* bytes over a source of the physical
//! ones, so the pager, the pool, the observers and every reader above them see the file as if the
//! missing pages were stored.
//!
//! Mapped, the logical file is one contiguous read-only region: anonymous zero pages, with every
//! stored run mapped over them from the file at its place (one mapping per run). Read, a positioned
//! read is split at the runs, and the gaps are zero-filled without I/O.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::device::{DeviceSpec, DeviceStats};
pub use super::source::PAGE_BYTES;
use super::source::{check_range, RemoteStats, RunMap, Source, SourceKind};
use crate::error::{Error, Result};

/// The most runs a mapped sparse file may have: each is a mapping of its own, and Linux allows a
/// process 65,530 by default (`vm.max_map_count`).
pub const MAX_MAPPED_RUNS: usize = 32_768;

/// Stored runs of a logical file: logical page ranges and where they start in the physical file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PageMap {
    /// `(first logical page, first physical page, pages)`, ascending and disjoint in both.
    runs: Vec<(u64, u64, u64)>,
    /// Logical length in bytes.
    logical_len: u64,
}

impl PageMap {
    /// A map from runs `(logical page, physical page, pages)`; `None` unless they ascend without
    /// overlap in both files and lie within `logical_len`.
    pub fn new(runs: Vec<(u64, u64, u64)>, logical_len: u64) -> Option<PageMap> {
        let mut end = (0u64, 0u64);
        for &(l, p, n) in &runs {
            if n == 0 || l < end.0 || p < end.1 {
                return None;
            }
            end = (l.checked_add(n)?, p.checked_add(n)?);
        }
        if end.0.checked_mul(PAGE_BYTES)? > logical_len.next_multiple_of(PAGE_BYTES) {
            return None;
        }
        Some(PageMap { runs, logical_len })
    }

    pub fn runs(&self) -> &[(u64, u64, u64)] {
        &self.runs
    }

    pub fn logical_len(&self) -> u64 {
        self.logical_len
    }

    /// Pages stored.
    pub fn stored_pages(&self) -> u64 {
        self.runs.iter().map(|r| r.2).sum()
    }

    /// The physical page holding logical page `page`, or `None` where it is not stored (zeros).
    pub fn physical(&self, page: u64) -> Option<u64> {
        let k = self.runs.partition_point(|r| r.0 + r.2 <= page);
        self.runs.get(k).filter(|r| r.0 <= page).map(|r| r.1 + (page - r.0))
    }

    /// The logical page stored at physical page `page`, where one is.
    pub fn logical(&self, page: u64) -> Option<u64> {
        let k = self.runs.partition_point(|r| r.1 + r.2 <= page);
        self.runs.get(k).filter(|r| r.1 <= page).map(|r| r.0 + (page - r.1))
    }

    /// The pieces of logical bytes `offset..offset + len`: `(logical offset, bytes, physical offset
    /// or None for zeros)`, in order.
    pub fn pieces(&self, offset: u64, len: u64) -> Vec<(u64, u64, Option<u64>)> {
        let mut out = Vec::new();
        let end = offset + len;
        let mut at = offset;
        let mut k = self.runs.partition_point(|r| (r.0 + r.2) * PAGE_BYTES <= at);
        while at < end {
            match self.runs.get(k) {
                Some(&(l, p, n)) if l * PAGE_BYTES <= at => {
                    let stop = ((l + n) * PAGE_BYTES).min(end);
                    out.push((at, stop - at, Some(p * PAGE_BYTES + (at - l * PAGE_BYTES))));
                    at = stop;
                    k += 1;
                }
                next => {
                    let stop = next.map_or(end, |r| (r.0 * PAGE_BYTES).min(end));
                    out.push((at, stop - at, None));
                    at = stop;
                }
            }
        }
        out
    }

    /// The physical page ranges `[p, q)` that hold the stored pages of logical page ranges `runs`
    /// (`[p, q)` each, ascending), merged where they touch.
    pub fn physical_runs(&self, runs: &[(u64, u64)]) -> Vec<(u64, u64)> {
        let mut out: Vec<(u64, u64)> = Vec::new();
        for &(p, q) in runs {
            for (_, bytes, at) in self.pieces(p * PAGE_BYTES, (q - p) * PAGE_BYTES) {
                if let Some(at) = at {
                    let (s, e) = (at / PAGE_BYTES, (at + bytes) / PAGE_BYTES);
                    match out.last_mut() {
                        Some(last) if last.1 >= s => last.1 = last.1.max(e),
                        _ => out.push((s, e)),
                    }
                }
            }
        }
        out
    }
}

/// The logical bytes of a file stored with pages left out (see the module's note).
pub struct SparseFile {
    path: PathBuf,
    inner: Arc<dyn Source>,
    map: PageMap,
    mapped: Option<RunMap>,
}

impl SparseFile {
    /// The logical file over `inner` (the physical bytes). A mapped `inner` gives a mapped logical
    /// file (its descriptor is mapped again, run by run); anything else reads through `inner`.
    pub fn new(inner: Arc<dyn Source>, map: PageMap) -> Result<SparseFile> {
        let path = inner.path().to_path_buf();
        for &(_, p, n) in &map.runs {
            let need = (p + n - 1) * PAGE_BYTES + 1;
            if inner.len() < need {
                return Err(Error::Truncated { path, expected: need, found: inner.len() });
            }
        }
        let mapped = match inner.kind() {
            SourceKind::Map => {
                if map.runs.len() > MAX_MAPPED_RUNS {
                    return Err(Error::InvalidArgument(format!(
                        "{}: {} stored runs are more than {MAX_MAPPED_RUNS} mappings; read it with --access read or pool",
                        path.display(),
                        map.runs.len()
                    )));
                }
                inner.map_runs(&map.runs, map.logical_len)?
            }
            SourceKind::Read => None,
        };
        Ok(SparseFile { path, inner, map, mapped })
    }

    pub fn page_map(&self) -> &PageMap {
        &self.map
    }
}

impl Source for SparseFile {
    fn path(&self) -> &Path {
        &self.path
    }

    fn len(&self) -> u64 {
        self.map.logical_len
    }

    fn kind(&self) -> SourceKind {
        self.inner.kind()
    }

    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<()> {
        check_range(&self.path, self.len(), offset, buf.len())?;
        if let Some(m) = &self.mapped {
            buf.copy_from_slice(&m.bytes()[offset as usize..offset as usize + buf.len()]);
            return Ok(());
        }
        for (at, bytes, from) in self.map.pieces(offset, buf.len() as u64) {
            let dst = &mut buf[(at - offset) as usize..(at - offset + bytes) as usize];
            match from {
                Some(from) => self.inner.read_at(from, dst)?,
                None => dst.fill(0),
            }
        }
        Ok(())
    }

    fn mapped(&self) -> Option<&[u8]> {
        self.mapped.as_ref().map(|m| &m.bytes()[..self.map.logical_len as usize])
    }

    fn advise_random(&self) -> Result<()> {
        if let Some(m) = &self.mapped {
            #[cfg(feature = "native")]
            m.advise(libc::MADV_RANDOM, &self.path)?;
        }
        self.inner.advise_random()
    }

    fn evict(&self) -> Result<()> {
        if let Some(m) = &self.mapped {
            #[cfg(feature = "native")]
            m.advise(libc::MADV_DONTNEED, &self.path)?;
        }
        self.inner.evict()
    }

    /// Pages left out read as zeros without I/O, so they are resident; a stored page is where
    /// its physical page is.
    fn resident_pages(&self, first: u64, end: u64) -> Result<Vec<bool>> {
        // Only the span of physical pages behind `first..end` is asked about, not the file.
        let physical: Vec<Option<u64>> = (first..end).map(|p| self.map.physical(p)).collect();
        let (lo, hi) = physical.iter().flatten().fold((u64::MAX, 0), |(lo, hi), &q| (lo.min(q), hi.max(q + 1)));
        let here = if lo < hi { self.inner.resident_pages(lo, hi)? } else { Vec::new() };
        Ok(physical.iter().map(|q| q.is_none_or(|q| here.get((q - lo) as usize).copied().unwrap_or(false))).collect())
    }

    fn stored_runs(&self, runs: &[(u64, u64)]) -> Vec<(u64, u64)> {
        self.inner.stored_runs(&self.map.physical_runs(runs))
    }

    /// The stored pages of `runs` are read from the physical file in one call (so a remote file
    /// coalesces them as it would any runs); pages left out are handed over as zeros.
    fn read_page_runs(&self, runs: &[(u64, u64)], got: &mut dyn FnMut(u64, &[u8]) -> Result<()>) -> Result<()> {
        let end_page = self.len().div_ceil(PAGE_BYTES);
        let mut zeros: Vec<u8> = Vec::new();
        for &(p, q) in runs {
            let mut page = p;
            while page < q.min(end_page) {
                if self.map.physical(page).is_some() {
                    page += 1;
                    continue;
                }
                let mut gap_end = page + 1;
                while gap_end < q.min(end_page) && self.map.physical(gap_end).is_none() {
                    gap_end += 1;
                }
                let bytes = (gap_end * PAGE_BYTES).min(self.len()) - page * PAGE_BYTES;
                zeros.resize(bytes as usize, 0);
                got(page, &zeros)?;
                page = gap_end;
            }
        }
        let map = &self.map;
        self.inner.read_page_runs(&map.physical_runs(runs), &mut |page, bytes| {
            // A physical run may cross from one stored run to the next: split where the logical
            // pages stop being consecutive.
            let (mut page, mut bytes) = (page, bytes);
            while !bytes.is_empty() {
                let Some(logical) = map.logical(page) else {
                    // Not a stored page of the logical file (the page map's own pages).
                    let skip = (PAGE_BYTES as usize).min(bytes.len());
                    (page, bytes) = (page + 1, &bytes[skip..]);
                    continue;
                };
                let mut pages = 1;
                while (pages as usize) * (PAGE_BYTES as usize) < bytes.len()
                    && map.logical(page + pages) == Some(logical + pages)
                {
                    pages += 1;
                }
                let take = ((pages * PAGE_BYTES) as usize).min(bytes.len());
                got(logical, &bytes[..take])?;
                (page, bytes) = (page + pages, &bytes[take..]);
            }
            Ok(())
        })
    }

    fn network(&self) -> Option<RemoteStats> {
        self.inner.network()
    }

    fn device_stats(&self) -> Option<DeviceStats> {
        self.inner.device_stats()
    }

    fn device_spec(&self) -> Option<DeviceSpec> {
        self.inner.device_spec()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both kinds read the logical bytes: stored runs from their physical place, the rest zero,
    /// across run boundaries and a partial last page.
    #[test]
    fn sparse_files_read_their_logical_bytes_both_ways() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.bin");
        // Logical: 10 pages + 100 bytes; stored: page 0, pages 3..5, page 10 (partial).
        let logical_len = 10 * PAGE_BYTES + 100;
        let logical: Vec<u8> = (0..logical_len)
            .map(|i| {
                let page = i / PAGE_BYTES;
                if page == 0 || (3..5).contains(&page) || page == 10 {
                    (i * 31 % 251 + 1) as u8
                } else {
                    0
                }
            })
            .collect();
        let runs = vec![(0, 0, 1), (3, 1, 2), (10, 3, 1)];
        let mut physical = Vec::new();
        for &(l, _, n) in &runs {
            let s = (l * PAGE_BYTES) as usize;
            let e = (((l + n) * PAGE_BYTES) as usize).min(logical.len());
            physical.extend_from_slice(&logical[s..e]);
        }
        std::fs::write(&path, &physical).unwrap();
        let map = PageMap::new(runs.clone(), logical_len).unwrap();
        assert_eq!(map.stored_pages(), 4);
        assert_eq!((map.physical(4), map.physical(5), map.logical(3)), (Some(2), None, Some(10)));
        assert_eq!(map.physical_runs(&[(2, 6), (9, 11)]), vec![(1, 4)]);
        for kind in [SourceKind::Map, SourceKind::Read] {
            let inner = super::super::open(&path, kind).unwrap();
            let s = SparseFile::new(inner, map.clone()).unwrap();
            assert_eq!(s.len(), logical_len);
            assert_eq!(s.mapped().is_some(), kind == SourceKind::Map);
            if let Some(m) = s.mapped() {
                assert_eq!(m, &logical[..]);
            }
            for (offset, len) in [
                (0u64, 100usize),
                (4000, 9000),
                (2 * PAGE_BYTES + 5, 3 * PAGE_BYTES as usize),
                (logical_len - 150, 150),
            ] {
                let mut buf = vec![0xAAu8; len];
                s.read_at(offset, &mut buf).unwrap();
                assert_eq!(&buf[..], &logical[offset as usize..offset as usize + len], "{kind:?} {offset}+{len}");
            }
            assert!(s.read_at(logical_len - 10, &mut [0u8; 20]).is_err());
            s.advise_random().unwrap();
            s.evict().unwrap();
        }
        // Runs that overlap, or a physical file too short for its runs, are refused.
        assert!(PageMap::new(vec![(0, 0, 2), (1, 2, 1)], logical_len).is_none());
        assert!(PageMap::new(vec![(0, 0, 12)], logical_len).is_none());
        let short = PageMap::new(vec![(0, 0, 1), (5, 9, 1)], logical_len).unwrap();
        let inner = super::super::open(&path, SourceKind::Read).unwrap();
        assert!(SparseFile::new(inner, short).err().unwrap().to_string().contains("truncated"));
    }
}
