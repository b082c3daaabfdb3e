//! A file whose bytes the host hands over: the web viewer's source, where every read of the
//! network is an asynchronous `fetch` the core cannot wait for (ARCHITECTURE.md, "The web
//! viewer"). The host fetches byte ranges (the opening range, then what
//! [`crate::refine::progressive::Progressive::take_request`] asks for) and [`HostedFile::insert`]s
//! them; reads of pages that are here succeed, reads of any other page are an error naming the
//! file, and [`Source::resident_pages`] says which are here, so progressive refinement only reads
//! what arrived. Nothing here needs an operating system: the same type is tested natively.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::RwLock;

use super::source::{check_range, RemoteStats, Source, SourceKind, PAGE_BYTES};
use crate::error::{Error, Result};

/// A file of known length, its pages ([`PAGE_BYTES`]) filled in by the host as they arrive.
pub struct HostedFile {
    path: PathBuf,
    len: u64,
    /// One slot per page; a page once here stays (a terrain file is never rewritten in place).
    pages: RwLock<Vec<Option<Box<[u8]>>>>,
    requests: AtomicU64,
    bytes: AtomicU64,
}

impl HostedFile {
    /// An empty file of `len` bytes named `path` (its URL) in errors.
    pub fn new(path: &Path, len: u64) -> HostedFile {
        HostedFile {
            path: path.to_path_buf(),
            len,
            pages: RwLock::new((0..len.div_ceil(PAGE_BYTES)).map(|_| None).collect()),
            requests: AtomicU64::new(0),
            bytes: AtomicU64::new(0),
        }
    }

    /// Takes the bytes of one answered request at `offset`: a page boundary, and whole pages
    /// except at the file's end. Counted as one request of `bytes.len()` body bytes.
    pub fn insert(&self, offset: u64, bytes: &[u8]) -> Result<()> {
        let end = offset.checked_add(bytes.len() as u64).filter(|&e| e <= self.len);
        let whole = (bytes.len() as u64).is_multiple_of(PAGE_BYTES) || end == Some(self.len);
        if !offset.is_multiple_of(PAGE_BYTES) || end.is_none() || !whole {
            return Err(Error::remote(
                &self.path.display().to_string(),
                format!(
                    "{} bytes at {offset} are not whole pages of a {}-byte file (the server answered another range?)",
                    bytes.len(),
                    self.len
                ),
            ));
        }
        self.requests.fetch_add(1, Ordering::Relaxed);
        self.bytes.fetch_add(bytes.len() as u64, Ordering::Relaxed);
        let mut pages = self.pages.write().unwrap_or_else(|p| p.into_inner());
        for (k, chunk) in bytes.chunks(PAGE_BYTES as usize).enumerate() {
            if let Some(slot) = pages.get_mut((offset / PAGE_BYTES) as usize + k) {
                if slot.is_none() {
                    *slot = Some(chunk.into());
                }
            }
        }
        Ok(())
    }

    /// Pages here.
    pub fn present_pages(&self) -> u64 {
        self.pages.read().unwrap_or_else(|p| p.into_inner()).iter().filter(|p| p.is_some()).count() as u64
    }
}

impl Source for HostedFile {
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
        let pages = self.pages.read().unwrap_or_else(|p| p.into_inner());
        let mut at = offset;
        let mut out = &mut buf[..];
        while !out.is_empty() {
            let p = at / PAGE_BYTES;
            let Some(Some(page)) = pages.get(p as usize) else {
                return Err(Error::remote(
                    &self.path.display().to_string(),
                    format!("page {p} (bytes {}..) was read before it arrived", p * PAGE_BYTES),
                ));
            };
            let k = (at % PAGE_BYTES) as usize;
            let n = out.len().min(page.len().saturating_sub(k));
            if n == 0 {
                return Err(Error::Truncated { path: self.path.clone(), expected: at + 1, found: self.len });
            }
            out[..n].copy_from_slice(&page[k..k + n]);
            out = &mut out[n..];
            at += n as u64;
        }
        Ok(())
    }

    fn advise_random(&self) -> Result<()> {
        Ok(())
    }

    fn evict(&self) -> Result<()> {
        Ok(())
    }

    fn resident_pages(&self, first: u64, end: u64) -> Result<Vec<bool>> {
        let pages = self.pages.read().unwrap_or_else(|p| p.into_inner());
        Ok((first..end).map(|p| matches!(pages.get(p as usize), Some(Some(_)))).collect())
    }

    fn network(&self) -> Option<RemoteStats> {
        Some(RemoteStats {
            requests: self.requests.load(Ordering::Relaxed),
            bytes: self.bytes.load(Ordering::Relaxed),
            retries: 0,
            cache_hit_pages: 0,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_what_arrived_and_names_the_file_for_what_did_not() {
        let bytes: Vec<u8> = (0..10_000u32).map(|i| (i * 7 % 251) as u8).collect();
        let f = HostedFile::new(Path::new("http://x/t.relief"), bytes.len() as u64);
        assert_eq!(f.resident_pages(0, 3).unwrap(), [false, false, false]);
        f.insert(0, &bytes[..4096]).unwrap();
        f.insert(8192, &bytes[8192..]).unwrap();
        assert_eq!(f.resident_pages(0, 3).unwrap(), [true, false, true]);
        let mut buf = [0u8; 100];
        f.read_at(8200, &mut buf).unwrap();
        assert_eq!(&buf[..], &bytes[8200..8300]);
        let e = f.read_at(4000, &mut buf).unwrap_err().to_string();
        assert!(e.contains("http://x/t.relief") && e.contains("page 1"), "{e}");
        f.insert(4096, &bytes[4096..8192]).unwrap();
        f.read_at(4000, &mut buf).unwrap();
        assert_eq!(&buf[..], &bytes[4000..4100]);
        let e = f.insert(100, &bytes[100..200]).unwrap_err().to_string();
        assert!(e.contains("not whole pages"), "{e}");
        let e = f.insert(4096, &bytes[4096..5000]).unwrap_err().to_string();
        assert!(e.contains("not whole pages"), "{e}");
        assert_eq!(f.network().map(|n| (n.requests, n.bytes)), Some((3, 10_000)));
        let e = f.read_at(9990, &mut buf).unwrap_err().to_string();
        assert!(e.contains("truncated"), "{e}");
    }
}
