//! Where a file's bytes come from: a [`Source`] is a read-only file of known length that can be
//! read at any offset. Two local kinds live here: [`MappedFile`] (a memory map; the OS pages the
//! file in, and readers may borrow the bytes in place) and [`ReadFile`] (positioned reads,
//! `pread`); a remote file ([`super::remote`]), a file stored with pages left out
//! ([`super::sparse`]) and a file on an emulated device build on the same trait. Every relief
//! file is opened through [`super::open`], and this is the one place relief maps a file it reads:
//! terrain, VDT, meta-node and page files all go through [`MappedFile::open`], and a terrain file
//! stored with pages left out is mapped again, run by run, by [`RunMap`], under the same argument.
//!
//! The trait says what a source can do, never what it is: whether a page can be read without
//! waiting on a network ([`Source::resident_pages`]), batched page reads
//! ([`Source::read_page_runs`]), what the network or the device under it has cost. The pager asks
//! these; nothing above it looks beneath a source.

#[cfg(feature = "native")]
use std::fs::File;
#[cfg(feature = "native")]
use std::os::fd::AsRawFd;
#[cfg(feature = "native")]
use std::os::unix::fs::FileExt;
use std::path::Path;
#[cfg(feature = "native")]
use std::path::PathBuf;

#[cfg(feature = "native")]
use memmap2::Mmap;
use serde::Serialize;

use super::device::{DeviceSpec, DeviceStats};
#[cfg(feature = "native")]
use crate::error::IoContext;
use crate::error::{Error, Result};

/// The page every source is read in: 4 KiB, the OS page and the unit of relief's files, of a
/// remote file's cache and of a sparse file's page map.
pub const PAGE_BYTES: u64 = 4096;

/// The most bytes relief maps at once: 128 TiB, the user address space of x86-64 and AArch64
/// with 48-bit virtual addresses. Terrain files are mapped whole, and a conversion maps its
/// scratch grids whole, so a grid needing more is refused before anything is written.
pub const MAX_MAPPED_BYTES: u64 = 1 << 47;

/// How a [`Source`] reads its file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SourceKind {
    /// A read-only memory map.
    Map,
    /// Positioned reads (`pread`).
    Read,
}

/// A read-only file of fixed length.
pub trait Source: Send + Sync {
    /// The file, for error messages.
    fn path(&self) -> &Path;
    /// The file's length in bytes, fixed when it was opened.
    fn len(&self) -> u64;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    fn kind(&self) -> SourceKind;
    /// Fills `buf` with the bytes at `offset`; a range past the end is an error naming the file.
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<()>;
    /// The whole file in memory, where the source is a map.
    fn mapped(&self) -> Option<&[u8]> {
        None
    }
    /// No readahead around what is read (`MADV_RANDOM`, `POSIX_FADV_RANDOM`): a cold run then
    /// reads exactly the pages it touches, which is what page-fault experiments count.
    fn advise_random(&self) -> Result<()>;
    /// Drops the file's pages from the OS page cache (a mapping's resident pages first), so the
    /// next reads come from storage.
    fn evict(&self) -> Result<()>;
    /// Which of pages `first..end` ([`PAGE_BYTES`] each) a read gets without waiting on a
    /// network: every page of a local file; a remote file's pages in its local cache.
    fn resident_pages(&self, first: u64, end: u64) -> Result<Vec<bool>> {
        Ok(vec![true; end.saturating_sub(first) as usize])
    }
    /// Reads the pages of `runs` (`[p, q)` page numbers, ascending, within the file; the last page
    /// may be short at the file's end), calling `got(page, bytes)` for runs of consecutive whole
    /// pages, in no particular order, with every page asked for at least once (a source may hand
    /// over pages around them too). One positioned read per run here; a remote file fetches its
    /// missing pages in coalesced range requests, several in flight.
    fn read_page_runs(&self, runs: &[(u64, u64)], got: &mut dyn FnMut(u64, &[u8]) -> Result<()>) -> Result<()> {
        let mut buf = Vec::new();
        for &(p, q) in runs {
            let (start, end) = (p.saturating_mul(PAGE_BYTES), q.saturating_mul(PAGE_BYTES).min(self.len()));
            if start >= end {
                continue;
            }
            buf.resize((end - start) as usize, 0);
            self.read_at(start, &mut buf)?;
            got(p, &buf)?;
        }
        Ok(())
    }
    /// The page runs of the file as stored that hold pages `runs` of this one (`[p, q)`,
    /// ascending): what a host fetches for them ([`super::hosted`]). The same runs here; a file
    /// stored with pages left out names its stored pages (pages left out are in none).
    fn stored_runs(&self, runs: &[(u64, u64)]) -> Vec<(u64, u64)> {
        runs.to_vec()
    }
    /// What reading this source has cost over a network, where it reads over one.
    fn network(&self) -> Option<RemoteStats> {
        None
    }
    /// What the emulated device under this source has served, where it is on one.
    fn device_stats(&self) -> Option<DeviceStats> {
        None
    }
    /// The emulated device under this source, where it is on one.
    fn device_spec(&self) -> Option<DeviceSpec> {
        None
    }
    /// The file mapped again as a logical region of `logical_len` bytes: zero pages, with each run
    /// `(logical page, physical page, pages)` of this file mapped over them at its place (see
    /// [`super::sparse`]). `None` where the source is not a local map.
    fn map_runs(&self, _runs: &[(u64, u64, u64)], _logical_len: u64) -> Result<Option<RunMap>> {
        Ok(None)
    }
}

