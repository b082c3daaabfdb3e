//! What the operating system counts and controls for the experiments: dropping a file from the
//! page cache, a cgroup v1 memory cap on this process, and the bytes this process had read from
//! storage.

use std::path::Path;

use crate::error::{Error, Result};

/// Evicts `path` from the OS page cache (`posix_fadvise(DONTNEED)`), so the next reads fault.
/// Pages still mapped by a live mapping stay: drop the mapping first.
pub fn drop_from_page_cache(path: &Path) -> Result<()> {
    #[cfg(not(feature = "native"))]
    return Err(Error::InvalidArgument(format!("{}: no page cache to drop in this build", path.display())));
    #[cfg(feature = "native")]
    {
        use std::os::unix::io::AsRawFd;
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        // SAFETY: plain system call on a file descriptor we own for the duration of the call.
        let rc = unsafe { libc::posix_fadvise(file.as_raw_fd(), 0, 0, libc::POSIX_FADV_DONTNEED) };
        if rc != 0 {
            return Err(Error::io(path, std::io::Error::from_raw_os_error(rc)));
        }
        Ok(())
    }
}

/// A cgroup v1 memory limit on this process while the value lives, so that a cold run's page
/// cache is about as small as the model's. Charges made before the move stay where
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

/// Bytes this process (all its threads) has caused to be read from storage so far: `read_bytes`
/// of `/proc/self/io`, which counts page-fault reads of mappings as well as `read`/`pread` that
/// missed the page cache. `None` where the kernel does not provide it.
pub fn storage_read_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/io").ok()?;
    s.lines().find_map(|l| l.strip_prefix("read_bytes:")).and_then(|v| v.trim().parse().ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn storage_reads_count_a_cold_read_of_a_file() {
        let Some(before) = storage_read_bytes() else { return };
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.bin");
        let f = std::fs::File::create(&path).unwrap();
        std::io::Write::write_all(&mut &f, &vec![7u8; 1 << 20]).unwrap();
        f.sync_all().unwrap();
        drop_from_page_cache(&path).unwrap();
        assert_eq!(std::fs::read(&path).unwrap().len(), 1 << 20);
        let read = storage_read_bytes().unwrap() - before;
        // tmpfs has no storage below it: nothing to count there.
        if read > 0 {
            assert!(read >= 1 << 20, "{read} bytes counted for a 1 MiB cold read");
        }
    }
}
