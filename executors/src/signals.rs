//! SIGINT/SIGTERM as a stop request, without signal handlers.
//!
//! The signals are blocked in the calling thread (and so in every thread it spawns afterwards)
//! and a small thread takes them with `sigwait`. Nothing runs in signal context, no system call of
//! the real-time loop is interrupted, and a library that installs its own handlers later (iceoryx2
//! does so lazily) never sees these signals.

use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};
use std::sync::Arc;

use nix::sys::signal::{pthread_sigmask, SigSet, SigmaskHow, Signal};

/// A stop request shared between the signal thread and the loops that honour it.
#[derive(Debug, Clone, Default)]
pub struct Stop {
    flag: Arc<AtomicBool>,
    signal: Arc<AtomicI32>,
}

impl Stop {
    /// A request nobody has made yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Requests a stop (as if `signal` had arrived; 0 for a programmatic stop).
    pub fn request(&self, signal: i32) {
        let _ = self
            .signal
            .compare_exchange(0, signal, Ordering::Relaxed, Ordering::Relaxed);
        self.flag.store(true, Ordering::Release);
    }

    /// Whether a stop was requested.
    pub fn requested(&self) -> bool {
        self.flag.load(Ordering::Acquire)
    }

    /// The flag itself, for loops that poll an `AtomicBool`.
    pub fn flag(&self) -> &AtomicBool {
        &self.flag
    }

    /// The first signal that requested the stop (0 if none or programmatic).
    pub fn signal(&self) -> i32 {
        self.signal.load(Ordering::Relaxed)
    }
}

/// Blocks SIGINT and SIGTERM in the calling thread and starts the thread that turns them into
/// `stop` requests. Call it first in `main`, before any other thread exists. A second signal
/// after the first one ends the process at once with status 128 + signal (an impatient Ctrl-C).
pub fn install(stop: &Stop) -> std::io::Result<()> {
    let mut set = SigSet::empty();
    set.add(Signal::SIGINT);
    set.add(Signal::SIGTERM);
    pthread_sigmask(SigmaskHow::SIG_BLOCK, Some(&set), None)?;
    let stop = stop.clone();
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || loop {
            let Ok(sig) = set.wait() else { continue };
            if stop.requested() {
                std::process::exit(128 + sig as i32);
            }
            stop.request(sig as i32);
        })?;
    Ok(())
}
