//! Shared by the fuzz targets: the readers take paths, so each input is written to a file in a
//! RAM-backed directory (/dev/shm where it exists) under the name the reader expects.

#![allow(dead_code, reason = "each user compiles its own subset of the helpers")]

use std::path::PathBuf;

pub fn input_file(name: &str, bytes: &[u8]) -> (tempfile::TempDir, PathBuf) {
    let base = if std::path::Path::new("/dev/shm").is_dir() { "/dev/shm" } else { "/tmp" };
    let dir = tempfile::tempdir_in(base).expect("a temporary directory");
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).expect("writing the input");
    (dir, path)
}

/// The terrain and meta-node headers end with an XXH3-64 of their first 248 bytes. A mutated
/// header would almost never pass it, and the fields behind it would go unfuzzed; so the target
/// stamps the right checksum on the input first (a wrong checksum is a one-line comparison).
pub fn with_header_checksum(data: &[u8]) -> Vec<u8> {
    let mut bytes = data.to_vec();
    if bytes.len() >= 256 {
        let sum = xxhash_rust::xxh3::xxh3_64(&bytes[..248]);
        bytes[248..256].copy_from_slice(&sum.to_le_bytes());
    }
    bytes
}

/// libFuzzer's -malloc_limit_mb needs a sanitizer's allocator hooks, and these targets are built
/// without one: this allocator enforces the limit itself. An allocation over [`MAX_ALLOCATION`]
/// (a reader sizing a buffer from a header it did not bound) aborts, which libFuzzer reports as
/// a crash with the input saved.
pub struct LimitedAlloc;

pub const MAX_ALLOCATION: usize = 256 << 20;

// SAFETY: every call is forwarded unchanged to the system allocator after a size check.
unsafe impl std::alloc::GlobalAlloc for LimitedAlloc {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        check(layout.size());
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { std::alloc::System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: std::alloc::Layout) -> *mut u8 {
        check(layout.size());
        // SAFETY: as above.
        unsafe { std::alloc::System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, new_size: usize) -> *mut u8 {
        check(new_size);
        // SAFETY: as above.
        unsafe { std::alloc::System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        // SAFETY: as above.
        unsafe { std::alloc::System.dealloc(ptr, layout) }
    }
}

fn check(size: usize) {
    if size > MAX_ALLOCATION {
        // No allocation here: print with a fixed buffer through libc.
        let msg = b"==fuzz== allocation over the limit (256 MiB)\n";
        // SAFETY: writes a static buffer to stderr.
        unsafe { libc_write(2, msg.as_ptr(), msg.len()) };
        std::process::abort();
    }
}

extern "C" {
    #[link_name = "write"]
    fn libc_write(fd: i32, buf: *const u8, count: usize) -> isize;
}

#[global_allocator]
static ALLOCATOR: LimitedAlloc = LimitedAlloc;