/// What a source read over a network has cost so far.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq, Eq)]
pub struct RemoteStats {
    /// Requests answered (retries included).
    pub requests: u64,
    /// Body bytes received.
    pub bytes: u64,
    /// Requests that failed and were retried.
    pub retries: u64,
    /// Pages read from the local cache instead of the network.
    pub cache_hit_pages: u64,
}

#[cfg(feature = "native")]
fn fadvise(path: &Path, file: &File, advice: libc::c_int) -> Result<()> {
    // SAFETY: posix_fadvise only reads the descriptor, which `file` keeps open for the call.
    let rc = unsafe { libc::posix_fadvise(file.as_raw_fd(), 0, 0, advice) };
    if rc != 0 {
        return Err(Error::io(path, std::io::Error::from_raw_os_error(rc)));
    }
    Ok(())
}

/// A read of `bytes` at `offset` must lie within a file of `len` bytes: else an error naming it.
pub(crate) fn check_range(path: &Path, len: u64, offset: u64, bytes: usize) -> Result<()> {
    match offset.checked_add(bytes as u64) {
        Some(end) if end <= len => Ok(()),
        _ => Err(Error::Truncated { path: path.into(), expected: offset.saturating_add(bytes as u64), found: len }),
    }
}

#[cfg(feature = "native")]
/// A file mapped read-only.
pub struct MappedFile {
    path: PathBuf,
    // Keeps the descriptor open for the map's lifetime (and for the advice calls).
    file: File,
    map: Mmap,
}

#[cfg(feature = "native")]
impl MappedFile {
    /// Maps `path` read-only, records it for the SIGBUS report, and checks the map covers the
    /// whole file.
    ///
    /// # Safety (why the `unsafe` inside is sound)
    /// The map is read-only and owned by this value, which also holds the file open for the
    /// map's lifetime. relief never writes any of its files in place: every writer builds a
    /// temporary file and renames it over the target, so an existing mapping keeps the old inode.
    /// Only another process truncating or rewriting the file while it is mapped can fault a read
    /// (SIGBUS, reported with the path by [`crate::sys::sigbus`]) or change what is read; every
    /// reader validates the sizes and offsets it uses against [`Source::len`], so well-formed
    /// reads stay inside the map.
    pub fn open(path: &Path) -> Result<MappedFile> {
        MappedFile::open_as(path, path)
    }

    /// [`Self::open`] of `actual`, named `path` in errors (a device's served copy of `path`).
    pub fn open_as(actual: &Path, path: &Path) -> Result<MappedFile> {
        let file = File::open(actual).at(path)?;
        let len = file.metadata().at(path)?.len();
        // SAFETY: see the function's documentation above.
        let map = unsafe { Mmap::map(&file) }.at(path)?;
        crate::sys::sigbus::note_mapped(path);
        if map.len() as u64 != len {
            return Err(Error::Truncated { path: path.into(), expected: len, found: map.len() as u64 });
        }
        Ok(MappedFile { path: path.to_path_buf(), file, map })
    }

