//! A mapped file truncated (or made unreadable) by another process while we read it raises SIGBUS
//! on the next access past its new end. The kernel gives no way to refuse the truncation, and
//! checking before every access would cost the hot loops, so the binary turns the signal into
//! the same one-line error as any other bad input: `relief: FILE: …` and exit status 1, instead
//! of a core dump. Library users who want this call [`install`] once; every validated mapping
//! ([`crate::format::terrain::TerrainFile`], the VDT and meta-node files) calls [`note_mapped`].
//!
//! The handler only reads one pointer and calls `write(2)` and `_exit(2)`, which are
//! async-signal-safe. Output files are written to a temporary name and renamed, so exiting here
//! never leaves a half-written output behind.

use std::path::Path;
use std::sync::atomic::{AtomicPtr, AtomicUsize, Ordering};

/// The most recently mapped file's path (leaked: the handler may read it at any moment, so a
/// replaced path is never freed; a few hundred bytes per file opened).
static PATH: AtomicPtr<u8> = AtomicPtr::new(std::ptr::null_mut());
static PATH_LEN: AtomicUsize = AtomicUsize::new(0);

/// Records `path` as the file a SIGBUS most likely concerns.
pub fn note_mapped(path: &Path) {
    let bytes: &'static mut [u8] = Box::leak(path.as_os_str().as_encoded_bytes().to_vec().into_boxed_slice());
    // Length first to 0, then pointer, then length: the handler reads a consistent pair or none.
    PATH_LEN.store(0, Ordering::SeqCst);
    PATH.store(bytes.as_mut_ptr(), Ordering::SeqCst);
    PATH_LEN.store(bytes.len(), Ordering::SeqCst);
}

#[cfg(feature = "native")]
extern "C" fn on_sigbus(_signal: libc::c_int) {
    fn put(bytes: &[u8]) {
        // SAFETY: write(2) on stderr with a valid buffer; async-signal-safe.
        unsafe { libc::write(2, bytes.as_ptr().cast(), bytes.len()) };
    }
    put(b"relief: ");
    let len = PATH_LEN.load(Ordering::SeqCst);
    let ptr = PATH.load(Ordering::SeqCst);
    if !ptr.is_null() && len > 0 {
        // SAFETY: `ptr` points to `len` bytes leaked in `note_mapped`, never freed.
        put(unsafe { std::slice::from_raw_parts(ptr, len) });
        put(b": ");
    }
    put(b"the mapped file was truncated or became unreadable while in use (SIGBUS)\n");
    // SAFETY: _exit is async-signal-safe and skips destructors, which must not run here.
    unsafe { libc::_exit(1) };
}

/// Installs the SIGBUS handler (process-wide; for binaries).
pub fn install() {
    // Without an operating system there is no signal to catch.
    #[cfg(feature = "native")]
    // SAFETY: a zeroed sigaction with a plain handler and an empty mask is valid; the handler
    // is async-signal-safe (see the module documentation).
    unsafe {
        let mut action: libc::sigaction = std::mem::zeroed();
        action.sa_sigaction = on_sigbus as extern "C" fn(libc::c_int) as usize;
        libc::sigemptyset(&mut action.sa_mask);
        libc::sigaction(libc::SIGBUS, &action, std::ptr::null_mut());
    }
}
