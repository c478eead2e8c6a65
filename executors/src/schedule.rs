//! The absolute-deadline schedule of the base tick, and the sleep that waits for it.
//!
//! Deadlines lie on a fixed grid `start + k · period`. A tick that wakes late runs at once (its
//! lateness is recorded); if it wakes a whole period or more late, the slots that passed are
//! **skipped** and counted as misses, and the tick runs as the newest passed slot: the schedule is
//! re-anchored on its grid and never catches up in a burst.

use std::sync::atomic::{AtomicBool, Ordering};

use nix::sys::time::TimeSpec;
use nix::time::{clock_nanosleep, ClockId, ClockNanosleepFlags};

/// What the schedule says about one wake-up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Wake {
    /// Slot number (ticks since start, counting skipped ones): the tick number of this tick.
    pub slot: u64,
    /// The slot's scheduled time (ns).
    pub sched_ns: u64,
    /// How late the wake-up was relative to the deadline it slept for (ns).
    pub late_ns: u64,
    /// Slots skipped because they had passed entirely (deadline misses).
    pub skipped: u64,
}

/// A fixed-period grid of deadlines.
#[derive(Debug, Clone)]
pub struct Schedule {
    period_ns: u64,
    deadline_ns: u64,
    slot: u64,
}

impl Schedule {
    /// First deadline at `start_ns`, then every `period_ns`.
    pub fn new(start_ns: u64, period_ns: u64) -> Self {
        assert!(period_ns > 0, "a period of 0 ns");
        Self {
            period_ns,
            deadline_ns: start_ns,
            slot: 0,
        }
    }

    /// The deadline to sleep until.
    pub fn deadline_ns(&self) -> u64 {
        self.deadline_ns
    }

    /// The period.
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// Accounts for a wake-up at `now_ns`, skipping every slot that passed entirely.
    pub fn wake(&mut self, now_ns: u64) -> Wake {
        let late_ns = now_ns.saturating_sub(self.deadline_ns);
        let skipped = late_ns / self.period_ns;
        self.deadline_ns += skipped * self.period_ns;
        self.slot += skipped;
        Wake {
            slot: self.slot,
            sched_ns: self.deadline_ns,
            late_ns,
            skipped,
        }
    }

    /// Moves to the next slot (after the tick's work).
    pub fn advance(&mut self) {
        self.deadline_ns += self.period_ns;
        self.slot += 1;
    }
}

/// Longest single sleep, so that a stop request is seen within this time even at low rates.
const MAX_SLEEP_NS: u64 = 50_000_000;

/// Sleeps until `deadline_ns` (CLOCK_MONOTONIC, absolute), busy-waiting the last `spin_ns`.
/// Returns `false` without waiting further if `stop` becomes set.
pub fn sleep_until(deadline_ns: u64, spin_ns: u64, stop: &AtomicBool) -> bool {
    let wake_at = deadline_ns.saturating_sub(spin_ns);
    loop {
        if stop.load(Ordering::Relaxed) {
            return false;
        }
        let now = conductor_bus::monotonic_ns();
        if now >= wake_at {
            break;
        }
        let until = wake_at.min(now + MAX_SLEEP_NS);
        let ts = TimeSpec::new((until / 1_000_000_000) as _, (until % 1_000_000_000) as _);
        // EINTR just loops; TIMER_ABSTIME makes the retry exact.
        let _ = clock_nanosleep(
            ClockId::CLOCK_MONOTONIC,
            ClockNanosleepFlags::TIMER_ABSTIME,
            &ts,
        );
    }
    while spin_ns > 0 && conductor_bus::monotonic_ns() < deadline_ns {
        core::hint::spin_loop();
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn on_time_ticks_advance_one_slot_each() {
        let mut s = Schedule::new(1_000, 100);
        let w = s.wake(1_020);
        assert_eq!(
            w,
            Wake {
                slot: 0,
                sched_ns: 1_000,
                late_ns: 20,
                skipped: 0
            }
        );
        s.advance();
        assert_eq!(s.deadline_ns(), 1_100);
        // Early wake-ups (they cannot happen with TIMER_ABSTIME, but) count as on time.
        assert_eq!(s.wake(1_090).late_ns, 0);
    }

    #[test]
    fn a_late_tick_runs_late_but_is_not_a_miss() {
        let mut s = Schedule::new(0, 100);
        let w = s.wake(99);
        assert_eq!((w.slot, w.late_ns, w.skipped), (0, 99, 0));
        s.advance();
        // The next deadline (100) is kept: one late tick does not shift the grid.
        assert_eq!(s.wake(100).late_ns, 0);
    }

    #[test]
    fn passed_slots_are_skipped_and_counted_never_run_in_a_burst() {
        let mut s = Schedule::new(0, 100);
        s.wake(0);
        s.advance();
        // Woke at 370 for the deadline at 100: slots 1 and 2 (100, 200) passed entirely; the tick
        // runs as slot 3 (deadline 300), 70 ns late relative to it.
        let w = s.wake(370);
        assert_eq!((w.slot, w.sched_ns, w.late_ns, w.skipped), (3, 300, 270, 2));
        s.advance();
        assert_eq!(s.deadline_ns(), 400, "re-anchored on the original grid");
        assert_eq!(s.wake(400).skipped, 0);
    }

    #[test]
    fn sleep_honours_stop() {
        let stop = AtomicBool::new(true);
        let far = conductor_bus::monotonic_ns() + 10_000_000_000;
        assert!(!sleep_until(far, 0, &stop));
    }

    #[test]
    fn sleep_reaches_the_deadline() {
        let stop = AtomicBool::new(false);
        let d = conductor_bus::monotonic_ns() + 2_000_000;
        assert!(sleep_until(d, 100_000, &stop));
        assert!(conductor_bus::monotonic_ns() >= d);
    }
}
