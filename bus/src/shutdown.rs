//! Orderly shutdown on SIGINT/SIGTERM/SIGHUP for processes on the bus.
//!
//! Killing a bus process without running its destructors leaves its shared-memory segments and
//! node records behind until another process cleans up after the dead node. Loops call
//! [`requested`] instead, return, and let every port drop normally.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

static FLAG: OnceLock<Arc<AtomicBool>> = OnceLock::new();

/// Installs SIGINT, SIGTERM and SIGHUP (terminal closed) handlers that only set a flag
/// (async-signal-safe). Idempotent.
/// A second signal after the first still only sets the flag; use SIGKILL to force.
pub fn install() -> std::io::Result<()> {
    let flag = FLAG.get_or_init(|| Arc::new(AtomicBool::new(false)));
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    for sig in [SIGINT, SIGTERM, SIGHUP] {
        signal_hook::flag::register(sig, Arc::clone(flag))?;
    }
    Ok(())
}

/// Whether SIGINT, SIGTERM or SIGHUP arrived since [`install`] (false if it was never installed).
#[inline]
pub fn requested() -> bool {
    FLAG.get().is_some_and(|f| f.load(Ordering::Relaxed))
}

/// Sets the flag as a signal would (tests, or a supervisor thread asking the loop to stop).
pub fn request() {
    FLAG.get_or_init(|| Arc::new(AtomicBool::new(false)))
        .store(true, Ordering::Relaxed);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sigterm_sets_the_flag_instead_of_killing() {
        install().unwrap();
        assert!(!requested());
        // SAFETY: raising a signal we installed a handler for, in our own process.
        unsafe { libc::raise(libc::SIGTERM) };
        assert!(requested());
    }
}
