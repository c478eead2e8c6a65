//! Ctrl-C / SIGTERM: long-running commands poll [`requested`] and wind down cleanly (a recording
//! is finalised, a gateway prints its counters) instead of dying mid-write.

use std::sync::atomic::{AtomicBool, Ordering};

static STOP: AtomicBool = AtomicBool::new(false);

/// Installs the SIGINT/SIGTERM/SIGHUP handler (once per process; later calls are no-ops).
pub fn install() {
    // Err only when a handler is already installed: ours, from an earlier call.
    let _ = ctrlc::set_handler(|| STOP.store(true, Ordering::SeqCst));
}

/// Whether a stop was requested.
pub fn requested() -> bool {
    STOP.load(Ordering::SeqCst)
}