    /// The mapped bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.map
    }
}

#[cfg(feature = "native")]
impl Source for MappedFile {
    fn path(&self) -> &Path {
        &self.path
    }

    fn len(&self) -> u64 {
        self.map.len() as u64
    }

    fn kind(&self) -> SourceKind {
        SourceKind::Map
    }

    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<()> {
        check_range(&self.path, self.len(), offset, buf.len())?;
        buf.copy_from_slice(&self.map[offset as usize..offset as usize + buf.len()]);
        Ok(())
    }

    fn mapped(&self) -> Option<&[u8]> {
        Some(&self.map)
    }

    fn advise_random(&self) -> Result<()> {
        self.map.advise(memmap2::Advice::Random).at(&self.path)?;
        fadvise(&self.path, &self.file, libc::POSIX_FADV_RANDOM)
    }

    fn evict(&self) -> Result<()> {
        // Pages still mapped stay in the page cache whatever posix_fadvise says: unmap them from
        // this process first. SAFETY: the map is a read-only shared mapping of a file; after
        // MADV_DONTNEED the next access reads the page again from the file, so no content
        // visible through `bytes()` changes.
        unsafe { self.map.unchecked_advise(memmap2::UncheckedAdvice::DontNeed) }.at(&self.path)?;
        fadvise(&self.path, &self.file, libc::POSIX_FADV_DONTNEED)
    }

    fn map_runs(&self, runs: &[(u64, u64, u64)], logical_len: u64) -> Result<Option<RunMap>> {
        RunMap::new(&self.path, &self.file, runs, logical_len, self.len()).map(Some)
    }
}

#[cfg(feature = "native")]
/// A logical region mapped over anonymous zero pages, with runs of a file mapped over them (a
/// file stored with pages left out, [`super::sparse`]).
pub struct RunMap {
    addr: *mut libc::c_void,
    len: usize,
}

#[cfg(feature = "native")]
// SAFETY: the region is read-only for its whole life and owned by this value; only `Drop`
// unmaps it, so sharing the address between threads shares only reads.
unsafe impl Send for RunMap {}
#[cfg(feature = "native")]
// SAFETY: as for `Send`: every access through `&RunMap` is a read of a read-only mapping.
unsafe impl Sync for RunMap {}

