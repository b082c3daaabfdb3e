//! The emulated device of [`super::device`] (ARCHITECTURE.md, "Device emulation"): a FUSE file
//! system of relief's own serving one file, every read request waiting as the device would.
//! Test equipment for the layout experiments, built with the `device` feature (it links `fuser`).

use std::ffi::OsStr;
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use fuser::{
    Config, Errno, FileAttr, FileHandle, FileType, Filesystem, FopenFlags, INodeNo, LockOwner, MountOption, OpenFlags,
    ReplyAttr, ReplyData, ReplyEntry, ReplyOpen, Request,
};

use super::device::{warm, DeviceSpec, DeviceStats};
use super::source::{MappedFile, ReadFile, Source, SourceKind};
use crate::error::{Error, IoContext, Result};

/// A source reading a device's served copy of a file (see [`super::open_on`]).
pub(super) struct OnDevice {
    // Declared first, so dropped first: the served file is closed (and unmapped) before the
    // device's file system is unmounted.
    inner: Box<dyn Source>,
    mount: DeviceMount,
}

impl OnDevice {
    /// `path` served through a device of `spec`, mapped or read as `kind` says.
    pub(super) fn open(path: &Path, kind: SourceKind, spec: DeviceSpec) -> Result<OnDevice> {
        let mount = DeviceMount::new(path, spec)?;
        let inner: Box<dyn Source> = match kind {
            SourceKind::Map => Box::new(MappedFile::open_as(mount.path(), path)?),
            SourceKind::Read => Box::new(ReadFile::open_as(mount.path(), path)?),
        };
        Ok(OnDevice { inner, mount })
    }
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
    fn device_stats(&self) -> Option<DeviceStats> {
        Some(self.mount.stats())
    }
    fn device_spec(&self) -> Option<DeviceSpec> {
        Some(self.mount.spec())
    }
    fn map_runs(&self, runs: &[(u64, u64, u64)], logical_len: u64) -> Result<Option<super::source::RunMap>> {
        self.inner.map_runs(runs, logical_len)
    }
}

#[derive(Default)]
struct Counters {
    requests: AtomicU64,
    bytes: AtomicU64,
    device_ns: AtomicU64,
    slow_backing: AtomicU64,
}

impl Counters {
    fn get(&self) -> DeviceStats {
        DeviceStats {
            requests: self.requests.load(Ordering::Relaxed),
            bytes: self.bytes.load(Ordering::Relaxed),
            device_s: self.device_ns.load(Ordering::Relaxed) as f64 * 1e-9,
            slow_backing: self.slow_backing.load(Ordering::Relaxed),
        }
    }
}

const ROOT: u64 = 1;
const FILE: u64 = 2;
/// How long the kernel may keep the names and attributes: the file never changes while mounted.
const TTL: Duration = Duration::from_secs(3600);

/// The file system: one directory holding one read-only file, the backing file's bytes.
struct DeviceFs {
    backing: File,
    name: std::ffi::OsString,
    len: u64,
    spec: DeviceSpec,
    counters: Arc<Counters>,
    mtime: SystemTime,
}

impl DeviceFs {
    fn attr(&self, ino: u64) -> FileAttr {
        let (kind, perm, size, nlink) =
            if ino == ROOT { (FileType::Directory, 0o555, 0, 2) } else { (FileType::RegularFile, 0o444, self.len, 1) };
        FileAttr {
            ino: INodeNo(ino),
            size,
            blocks: size.div_ceil(512),
            atime: self.mtime,
            mtime: self.mtime,
            ctime: self.mtime,
            crtime: self.mtime,
            kind,
            perm,
            nlink,
            // SAFETY: getuid cannot fail and touches no memory.
            uid: unsafe { libc::getuid() },
            // SAFETY: as getuid.
            gid: unsafe { libc::getgid() },
            rdev: 0,
            blksize: 4096,
            flags: 0,
        }
    }
}

