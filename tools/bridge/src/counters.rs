//! What the bridge did, counted (printed at exit and by the summary line).

use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::time::{Duration, Instant};

/// Counters shared by the bridge's threads.
#[derive(Debug, Default)]
pub struct Counters {
    /// State samples put on Zenoh.
    pub exported: AtomicU64,
    /// Remote samples published on the local bus.
    pub imported: AtomicU64,
    /// Messages on the key space that were not Conductor bridge messages (dropped, logged).
    pub malformed: AtomicU64,
    /// Samples or frames older than one already handled (dropped: latest-value, no duplicates).
    pub out_of_order: AtomicU64,
    /// Samples from a host or of a state no catalog declared (dropped).
    pub unknown: AtomicU64,
    /// Inbound messages dropped because the bridge's bounded queue was full.
    pub overflow: AtomicU64,
    /// Local command frames sent to a remote owner.
    pub commands_out: AtomicU64,
    /// Remote command frames handed to a local executor.
    pub commands_in: AtomicU64,
    /// Setpoints refused here: their state is not exported for remote commands.
    pub setpoints_refused: AtomicU64,
    /// Command frames dropped: the link was down, the queue full, or the frame too old.
    pub commands_dropped: AtomicU64,
    /// Times a remote host went quiet (its mirrors marked STALE).
    pub stale_events: AtomicU64,
}

impl Counters {
    /// Adds one to `c`; returns the new value.
    pub fn bump(c: &AtomicU64) -> u64 {
        c.fetch_add(1, Relaxed) + 1
    }

    /// One line with every counter.
    pub fn summary(&self) -> String {
        let g = |c: &AtomicU64| c.load(Relaxed);
        format!(
            "exported {} imported {} malformed {} out_of_order {} unknown {} overflow {} \
             commands_out {} commands_in {} setpoints_refused {} commands_dropped {} stale_events {}",
            g(&self.exported),
            g(&self.imported),
            g(&self.malformed),
            g(&self.out_of_order),
            g(&self.unknown),
            g(&self.overflow),
            g(&self.commands_out),
            g(&self.commands_in),
            g(&self.setpoints_refused),
            g(&self.commands_dropped),
            g(&self.stale_events),
        )
    }
}

/// Lets a repeated warning through at most once per second, saying how many were held back.
#[derive(Debug)]
pub struct RateLimit {
    last: Option<Instant>,
    held: u64,
}

impl Default for RateLimit {
    fn default() -> Self {
        Self::new()
    }
}

impl RateLimit {
    /// A limiter that lets the first one through.
    pub fn new() -> Self {
        Self {
            last: None,
            held: 0,
        }
    }

    /// `Some(held back since the last one)` when this one may be logged.
    pub fn allow(&mut self) -> Option<u64> {
        let now = Instant::now();
        if self
            .last
            .is_some_and(|t| now.duration_since(t) < Duration::from_secs(1))
        {
            self.held += 1;
            return None;
        }
        self.last = Some(now);
        Some(std::mem::take(&mut self.held))
    }
}
