//! The payload ABI: what crosses process (and language) boundaries.
//!
//! Every type here is `#[repr(C)]`, fixed-size, self-contained and `ZeroCopySend`, with an explicit
//! iceoryx2 type name that carries the ABI version. Two binaries (or a Rust and a Python process)
//! connect only when name, size and alignment agree; the byte layout is documented in `bus/ABI.md`
//! and pinned by the layout tests below.

use iceoryx2::prelude::ZeroCopySend;

/// Version of the payload layouts in this module. Bumped on any change of a layout or of the
/// meaning of a field, flag or attribute (additions old readers can ignore keep it: `bus/ABI.md`,
/// *Versioning*); it is part of every type name and of the `conductor.abi` service attribute.
pub const ABI_VERSION: u32 = 2;

/// Maximum number of setpoints one [`CommandFrame`] carries (a 41-DOF humanoid fits in one frame).
pub const MAX_SETPOINTS: usize = 64;

/// Number of buckets of the lateness histogram in [`ExecutorStats`].
pub const HISTOGRAM_BUCKETS: usize = crate::histogram::BUCKETS;

/// Bit flags carried in [`StateSample::status`].
pub mod status {
    /// The value is the last good one: the hardware did not answer this cycle.
    pub const STALE: u32 = 1 << 0;
    /// The last command applied to this state was clamped to its limits.
    pub const CLAMPED: u32 = 1 << 1;
    /// The last command for this state was rejected (NaN/inf, read-only state, or its device
    /// refuses setpoints: see `DISABLED` and `TRIPPED`).
    pub const REJECTED: u32 = 1 << 2;
    /// The command watchdog fired: the device is in its declared safe action.
    pub const WATCHDOG: u32 = 1 << 3;
    /// The device reported a fault (e.g. a Dynamixel hardware-error bit).
    pub const DEVICE_FAULT: u32 = 1 << 4;
    /// The sample comes from a replayed recording, not from hardware.
    pub const REPLAYED: u32 = 1 << 5;
    /// The executor runs on simulated hardware.
    pub const SIMULATED: u32 = 1 << 6;
    /// The device is not driving its actuator (torque off, out of motor mode, idle, being
    /// brought up): setpoints are refused (except by a `startup = "hold_off"` device before its
    /// first command).
    pub const DISABLED: u32 = 1 << 7;
    /// A watchdog trip or a fault took the device to its safe state: setpoints are refused until
    /// its `enable` state is set to 1.
    pub const TRIPPED: u32 = 1 << 8;

    /// The name of every flag, in bit order (bit `i` is `NAMES[i]`).
    pub const NAMES: [&str; 9] = [
        "stale",
        "clamped",
        "rejected",
        "watchdog",
        "device-fault",
        "replayed",
        "simulated",
        "disabled",
        "tripped",
    ];

    /// Human-readable names of the flags set in `status`, in bit order.
    pub fn names(status: u32) -> impl Iterator<Item = &'static str> {
        NAMES
            .iter()
            .enumerate()
            .filter(move |(bit, _)| status & (1 << bit) != 0)
            .map(|(_, n)| *n)
    }
}

/// One sample of one State, published on `conductor/<subsystem>/<state>`.
///
/// Times are `CLOCK_MONOTONIC` nanoseconds. `t_sample_ns` is when the hardware was sampled (the
/// request time for request/reply buses), `t_publish_ns` when the executor handed it to the bus
/// (an executor reads the clock once per tick, before the tick's first state, and stamps every
/// state of the tick with it).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("conductor.StateSample.v2")]
#[repr(C)]
pub struct StateSample {
    /// Per-state sample counter, starting at 0 and incremented by one per publish; a gap seen by a
    /// subscriber means samples were overwritten before it read them.
    pub seq: u64,
    /// Executor tick on which this sample was produced. Samples of one subsystem that share a tick
    /// reflect the same bus cycle (and the same applied command frame).
    pub tick: u64,
    /// When the quantity was sampled (CLOCK_MONOTONIC, ns).
    pub t_sample_ns: u64,
    /// When the sample was published (CLOCK_MONOTONIC, ns).
    pub t_publish_ns: u64,
    /// The value in the state's units (after scale, offset and direction).
    pub value: f64,
    /// [`status`] bit flags.
    pub status: u32,
    /// Zero; reserved for future use without a layout change.
    pub reserved: u32,
}

/// One setpoint inside a [`CommandFrame`].
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("conductor.Setpoint.v2")]
#[repr(C)]
pub struct Setpoint {
    /// Index of the target state within its subsystem (the `index` service attribute).
    pub index: u32,
    /// Zero; reserved for per-setpoint options.
    pub flags: u32,
    /// Requested value in the state's units.
    pub value: f64,
}