impl Filesystem for DeviceFs {
    fn lookup(&self, _req: &Request, parent: INodeNo, name: &OsStr, reply: ReplyEntry) {
        if parent.0 == ROOT && name == self.name.as_os_str() {
            reply.entry(&TTL, &self.attr(FILE), fuser::Generation(0));
        } else {
            reply.error(Errno::ENOENT);
        }
    }

    fn getattr(&self, _req: &Request, ino: INodeNo, _fh: Option<FileHandle>, reply: ReplyAttr) {
        match ino.0 {
            ROOT | FILE => reply.attr(&TTL, &self.attr(ino.0)),
            _ => reply.error(Errno::ENOENT),
        }
    }

    fn open(&self, _req: &Request, ino: INodeNo, _flags: OpenFlags, reply: ReplyOpen) {
        if ino.0 == FILE {
            // Keep the page cache across opens: the file never changes while mounted.
            reply.opened(FileHandle(0), FopenFlags::FOPEN_KEEP_CACHE);
        } else {
            reply.error(Errno::EISDIR);
        }
    }

    fn read(
        &self,
        _req: &Request,
        ino: INodeNo,
        _fh: FileHandle,
        offset: u64,
        size: u32,
        _flags: OpenFlags,
        _lock_owner: Option<LockOwner>,
        reply: ReplyData,
    ) {
        if ino.0 != FILE {
            return reply.error(Errno::EISDIR);
        }
        let start = Instant::now();
        let bytes = (size as u64).min(self.len.saturating_sub(offset));
        let mut buf = vec![0u8; bytes as usize];
        let read = self.backing.read_exact_at(&mut buf, offset);
        let service = self.spec.service_time(size as u64);
        let spent = start.elapsed();
        if spent < service {
            sleep_until(start + service);
        } else if service > Duration::ZERO {
            self.counters.slow_backing.fetch_add(1, Ordering::Relaxed);
        }
        let c = &self.counters;
        c.requests.fetch_add(1, Ordering::Relaxed);
        c.bytes.fetch_add(size as u64, Ordering::Relaxed);
        c.device_ns.fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
        match read {
            Ok(()) => reply.data(&buf),
            Err(_) => reply.error(Errno::EIO),
        }
    }
}

/// Sleeps until `deadline`, to within a few microseconds: the thread's timer slack is set to 1 ns
/// first, as a device's completion does not come 50 µs late (the default slack).
fn sleep_until(deadline: Instant) {
    thread_local!(static PRECISE: std::cell::Cell<bool> = const { std::cell::Cell::new(false) });
    if !PRECISE.get() {
        // SAFETY: PR_SET_TIMERSLACK takes an integer and changes only this thread's timers.
        unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong) };
        PRECISE.set(true);
    }
    loop {
        let now = Instant::now();
        if now >= deadline {
            return;
        }
        std::thread::sleep(deadline - now);
    }
}

/// A file served through an emulated device: [`Self::path`] is the served copy, to be opened
/// (mapped or read) as the original would be; unmounted when dropped (after whatever opened the
/// served path has closed it, which the owner's field order ensures).
pub struct DeviceMount {
    served: PathBuf,
    spec: DeviceSpec,
    counters: Arc<Counters>,
    // Unmounts on drop, before the mount point is removed.
    session: Option<fuser::BackgroundSession>,
    _dir: tempfile::TempDir,
}