#[cfg(feature = "native")]
impl RunMap {
    /// Reserves `logical_len` bytes of zero pages and maps every run of `file` (`physical_len`
    /// bytes long) over them.
    ///
    /// # Safety (why the `unsafe` inside is sound)
    /// The reservation is a fresh private anonymous mapping of this process, and every run is
    /// mapped with `MAP_FIXED` strictly inside it (runs past the logical length are refused here),
    /// so no other mapping is replaced. Everything is read-only, and the file mappings carry the
    /// same argument as [`MappedFile::open`]: relief never writes its files in place, and a
    /// truncation by another process is reported as SIGBUS with the path.
    fn new(path: &Path, file: &File, runs: &[(u64, u64, u64)], logical_len: u64, physical_len: u64) -> Result<RunMap> {
        let len = logical_len.max(1) as usize;
        let reserved = (len as u64).div_ceil(PAGE_BYTES) * PAGE_BYTES;
        if runs.iter().any(|&(l, _, n)| l.saturating_add(n).saturating_mul(PAGE_BYTES) > reserved) {
            return Err(Error::InvalidArgument(format!("{}: a stored run lies past the logical file", path.display())));
        }
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
        let region = RunMap { addr, len };
        for &(l, p, n) in runs {
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

    /// The logical bytes.
    pub fn bytes(&self) -> &[u8] {
        // SAFETY: a readable mapping of `len` bytes that lives as long as `self`.
        unsafe { std::slice::from_raw_parts(self.addr.cast::<u8>(), self.len) }
    }

    /// `madvise` over the whole region (`MADV_RANDOM`, `MADV_DONTNEED`).
    pub fn advise(&self, advice: i32, path: &Path) -> Result<()> {
        // SAFETY: advice on our own mapping; DONTNEED on a read-only shared file mapping or on
        // anonymous zero pages changes nothing that is read (they read back the same).
        if unsafe { libc::madvise(self.addr, self.len, advice) } != 0 {
            return Err(Error::io(path, std::io::Error::last_os_error()));
        }
        Ok(())
    }
}

#[cfg(feature = "native")]
impl Drop for RunMap {
    fn drop(&mut self) {
        // SAFETY: the region was mapped by `new` and is unmapped once, here.
        unsafe { libc::munmap(self.addr, self.len) };
    }
}

/// Without an operating system's maps there are no run maps: [`Source::map_runs`] is `None`.
#[cfg(not(feature = "native"))]
pub enum RunMap {}

#[cfg(not(feature = "native"))]
impl RunMap {
    /// The logical bytes (never called: no value exists).
    pub fn bytes(&self) -> &[u8] {
        match *self {}
    }

    /// Never called: no value exists.
    pub fn advise(&self, _advice: i32, _path: &Path) -> Result<()> {
        match *self {}
    }
}

#[cfg(feature = "native")]
/// A file read with positioned reads.
pub struct ReadFile {
    path: PathBuf,
    file: File,
    len: u64,
}

#[cfg(feature = "native")]
impl ReadFile {
    pub fn open(path: &Path) -> Result<ReadFile> {
        ReadFile::open_as(path, path)
    }

    /// [`Self::open`] of `actual`, named `path` in errors (a device's served copy of `path`).
    pub fn open_as(actual: &Path, path: &Path) -> Result<ReadFile> {
        let file = File::open(actual).at(path)?;
        let len = file.metadata().at(path)?.len();
        Ok(ReadFile { path: path.to_path_buf(), file, len })
    }
}

#[cfg(feature = "native")]
impl Source for ReadFile {
    fn path(&self) -> &Path {
        &self.path
    }

    fn len(&self) -> u64 {
        self.len
    }

    fn kind(&self) -> SourceKind {
        SourceKind::Read
    }

    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<()> {
        check_range(&self.path, self.len, offset, buf.len())?;
        self.file.read_exact_at(buf, offset).at(&self.path)
    }

    fn advise_random(&self) -> Result<()> {
        fadvise(&self.path, &self.file, libc::POSIX_FADV_RANDOM)
    }

    fn evict(&self) -> Result<()> {
        fadvise(&self.path, &self.file, libc::POSIX_FADV_DONTNEED)
    }
}

#[cfg(all(test, feature = "native"))]
mod tests {
    use super::*;

    #[test]
    fn both_kinds_read_the_same_bytes_and_refuse_ranges_past_the_end() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.bin");
        let bytes: Vec<u8> = (0..10_000u32).map(|i| (i * 7 % 251) as u8).collect();
        std::fs::write(&path, &bytes).unwrap();
        for kind in [SourceKind::Map, SourceKind::Read] {
            let s = super::super::open(&path, kind).unwrap();
            assert_eq!((s.len(), s.kind()), (10_000, kind));
            let mut buf = [0u8; 100];
            s.read_at(4090, &mut buf).unwrap();
            assert_eq!(&buf[..], &bytes[4090..4190]);
            let e = s.read_at(9950, &mut buf).unwrap_err().to_string();
            assert!(e.starts_with(&path.display().to_string()) && e.contains("truncated"), "{e}");
            assert_eq!(s.mapped().is_some(), kind == SourceKind::Map);
            s.advise_random().unwrap();
            s.evict().unwrap();
            s.read_at(0, &mut buf).unwrap();
            assert_eq!(&buf[..], &bytes[..100], "readable after eviction");
        }
        let missing = dir.path().join("missing.bin");
        for kind in [SourceKind::Map, SourceKind::Read] {
            let e = super::super::open(&missing, kind).err().unwrap().to_string();
            assert!(e.starts_with(&missing.display().to_string()), "{e}");
        }
    }
}
