//! [`TickProfile`]: where a tick's time goes, phase by phase, from the executor's own clock.
//!
//! Opt-in (`CONDUCTOR_TICK_PROFILE=<file>` for `conductor-executor`): each phase boundary of a
//! tick reads `CLOCK_MONOTONIC` once and adds the time since the previous boundary to that
//! phase's total, in fixed-size fields (no allocation, no lock). Disabled, a boundary is one
//! predictable branch. The totals are written to the file when the executor stops, off the
//! real-time path; `benches/README.md` shows how they are read.

use conductor_bus::monotonic_ns;

/// The phases of a tick, in the order they run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(usize)]
pub enum TickPhase {
    /// Draining the command frames and applying their setpoints.
    Commands,
    /// Watchdog, state stage and device stage downstream (setpoints and sample requests).
    Down,
    /// Hardware I/O: the links' `receive` and `exchange`.
    HardwareIo,
    /// Protocol: encoding requests, decoding replies, routing them, link supervision.
    Protocol,
    /// Device stage upstream: replies to channel values, lifecycle, flags.
    DeviceUp,
    /// Publishing every state that ticked (loan, write, send per state: the service's history
    /// and the subscribers' queues are updated inside the send).
    Publish,
    /// Notifying the tick event.
    TickEvent,
    /// Handing lifecycle events to the event thread, lateness histogram, stats when due.
    Stats,
}

impl TickPhase {
    /// Every phase, in tick order.
    pub const ALL: [TickPhase; 8] = [
        TickPhase::Commands,
        TickPhase::Down,
        TickPhase::HardwareIo,
        TickPhase::Protocol,
        TickPhase::DeviceUp,
        TickPhase::Publish,
        TickPhase::TickEvent,
        TickPhase::Stats,
    ];

    /// The phase's name in the profile file.
    pub fn name(self) -> &'static str {
        match self {
            TickPhase::Commands => "commands",
            TickPhase::Down => "down",
            TickPhase::HardwareIo => "hardware_io",
            TickPhase::Protocol => "protocol",
            TickPhase::DeviceUp => "device_up",
            TickPhase::Publish => "publish",
            TickPhase::TickEvent => "tick_event",
            TickPhase::Stats => "stats",
        }
    }
}

const PHASES: usize = TickPhase::ALL.len();

/// Per-phase time totals over the ticks since [`TickProfile::reset`].
#[derive(Debug, Clone, Default)]
pub struct TickProfile {
    enabled: bool,
    last_ns: u64,
    ticks: u64,
    states: u64,
    ns: [u64; PHASES],
}

impl TickProfile {
    /// A profile that records (`true`) or does nothing (`false`).
    pub fn new(enabled: bool) -> Self {
        Self {
            enabled,
            ..Self::default()
        }
    }

    /// Whether it records.
    #[inline]
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// Zeroes the totals (keeps `enabled`).
    pub fn reset(&mut self) {
        *self = Self::new(self.enabled);
    }

    /// Opens a tick: the time from here to the first [`mark`](Self::mark) goes to its phase.
    #[inline]
    pub fn begin(&mut self) {
        if self.enabled {
            self.ticks += 1;
            self.last_ns = monotonic_ns();
        }
    }

    /// Closes `phase`: adds the time since the previous boundary to it.
    #[inline]
    pub fn mark(&mut self, phase: TickPhase) {
        if self.enabled {
            let now = monotonic_ns();
            self.ns[phase as usize] += now.saturating_sub(self.last_ns);
            self.last_ns = now;
        }
    }

    /// Counts `n` states published this tick.
    #[inline]
    pub fn published(&mut self, n: usize) {
        if self.enabled {
            self.states += n as u64;
        }
    }

    /// Ticks recorded.
    pub fn ticks(&self) -> u64 {
        self.ticks
    }

    /// States published over the recorded ticks.
    pub fn states(&self) -> u64 {
        self.states
    }

    /// Total nanoseconds spent in `phase`.
    pub fn total_ns(&self, phase: TickPhase) -> u64 {
        self.ns[phase as usize]
    }

    /// The profile as `key=value` lines: `ticks`, `states_published`, then `<phase>_ns` (total)
    /// and `<phase>_ns_per_tick` for every phase, and `total_ns_per_tick`.
    pub fn report(&self) -> String {
        let per = |ns: u64| ns as f64 / self.ticks.max(1) as f64;
        let mut out = format!("ticks={}\nstates_published={}\n", self.ticks, self.states);
        let mut total = 0;
        for p in TickPhase::ALL {
            let ns = self.total_ns(p);
            total += ns;
            out += &format!(
                "{0}_ns={1}\n{0}_ns_per_tick={2:.1}\n",
                p.name(),
                ns,
                per(ns)
            );
        }
        out += &format!("total_ns_per_tick={:.1}\n", per(total));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn disabled_records_nothing() {
        let mut p = TickProfile::new(false);
        p.begin();
        p.mark(TickPhase::Publish);
        p.published(3);
        assert_eq!(
            (p.ticks(), p.states(), p.total_ns(TickPhase::Publish)),
            (0, 0, 0)
        );
    }

    #[test]
    fn phases_add_up_to_the_tick() {
        let mut p = TickProfile::new(true);
        let t0 = monotonic_ns();
        p.begin();
        std::thread::sleep(std::time::Duration::from_millis(2));
        p.mark(TickPhase::HardwareIo);
        p.mark(TickPhase::Publish);
        p.published(41);
        let t1 = monotonic_ns();
        let sum: u64 = TickPhase::ALL.iter().map(|&ph| p.total_ns(ph)).sum();
        assert!(p.total_ns(TickPhase::HardwareIo) >= 2_000_000);
        assert!(sum <= t1 - t0, "{sum} > {}", t1 - t0);
        assert_eq!((p.ticks(), p.states()), (1, 41));
        let r = p.report();
        assert!(
            r.contains("ticks=1\n") && r.contains("states_published=41\n"),
            "{r}"
        );
        assert!(r.contains("hardware_io_ns_per_tick="), "{r}");
        p.reset();
        assert!(p.enabled());
        assert_eq!(p.ticks(), 0);
    }
}
