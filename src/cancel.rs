//! Cooperative cancellation of a running computation: a caller that cannot deliver a signal
//! to the computing thread (the Python package, whose Ctrl-C reaches only the interpreter's
//! main thread) calls [`request`]; the pipeline calls [`check`] between its steps and in its
//! long loops, which ends the computation with [`Error::Cancelled`] within a step. The command
//! line needs none of this (SIGINT ends the process).
//!
//! One flag per process: a request cancels every computation in progress (the Python package
//! clears it when the interrupted call has returned).

use crate::error::{Error, Result};
use std::sync::atomic::{AtomicBool, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);

/// Ask every computation in progress to stop at its next [`check`].
pub fn request() {
    REQUESTED.store(true, Ordering::SeqCst);
}

/// Withdraw a request (after the interrupted computation returned).
pub fn clear() {
    REQUESTED.store(false, Ordering::SeqCst);
}

/// Whether a stop was requested.
pub fn requested() -> bool {
    REQUESTED.load(Ordering::Relaxed)
}

/// `Err(Error::Cancelled)` when a stop was requested: called between steps and in long loops.
pub fn check() -> Result<()> {
    if requested() {
        Err(Error::Cancelled)
    } else {
        Ok(())
    }
}
