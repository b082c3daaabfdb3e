//! Process and file-system plumbing shared by every stage: outputs replaced atomically,
//! cancellation, progress bars, memory and page-fault figures, the SIGBUS report, file-backed
//! scratch memory.

pub mod atomic_file;
pub mod cancel;
pub mod mem;
pub mod progress;
pub mod scratch;
pub mod sigbus;
