//! Cooperative cancellation: the binary's Ctrl-C handler raises a flag that long loops check, so
//! an interrupted conversion unwinds normally and removes its temporary files.

use std::sync::atomic::{AtomicBool, Ordering};

use crate::error::{Error, Result};

static CANCELLED: AtomicBool = AtomicBool::new(false);

/// Asks every running operation to stop at its next check.
pub fn request() {
    CANCELLED.store(true, Ordering::Relaxed);
}

/// `Err(Error::Interrupted)` once cancellation was requested.
#[inline]
pub fn check() -> Result<()> {
    if CANCELLED.load(Ordering::Relaxed) {
        Err(Error::Interrupted)
    } else {
        Ok(())
    }
}