impl DeviceMount {
    /// Mounts a FUSE file system serving `path` (a regular local file) through a device of `spec`.
    /// The backing file is read once first, so that its own reads come from the page cache.
    /// Needs the right to mount (root, or FUSE's `fusermount3`); otherwise a one-line error.
    pub fn new(path: &Path, spec: DeviceSpec) -> Result<DeviceMount> {
        let backing = File::open(path).at(path)?;
        let meta = backing.metadata().at(path)?;
        if !meta.is_file() {
            return Err(Error::InvalidArgument(format!("{}: an emulated device needs a regular file", path.display())));
        }
        let name = path
            .file_name()
            .filter(|n| !n.is_empty())
            .ok_or_else(|| Error::InvalidArgument(format!("{}: no file name", path.display())))?
            .to_os_string();
        warm(&backing, meta.len()).at(path)?;
        reap_stale_mounts();
        let prefix = format!("{MOUNT_PREFIX}{}-", std::process::id());
        let dir = tempfile::Builder::new().prefix(&prefix).tempdir().at(path)?;
        let counters = Arc::new(Counters::default());
        let fs = DeviceFs {
            backing,
            name: name.clone(),
            len: meta.len(),
            spec,
            counters: Arc::clone(&counters),
            mtime: meta.modified().unwrap_or(SystemTime::UNIX_EPOCH),
        };
        let mut config = Config::default();
        config.mount_options =
            vec![MountOption::RO, MountOption::FSName("relief-device".into()), MountOption::Subtype("relief".into())];
        config.n_threads = Some(spec.queue_depth as usize);
        config.clone_fd = spec.queue_depth > 1;
        let session = fuser::spawn_mount(fs, dir.path(), &config).map_err(|e| {
            Error::InvalidArgument(format!(
                "{}: cannot emulate a device: mounting a FUSE file system at {} failed: {e} (needs /dev/fuse and \
                 the right to mount, e.g. root)",
                path.display(),
                dir.path().display()
            ))
        })?;
        let served = dir.path().join(&name);
        // Open and close the served file once while the server runs: the kernel sends FLUSH on a
        // close, the server answers "not implemented", and the kernel sends no more. Otherwise a
        // process killed (say by its memory cap) while the file is open would send FLUSH from its
        // exit to its own server, already gone, and never finish exiting.
        drop(File::open(&served).at(&served)?);
        Ok(DeviceMount { served, spec, counters, session: Some(session), _dir: dir })
    }

    /// The served copy of the file.
    pub fn path(&self) -> &Path {
        &self.served
    }

    pub fn spec(&self) -> DeviceSpec {
        self.spec
    }

    /// What the device has served so far.
    pub fn stats(&self) -> DeviceStats {
        self.counters.get()
    }
}

impl Drop for DeviceMount {
    fn drop(&mut self) {
        if let Some(session) = self.session.take() {
            // Unmount and wait for the event loops to end; nothing to report on failure. A
            // process killed before this runs leaves its mount behind, disconnected; the next
            // mount reaps it (`reap_stale_mounts`).
            let _ = session.umount_and_join();
        }
    }
}

/// The mount points' name prefix, in the temporary directory.
const MOUNT_PREFIX: &str = "relief-device-";