/// A bundle of setpoints for one subsystem, published on `conductor/<subsystem>/commands`.
///
/// The executor applies every setpoint of a frame in the same tick (the thesis' `sendCtrl`).
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("conductor.CommandFrame.v2")]
#[repr(C)]
pub struct CommandFrame {
    /// Sender's frame counter.
    pub seq: u64,
    /// When the frame was sent (CLOCK_MONOTONIC, ns).
    pub t_send_ns: u64,
    /// Number of valid entries at the front of `entries` (≤ [`MAX_SETPOINTS`]).
    pub count: u32,
    /// Zero; reserved.
    pub flags: u32,
    /// The setpoints; only the first `count` are meaningful.
    pub entries: [Setpoint; MAX_SETPOINTS],
}

impl Default for CommandFrame {
    fn default() -> Self {
        Self {
            seq: 0,
            t_send_ns: 0,
            count: 0,
            flags: 0,
            entries: [Setpoint::default(); MAX_SETPOINTS],
        }
    }
}

impl CommandFrame {
    /// The valid setpoints. A frame whose `count` exceeds the capacity (a malformed frame from a
    /// foreign writer) yields only the entries that exist.
    pub fn setpoints(&self) -> &[Setpoint] {
        &self.entries[..(self.count as usize).min(MAX_SETPOINTS)]
    }

    /// Appends a setpoint, or returns `false` when the frame is full.
    pub fn push(&mut self, index: u32, value: f64) -> bool {
        let n = self.count as usize;
        if n >= MAX_SETPOINTS {
            return false;
        }
        self.entries[n] = Setpoint {
            index,
            flags: 0,
            value,
        };
        self.count += 1;
        true
    }

    /// Removes all setpoints.
    pub fn clear(&mut self) {
        self.count = 0;
    }
}

/// Executor health, published on `conductor/<subsystem>/stats` (about 10 times per second).
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("conductor.ExecutorStats.v2")]
#[repr(C)]
pub struct ExecutorStats {
    /// Stats message counter.
    pub seq: u64,
    /// When these figures were taken (CLOCK_MONOTONIC, ns).
    pub t_ns: u64,
    /// Base ticks executed since start.
    pub ticks: u64,
    /// Deadlines missed (the schedule was re-anchored each time).
    pub misses: u64,
    /// Configured base rate (Hz).
    pub base_rate_hz: f64,
    /// Achieved tick rate over the last stats interval (Hz).
    pub achieved_rate_hz: f64,
    /// Tick lateness percentiles since start, from [`histogram`](Self::histogram) (bucket upper bounds, ns).
    pub lateness_p50_ns: u64,
    /// See [`lateness_p50_ns`](Self::lateness_p50_ns).
    pub lateness_p99_ns: u64,
    /// See [`lateness_p50_ns`](Self::lateness_p50_ns).
    pub lateness_p999_ns: u64,
    /// Largest lateness observed (exact, ns).
    pub lateness_max_ns: u64,
    /// Bus errors (bad CRC, garbage bytes, missing replies, transport errors).
    pub bus_errors: u64,
    /// Command frames received.
    pub frames_applied: u64,
    /// Setpoints rejected (NaN/inf, unknown index, read-only state).
    pub setpoints_rejected: u64,
    /// Setpoints clamped to limits.
    pub setpoints_clamped: u64,
    /// Times the command watchdog fired.
    pub watchdog_trips: u64,
    /// States currently flagged stale.
    pub stale_states: u32,
    /// States owned by this executor.
    pub states: u32,
    /// 1 when the RT thread runs SCHED_FIFO, 0 when it fell back to normal scheduling.
    pub rt_active: u32,
    /// CPU the RT thread is pinned to, or -1.
    pub cpu: i32,
    /// Times a bus (serial port, CAN interface, adapter) vanished.
    pub bus_outages: u64,
    /// Device fault transitions (a fault raised or changed).
    pub device_faults: u64,
    /// Replies that came after their request had been given up (counted, never published).
    pub late_replies: u64,
    /// Setpoints refused because their device was disabled or tripped.
    pub setpoints_refused: u64,
    /// Devices of the subsystem.
    pub devices: u32,
    /// Devices driving (enabled; a simulated device without a lifecycle unless tripped).
    pub devices_enabled: u32,
    /// Devices tripped (watchdog or fault), waiting to be enabled again.
    pub devices_tripped: u32,
    /// Devices reporting a fault now.
    pub devices_faulted: u32,
    /// Buses down now.
    pub links_down: u32,
    /// Zero.
    pub reserved: u32,
    /// Tick lateness histogram (see [`crate::histogram`] for the bucket layout).
    pub histogram: [u64; HISTOGRAM_BUCKETS],
}

