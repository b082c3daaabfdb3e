//! The one place relief maps a file into memory. Terrain, VDT, meta-node and page files are all
//! opened through their own validating constructor, and each of those maps through
//! [`map_read_only`], so the safety argument is made once.

use std::fs::File;
use std::path::Path;

use memmap2::Mmap;

use crate::error::{Error, IoContext, Result};

/// The most bytes relief maps at once: 128 TiB, the user address space of x86-64 and AArch64
/// with 48-bit virtual addresses. Terrain files are mapped whole, and a conversion maps its
/// scratch grids whole, so a grid needing more is refused before anything is written.
pub const MAX_MAPPED_BYTES: u64 = 1 << 47;

/// Maps `file` (opened from `path`, `file_len` bytes long by its metadata) read-only, records
/// `path` for the SIGBUS report, and checks the map covers the whole file.
///
/// # Safety (why the `unsafe` inside is sound)
/// The map is read-only and owned by the caller's file value, which also holds `file` open for
/// the map's lifetime. relief never writes any of its files in place: every writer builds a
/// temporary file and renames it over the target, so an existing mapping keeps the old inode.
/// Only another process truncating or rewriting the file while it is mapped can fault a read
/// (SIGBUS, reported with the path by [`crate::sys::sigbus`]) or change what is read; callers
/// validate every size and offset they use against `file_len`, so well-formed reads stay in
/// bounds of the map.
pub(crate) fn map_read_only(path: &Path, file: &File, file_len: u64) -> Result<Mmap> {
    // SAFETY: see the function's documentation above.
    let map = unsafe { Mmap::map(file) }.at(path)?;
    crate::sys::sigbus::note_mapped(path);
    if map.len() as u64 != file_len {
        return Err(Error::Truncated { path: path.into(), expected: file_len, found: map.len() as u64 });
    }
    Ok(map)
}
