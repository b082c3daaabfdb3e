//! Process and file-system plumbing shared by every stage: outputs replaced atomically,
//! cancellation, progress bars, memory and page-fault figures, the SIGBUS report, file-backed
//! scratch memory.

pub mod atomic_file;
pub mod cancel;
pub mod mem;
pub mod progress;
#[cfg(feature = "native")]
pub mod scratch;
pub mod sigbus;

/// A hint to bring the cache line at `at` into the cache. Never reads or faults, so any address
/// (past the end of an array, say) is sound; where the target has no such hint it does nothing.
#[inline(always)]
pub fn prefetch<T>(at: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: `_mm_prefetch` does not dereference its argument (PREFETCHT0 is a hint that cannot
    // fault), so any address is sound.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(at.cast())
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = at;
}
