//! A file whose logical bytes are stored with whole 4 KiB pages left out: the pages a [`PageMap`]
//! does not name read as zeros (a terrain file's padding, ARCHITECTURE.md "Padding that is never
//! stored"). [`SparseFile`] is a [`Source`] of the *logical* bytes over a source of the physical
//! ones, so the pager, the pool, the observers and every reader above them see the file as if the
//! missing pages were stored.
//!
//! Mapped, the logical file is one contiguous read-only region: anonymous zero pages, with every
//! stored run mapped over them from the file at its place (one mapping per run). Read, a positioned
//! read is split at the runs, and the gaps are zero-filled without I/O.

use std::fs::File;
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::device::DeviceMount;
use super::source::{check_range, Source, SourceKind};
use crate::error::{Error, Result};

pub const PAGE_BYTES: u64 = 4096;

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

/// A logical region mapped over anonymous zero pages.
struct VirtualMap {
    addr: *mut libc::c_void,
    len: usize,
}

// SAFETY: the region is read-only for its whole life; only `Drop` unmaps it.
unsafe impl Send for VirtualMap {}
unsafe impl Sync for VirtualMap {}

impl VirtualMap {
    /// Reserves `len` bytes of zero pages and maps every run of `map` from `file` over them.
    ///
    /// # Safety (why the `unsafe` inside is sound)
    /// The reservation is a fresh private anonymous mapping of this process, and every run is
    /// mapped with `MAP_FIXED` strictly inside it (the runs lie within the logical length, checked
    /// by [`PageMap::new`]), so no other mapping is replaced. Everything is read-only, and the file
    /// mappings carry the same argument as [`super::source::MappedFile::open`]: relief never writes
    /// its files in place, and a truncation by another process is reported as SIGBUS with the path.
    fn new(path: &Path, file: &File, map: &PageMap, physical_len: u64) -> Result<VirtualMap> {
        let len = map.logical_len.max(1) as usize;
        // SAFETY: see above; a fresh anonymous region.
        let addr = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                len,
                libc::PROT_READ,
                libc::MAP_PRIVATE | libc::MAP_ANONYMOUS | libc::MAP_NORESERVE,
                -1,
                0,
            )
        };
        if addr == libc::MAP_FAILED {
            return Err(Error::io(path, std::io::Error::last_os_error()));
        }
        let region = VirtualMap { addr, len };
        for &(l, p, n) in &map.runs {
            let (at, from) = (l * PAGE_BYTES, p * PAGE_BYTES);
            // The last run may end in a partial page of the file.
            let bytes = (n * PAGE_BYTES).min(physical_len.saturating_sub(from));
            if bytes == 0 {
                continue;
            }
            // SAFETY: inside the reservation (see above).
            let got = unsafe {
                libc::mmap(
                    region.addr.cast::<u8>().add(at as usize).cast(),
                    bytes as usize,
                    libc::PROT_READ,
                    libc::MAP_SHARED | libc::MAP_FIXED,
                    file.as_raw_fd(),
                    from as libc::off_t,
                )
            };
            if got == libc::MAP_FAILED {
                let e = std::io::Error::last_os_error();
                return Err(Error::io(path, std::io::Error::new(e.kind(), format!("mapping a stored run: {e}"))));
            }
        }
        Ok(region)
    }

    fn bytes(&self) -> &[u8] {
        // SAFETY: a readable mapping of `len` bytes that lives as long as `self`.
        unsafe { std::slice::from_raw_parts(self.addr.cast::<u8>(), self.len) }
    }

    fn advise(&self, advice: libc::c_int, path: &Path) -> Result<()> {
        // SAFETY: advice on our own mapping; DONTNEED on a read-only shared file mapping or on
        // anonymous zero pages changes nothing that is read (they read back the same).
        if unsafe { libc::madvise(self.addr, self.len, advice) } != 0 {
            return Err(Error::io(path, std::io::Error::last_os_error()));
        }
        Ok(())
    }
}

impl Drop for VirtualMap {
    fn drop(&mut self) {
        // SAFETY: the region was mapped by `new` and is unmapped once, here.
        unsafe { libc::munmap(self.addr, self.len) };
    }
}

/// The logical bytes of a file stored with pages left out (see the module's note).
pub struct SparseFile {
    path: PathBuf,
    inner: Arc<dyn Source>,
    map: PageMap,
    mapped: Option<VirtualMap>,
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
        let mapped = match (inner.kind(), inner.file()) {
            (SourceKind::Map, Some(file)) => {
                if map.runs.len() > MAX_MAPPED_RUNS {
                    return Err(Error::InvalidArgument(format!(
                        "{}: {} stored runs are more than {MAX_MAPPED_RUNS} mappings; read it with --access read or pool",
                        path.display(),
                        map.runs.len()
                    )));
                }
                Some(VirtualMap::new(&path, file, &map, inner.len())?)
            }
            _ => None,
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
            m.advise(libc::MADV_RANDOM, &self.path)?;
        }
        self.inner.advise_random()
    }

    fn evict(&self) -> Result<()> {
        if let Some(m) = &self.mapped {
            m.advise(libc::MADV_DONTNEED, &self.path)?;
        }
        self.inner.evict()
    }

    fn remote(&self) -> Option<&super::remote::RemoteFile> {
        self.inner.remote()
    }

    fn device(&self) -> Option<&DeviceMount> {
        self.inner.device()
    }

    fn file(&self) -> Option<&File> {
        self.inner.file()
    }

    fn page_map(&self) -> Option<&PageMap> {
        Some(&self.map)
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
            let inner = super::super::source::open(&path, kind).unwrap();
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
        let inner = super::super::source::open(&path, SourceKind::Read).unwrap();
        assert!(SparseFile::new(inner, short).err().unwrap().to_string().contains("truncated"));
    }
}
