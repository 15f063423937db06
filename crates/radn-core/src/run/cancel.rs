//! Stopping a run from outside — Ctrl-C, SIGTERM, a host application's cancel button — without
//! leaving debris: a process-wide request that runs check between frames and between bands, so
//! that they end with [`Error::Cancelled`] and every temporary file, claim and scratch folder is
//! removed as it is dropped. Frames finished before the request stay; a resumed run skips them.

use std::sync::atomic::{AtomicBool, Ordering};

use crate::error::{Error, Result};

static REQUESTED: AtomicBool = AtomicBool::new(false);

/// Asks every run in this process to stop at its next check (safe from a signal handler).
pub fn request() {
    REQUESTED.store(true, Ordering::SeqCst);
}

/// Whether a stop was asked for.
pub fn requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}

/// Withdraws a request, so that a later run in the same process goes ahead (tests, hosts that
/// run several jobs).
pub fn clear() {
    REQUESTED.store(false, Ordering::SeqCst);
}

/// [`Error::Cancelled`] where a stop was asked for: the check a run makes between frames and
/// bands.
pub fn check() -> Result<()> {
    if requested() {
        Err(Error::Cancelled)
    } else {
        Ok(())
    }
}
