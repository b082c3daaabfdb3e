//! Scratch memory backed by an unlinked file: large intermediate grids (conversion's heights and
//! bounds, imagery's mip levels) that the kernel may page out, so anonymous memory stays small.

use std::fs::File;
use std::path::Path;

use memmap2::MmapMut;

use crate::error::{Error, IoContext, Result};

/// A writable mapping of a fresh, already unlinked file (it vanishes with the process, whatever
/// the exit).
pub struct ScratchMap {
    _file: File, // held for the mapping's lifetime
    map: MmapMut,
    len: usize,
}

impl ScratchMap {
    /// `bytes` zeroed bytes in a scratch file in `dir`.
    pub fn new(dir: &Path, bytes: u64) -> Result<ScratchMap> {
        let file = tempfile::tempfile_in(dir).at(dir)?;
        // A mapping cannot be empty; an empty scratch maps one byte and shows none.
        let len = bytes.max(1);
        file.set_len(len).map_err(|e| file_system_limit(e, dir, len))?;
        // SAFETY: the file was just created by this process and is unlinked (nobody else can
        // open it), sized above; it is mapped once and lives as long as the map.
        let map = unsafe { MmapMut::map_mut(&file) }.at(dir)?;
        Ok(ScratchMap { _file: file, map, len: bytes as usize })
    }

    /// Maps a scratch file this process wrote itself: `file` must come from
    /// [`tempfile::tempfile_in`] (unlinked, so nobody else can open it). `dir` names it in errors.
    pub fn from_unlinked(file: std::fs::File, dir: &Path) -> Result<ScratchMap> {
        let len = file.metadata().at(dir)?.len();
        if len == 0 {
            return Ok(ScratchMap { map: MmapMut::map_anon(1).at(dir)?, _file: file, len: 0 });
        }
        // SAFETY: as in `new`: an unlinked file of this process, mapped once, outliving nothing
        // that reads it (the map owns the file).
        let map = unsafe { MmapMut::map_mut(&file) }.at(dir)?;
        Ok(ScratchMap { _file: file, map, len: len as usize })
    }

    /// The bytes, as records.
    pub fn slice_mut<T: bytemuck::Pod>(&mut self) -> &mut [T] {
        bytemuck::cast_slice_mut(&mut self.map[..self.len])
    }

    pub fn slice<T: bytemuck::Pod>(&self) -> &[T] {
        bytemuck::cast_slice(&self.map[..self.len])
    }
}

/// A failed `set_len`; EFBIG (larger than the file system's largest file) says how large.
pub(crate) fn file_system_limit(e: std::io::Error, path: &Path, len: u64) -> Error {
    if e.raw_os_error() == Some(libc::EFBIG) {
        let problem =
            format!("{} is more than this file system allows in one file ({e})", crate::error::tib(len as u128));
        return Error::io(path, std::io::Error::new(e.kind(), problem));
    }
    Error::io(path, e)
}