impl Default for ExecutorStats {
    fn default() -> Self {
        Self {
            seq: 0,
            t_ns: 0,
            ticks: 0,
            misses: 0,
            base_rate_hz: 0.0,
            achieved_rate_hz: 0.0,
            lateness_p50_ns: 0,
            lateness_p99_ns: 0,
            lateness_p999_ns: 0,
            lateness_max_ns: 0,
            bus_errors: 0,
            frames_applied: 0,
            setpoints_rejected: 0,
            setpoints_clamped: 0,
            watchdog_trips: 0,
            stale_states: 0,
            states: 0,
            rt_active: 0,
            cpu: -1,
            bus_outages: 0,
            device_faults: 0,
            late_replies: 0,
            setpoints_refused: 0,
            devices: 0,
            devices_enabled: 0,
            devices_tripped: 0,
            devices_faulted: 0,
            links_down: 0,
            reserved: 0,
            histogram: [0; HISTOGRAM_BUCKETS],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::{align_of, offset_of, size_of};
    use iceoryx2::prelude::ZeroCopySend;

    // These numbers are the ABI documented in bus/ABI.md; changing one is a breaking change that
    // must bump ABI_VERSION and the type names.
    #[test]
    fn state_sample_layout() {
        assert_eq!(size_of::<StateSample>(), 48);
        assert_eq!(align_of::<StateSample>(), 8);
        assert_eq!(offset_of!(StateSample, seq), 0);
        assert_eq!(offset_of!(StateSample, tick), 8);
        assert_eq!(offset_of!(StateSample, t_sample_ns), 16);
        assert_eq!(offset_of!(StateSample, t_publish_ns), 24);
        assert_eq!(offset_of!(StateSample, value), 32);
        assert_eq!(offset_of!(StateSample, status), 40);
        assert_eq!(offset_of!(StateSample, reserved), 44);
    }

    #[test]
    fn command_frame_layout() {
        assert_eq!(size_of::<Setpoint>(), 16);
        assert_eq!(offset_of!(Setpoint, value), 8);
        assert_eq!(size_of::<CommandFrame>(), 24 + 16 * MAX_SETPOINTS);
        assert_eq!(offset_of!(CommandFrame, count), 16);
        assert_eq!(offset_of!(CommandFrame, entries), 24);
    }

    #[test]
    fn stats_layout() {
        assert_eq!(offset_of!(ExecutorStats, stale_states), 120);
        assert_eq!(offset_of!(ExecutorStats, bus_outages), 136);
        assert_eq!(offset_of!(ExecutorStats, devices), 168);
        assert_eq!(offset_of!(ExecutorStats, links_down), 184);
        assert_eq!(offset_of!(ExecutorStats, histogram), 192);
        assert_eq!(size_of::<ExecutorStats>(), 192 + 8 * HISTOGRAM_BUCKETS);
    }

    #[test]
    fn type_names_carry_the_abi_version() {
        // SAFETY: type_name() is an unsafe trait fn only because implementors promise uniqueness;
        // calling it has no preconditions.
        let names = unsafe {
            [
                StateSample::type_name(),
                CommandFrame::type_name(),
                ExecutorStats::type_name(),
            ]
        };
        for n in names {
            assert!(n.ends_with(&format!(".v{ABI_VERSION}")), "{n}");
        }
    }

    #[test]
    fn frame_push_until_full() {
        let mut f = CommandFrame::default();
        for i in 0..MAX_SETPOINTS as u32 {
            assert!(f.push(i, i as f64));
        }
        assert!(!f.push(99, 0.0));
        assert_eq!(f.setpoints().len(), MAX_SETPOINTS);
        assert_eq!(f.setpoints()[63].index, 63);
        f.count = 1000; // a foreign writer's garbage count must not index out of bounds
        assert_eq!(f.setpoints().len(), MAX_SETPOINTS);
        f.clear();
        assert!(f.setpoints().is_empty());
    }

    #[test]
    fn status_names() {
        let v: Vec<_> = status::names(status::STALE | status::WATCHDOG).collect();
        assert_eq!(v, ["stale", "watchdog"]);
        let v: Vec<_> = status::names(status::DISABLED | status::TRIPPED).collect();
        assert_eq!(v, ["disabled", "tripped"]);
    }
}