/// Detaches and removes the mounts of relief devices whose process is gone (a process killed by a
/// memory cap or a signal cannot unmount; its mount point then answers "transport endpoint is not
/// connected" until unmounted). A mount point is named after its process
/// (`relief-device-PID-…`), and only mounts whose process no longer exists are touched: looking
/// into a mount whose server is alive but busy, or exiting, could block.
fn reap_stale_mounts() {
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name
            .to_str()
            .and_then(|n| n.strip_prefix(MOUNT_PREFIX))
            .and_then(|rest| rest.split_once('-'))
            .and_then(|(pid, _)| pid.parse::<u32>().ok())
        else {
            continue;
        };
        if pid == std::process::id() || Path::new(&format!("/proc/{pid}")).exists() {
            continue;
        }
        let dir = entry.path();
        let Ok(c_path) = std::ffi::CString::new(dir.as_os_str().as_encoded_bytes()) else { continue };
        // SAFETY: umount2 reads the NUL-terminated path it is given; MNT_DETACH only unlinks the
        // dead mount from the tree.
        // Not mounted any more (EINVAL) is fine too: then only the directory is left.
        unsafe { libc::umount2(c_path.as_ptr(), libc::MNT_DETACH) };
        let _ = std::fs::remove_dir(&dir);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pager::open_on;
    use crate::pager::source::SourceKind;

    const PAGE: usize = 4096;

    fn file_of(pages: usize) -> (tempfile::TempDir, PathBuf, Vec<u8>) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("device.bin");
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let bytes: Vec<u8> = (0..pages * PAGE)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                s as u8
            })
            .collect();
        std::fs::write(&path, &bytes).unwrap();
        (dir, path, bytes)
    }

    fn majors() -> i64 {
        // SAFETY: getrusage fills the struct it is given.
        let mut u: libc::rusage = unsafe { std::mem::zeroed() };
        // SAFETY: as above.
        unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
        u.ru_majflt
    }

    /// N cold reads of distinct pages, positioned or by page fault: exactly N requests, each
    /// waited out (N × latency of device time and of wall time at queue depth 1), the bytes
    /// unchanged; read again, they come from the page cache and cost nothing.
    #[test]
    fn every_cold_read_is_one_request_charged_the_latency() {
        let (_dir, path, bytes) = file_of(96);
        let latency = Duration::from_millis(3);
        let spec = DeviceSpec::new(3.0, 1, None).unwrap();
        for kind in [SourceKind::Read, SourceKind::Map] {
            let source = open_on(&path, kind, Some(spec)).unwrap();
            assert_eq!((source.path(), source.len(), source.kind()), (path.as_path(), bytes.len() as u64, kind));
            source.advise_random().unwrap();
            source.evict().unwrap();
            let pages: Vec<usize> = (0..24).map(|k| (k * 37) % 96).collect();
            for pass in 0..2 {
                let (before, majors_before, t) = (source.device_stats().unwrap(), majors(), Instant::now());
                for &p in &pages {
                    let at = p * PAGE + 100;
                    let got = match source.mapped() {
                        Some(m) => m[at..at + 64].to_vec(),
                        None => {
                            let mut b = vec![0u8; 64];
                            source.read_at(at as u64, &mut b).unwrap();
                            b
                        }
                    };
                    assert_eq!(got, bytes[at..at + 64], "{kind:?} page {p}");
                }
                let (after, elapsed) = (source.device_stats().unwrap(), t.elapsed());
                let requests = after.requests - before.requests;
                if pass == 0 {
                    let n = pages.len() as u32;
                    assert_eq!(requests, n as u64, "{kind:?}: one request per cold page");
                    assert_eq!(after.bytes - before.bytes, n as u64 * PAGE as u64, "{kind:?}");
                    assert!(after.device_s - before.device_s >= (latency * n).as_secs_f64(), "{kind:?} {after:?}");
                    assert!(elapsed >= latency * n, "{kind:?}: {elapsed:?} for {n} requests");
                    if kind == SourceKind::Map {
                        assert!(majors() - majors_before >= n as i64, "{kind:?}: the faults are major");
                    }
                } else {
                    assert_eq!(requests, 0, "{kind:?}: a warm page costs no request");
                }
            }
        }
    }

    /// At queue depth 4, four threads' requests are served at once: the wall time is about a
    /// quarter of the device time; at depth 1 it is all of it.
    #[test]
    fn the_queue_depth_serves_requests_at_once() {
        let (_dir, path, _) = file_of(64);
        for depth in [1u32, 4] {
            let source = open_on(&path, SourceKind::Read, Some(DeviceSpec::new(5.0, depth, None).unwrap())).unwrap();
            source.advise_random().unwrap();
            source.evict().unwrap();
            let t = Instant::now();
            std::thread::scope(|s| {
                for k in 0..4 {
                    let source = &source;
                    s.spawn(move || {
                        let mut b = [0u8; 8];
                        for p in 0..8 {
                            source.read_at(((k * 16 + p) * PAGE) as u64, &mut b).unwrap();
                        }
                    });
                }
            });
            let (elapsed, stats) = (t.elapsed().as_secs_f64(), source.device_stats().unwrap());
            assert_eq!(stats.requests, 32, "depth {depth}");
            assert!(stats.device_s >= 32.0 * 0.005, "depth {depth}: {stats:?}");
            let overlap = stats.device_s / elapsed;
            if depth == 1 {
                assert!(overlap < 1.05, "depth 1 serves one at a time: overlap {overlap:.2}");
            } else {
                assert!(overlap > 2.5, "depth 4 serves four at a time: overlap {overlap:.2}");
            }
        }
    }

    /// Not a test on its own: run by `a_killed_server_s_mount_is_reaped` in a child process,
    /// it mounts a device, opens the served file, prints the mount point and dies without
    /// unmounting or closing.
    #[test]
    #[ignore]
    fn mount_and_die() {
        if std::env::var_os("RELIEF_DEVICE_DIE").is_none() {
            return;
        }
        let (_dir, path, _) = file_of(1);
        let mount = DeviceMount::new(&path, DeviceSpec::new(0.0, 1, None).unwrap()).unwrap();
        let _open = File::open(mount.path()).unwrap();
        println!("MOUNT {}", mount.path().parent().unwrap().display());
        std::process::abort();
    }

    /// A process killed while its device is mounted and its file open finishes exiting (no
    /// FLUSH is sent to its own server, gone by then) and leaves a disconnected mount behind; the
    /// next device mounted detaches and removes it.
    #[test]
    fn a_killed_server_s_mount_is_reaped() {
        use std::io::Read;
        let mut child = std::process::Command::new(std::env::current_exe().unwrap())
            .args(["--exact", "pager::fuse::tests::mount_and_die", "--ignored", "--nocapture"])
            .env("RELIEF_DEVICE_DIE", "1")
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let deadline = std::time::Instant::now() + Duration::from_secs(60);
        let status = loop {
            if let Some(status) = child.try_wait().unwrap() {
                break status;
            }
            assert!(std::time::Instant::now() < deadline, "the killed child never finished exiting");
            std::thread::sleep(Duration::from_millis(20));
        };
        assert!(!status.success(), "the child aborts");
        let mut stdout = String::new();
        child.stdout.take().unwrap().read_to_string(&mut stdout).unwrap();
        let stale = PathBuf::from(
            stdout.lines().find_map(|l| l.strip_prefix("MOUNT ")).unwrap_or_else(|| panic!("child said: {stdout}")),
        );
        let err = std::fs::metadata(&stale).unwrap_err();
        assert_eq!(err.raw_os_error(), Some(libc::ENOTCONN), "{}: {err}", stale.display());
        let (_dir, path, _) = file_of(1);
        let _live = DeviceMount::new(&path, DeviceSpec::new(0.0, 1, None).unwrap()).unwrap();
        // A disconnected mount point keeps its directory entry: gone means unmounted and removed.
        let listed = std::fs::read_dir(stale.parent().unwrap()).unwrap().flatten().any(|e| e.path() == stale);
        assert!(!listed, "{} was not reaped", stale.display());
    }

    #[test]
    fn the_spec_refuses_what_no_device_has() {
        assert!(DeviceSpec::new(8.0, 1, None).is_ok());
        for (ms, q, r) in [(-1.0, 1, None), (f64::NAN, 1, None), (1.0, 0, None), (1.0, 65, None), (1.0, 1, Some(0.0))] {
            assert!(DeviceSpec::new(ms, q, r).is_err(), "{ms} {q} {r:?}");
        }
        let s = DeviceSpec::new(2.0, 1, Some(100.0)).unwrap();
        // 2 ms + 1 MB at 100 MB/s.
        assert_eq!(s.service_time(1_000_000), Duration::from_secs_f64(0.012));
    }
}
