//! Where a file's bytes come from: a [`Source`] is a read-only file of known length that can be
//! read at any offset. Two kinds: [`MappedFile`] (a memory map; the OS pages the file in, and
//! readers may borrow the bytes in place) and [`ReadFile`] (positioned reads, `pread`). Every
//! relief file is opened through [`open`], so this is also the one place relief maps a file:
//! terrain, VDT, meta-node and page files all go through [`MappedFile::open`], and the safety
//! argument is made once (a terrain file stored with pages left out is mapped again, run by run,
//! by [`super::sparse`], under the same argument).

use std::fs::File;
use std::os::fd::AsRawFd;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use memmap2::Mmap;

use super::device::{DeviceMount, DeviceSpec};
use crate::error::{Error, IoContext, Result};

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
    /// The remote file behind this source, where it is one.
    fn remote(&self) -> Option<&super::remote::RemoteFile> {
        None
    }
    /// The emulated device this source reads through, where it has one.
    fn device(&self) -> Option<&DeviceMount> {
        None
    }
    /// The open local file underneath, where there is one (to map it again, see
    /// [`super::sparse`]).
    fn file(&self) -> Option<&File> {
        None
    }
    /// Where the source's logical bytes are stored with pages left out, their map.
    fn page_map(&self) -> Option<&super::sparse::PageMap> {
        None
    }
}

/// A source reading a device's served copy of a file (see [`open_on`]).
struct OnDevice {
    // Declared first, so dropped first: the served file is closed (and unmapped) before the
    // device's file system is unmounted.
    inner: Box<dyn Source>,
    mount: DeviceMount,
}

impl Source for OnDevice {
    fn path(&self) -> &Path {
        self.inner.path()
    }
    fn len(&self) -> u64 {
        self.inner.len()
    }
    fn kind(&self) -> SourceKind {
        self.inner.kind()
    }
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> Result<()> {
        self.inner.read_at(offset, buf)
    }
    fn mapped(&self) -> Option<&[u8]> {
        self.inner.mapped()
    }
    fn advise_random(&self) -> Result<()> {
        self.inner.advise_random()
    }
    fn evict(&self) -> Result<()> {
        self.inner.evict()
    }
    fn device(&self) -> Option<&DeviceMount> {
        Some(&self.mount)
    }
    fn file(&self) -> Option<&File> {
        self.inner.file()
    }
}

/// Opens `path` as a source of the given kind. A remote location (`http(s)://`, `s3://`, see
/// [`super::remote`]) is read with range requests through its local cache, whatever the kind.
pub fn open(path: &Path, kind: SourceKind) -> Result<std::sync::Arc<dyn Source>> {
    open_on(path, kind, None)
}

/// [`open`], a local file served through an emulated device when `device` is given (see
/// [`super::device`]): mapped or read as asked, from the device's served copy.
pub fn open_on(path: &Path, kind: SourceKind, device: Option<DeviceSpec>) -> Result<std::sync::Arc<dyn Source>> {
    if let Some(spec) = device {
        if super::remote::is_remote(path) {
            return Err(Error::InvalidArgument(format!(
                "{}: an emulated device is for local files (a remote one has its own latency)",
                path.display()
            )));
        }
        let mount = DeviceMount::new(path, spec)?;
        let inner: Box<dyn Source> = match kind {
            SourceKind::Map => Box::new(MappedFile::open_as(mount.path(), path)?),
            SourceKind::Read => Box::new(ReadFile::open_as(mount.path(), path)?),
        };
        return Ok(std::sync::Arc::new(OnDevice { inner, mount }));
    }
    if super::remote::is_remote(path) {
        let location = path.to_string_lossy();
        return Ok(std::sync::Arc::new(super::remote::RemoteFile::open(
            &location,
            super::remote::RemoteOptions::from_env()?,
        )?));
    }
    Ok(match kind {
        SourceKind::Map => std::sync::Arc::new(MappedFile::open(path)?),
        SourceKind::Read => std::sync::Arc::new(ReadFile::open(path)?),
    })
}

fn fadvise(path: &Path, file: &File, advice: libc::c_int) -> Result<()> {
    // SAFETY: posix_fadvise only reads the descriptor, which `file` keeps open for the call.
    let rc = unsafe { libc::posix_fadvise(file.as_raw_fd(), 0, 0, advice) };
    if rc != 0 {
        return Err(Error::io(path, std::io::Error::from_raw_os_error(rc)));
    }
    Ok(())
}

/// A read of `bytes` at `offset` must lie within a file of `len` bytes: else an error naming it.
pub(super) fn check_range(path: &Path, len: u64, offset: u64, bytes: usize) -> Result<()> {
    match offset.checked_add(bytes as u64) {
        Some(end) if end <= len => Ok(()),
        _ => Err(Error::Truncated { path: path.into(), expected: offset.saturating_add(bytes as u64), found: len }),
    }
}

/// A file mapped read-only.
pub struct MappedFile {
    path: PathBuf,
    // Keeps the descriptor open for the map's lifetime (and for the advice calls).
    file: File,
    map: Mmap,
}

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

    fn file(&self) -> Option<&File> {
        Some(&self.file)
    }
}

/// A file read with positioned reads.
pub struct ReadFile {
    path: PathBuf,
    file: File,
    len: u64,
}

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

    fn file(&self) -> Option<&File> {
        Some(&self.file)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_kinds_read_the_same_bytes_and_refuse_ranges_past_the_end() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.bin");
        let bytes: Vec<u8> = (0..10_000u32).map(|i| (i * 7 % 251) as u8).collect();
        std::fs::write(&path, &bytes).unwrap();
        for kind in [SourceKind::Map, SourceKind::Read] {
            let s = open(&path, kind).unwrap();
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
            let e = open(&missing, kind).err().unwrap().to_string();
            assert!(e.starts_with(&missing.display().to_string()), "{e}");
        }
    }
}
