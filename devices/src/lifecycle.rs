//! The lifecycle of a device on its bus, as the executor sees it: bring-up (probe, check the
//! model, write and verify the configuration, enable from where it is), driving, trips and
//! faults, and the confirmation of safe actions on the wire.
//!
//! ```text
//!            bring_up                     config ok        startup = enable
//!  Unmanaged ────────→ Probing ──────────→ Configuring ───────────────────→ Enabling ──→ Enabled
//!                        │  no answer /        │ refused                 (goal = present,   │
//!                        │  wrong model        ↓                          then torque on)   │ trip
//!                        └──────────────→   Failed          startup = hold_off              ↓
//!                                                     ──────────────────→ Disabled ←── Holding
//!  bus lost (any phase) → Offline ── bus back → Probing …      ↑ enable = 1 → Enabling
//! ```
//!
//! A managed device accepts setpoints only while `Enabled` (and, with `startup = hold_off`, the
//! first setpoint of a device that was never enabled nor tripped: it enables it from where it
//! is). After a trip (watchdog, fault) it refuses every setpoint until its `enable` channel is
//! written 1, which enables it again from its *present* position.

/// What a device does once it is brought up.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Startup {
    /// Enable it, holding the position it is in.
    #[default]
    Enable,
    /// Leave it limp (torque off) until the first setpoint, which enables it from where it is.
    HoldOff,
}

impl Startup {
    /// Every policy, as written in a manifest.
    pub const CHOICES: &'static [&'static str] = &["enable", "hold_off"];

    /// The policy written `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "enable" => Some(Startup::Enable),
            "hold_off" => Some(Startup::HoldOff),
            _ => None,
        }
    }
}

/// Where a device is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Never brought up: a bare driver whose writes go straight to the bus.
    Unmanaged,
    /// Its bus is down: nothing is sent until the bus is back.
    Offline,
    /// Looking for it (ping, model number).
    Probing,
    /// Found: reading, writing and verifying its configuration.
    Configuring,
    /// Reading where it is, setting its target there, switching it on.
    Enabling,
    /// Driving: setpoints accepted.
    Enabled,
    /// Tripped with a `hold` safe action: powered, holding its last position, setpoints refused.
    Holding,
    /// Powered off (torque off, out of motor mode, axis idle).
    Disabled,
    /// Bring-up failed: see [`DeviceStatus::failure`].
    Failed,
}

impl Phase {
    /// Short name for logs and tools.
    pub fn name(self) -> &'static str {
        match self {
            Phase::Unmanaged => "unmanaged",
            Phase::Offline => "offline",
            Phase::Probing => "probing",
            Phase::Configuring => "configuring",
            Phase::Enabling => "enabling",
            Phase::Enabled => "enabled",
            Phase::Holding => "holding",
            Phase::Disabled => "disabled",
            Phase::Failed => "failed",
        }
    }

    /// Whether the device is up (answered, configured) and settled in a steady phase.
    pub fn is_settled(self) -> bool {
        matches!(
            self,
            Phase::Unmanaged | Phase::Enabled | Phase::Holding | Phase::Disabled | Phase::Failed
        )
    }
}

/// Why bring-up failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Failure {
    /// Nothing answered at its address.
    NoAnswer,
    /// Something answered with another model number.
    WrongModel {
        /// The model number found.
        found: u16,
    },
    /// A configuration register did not take the value written (an EEPROM write with torque
    /// on, a value the device refuses).
    ConfigRefused {
        /// Register address.
        addr: u16,
        /// Raw value written.
        wrote: i64,
        /// Raw value read back.
        read: i64,
    },
    /// Its present position is outside the range it can be commanded to: enabling would make
    /// it move.
    OutOfRange {
        /// The raw present position.
        raw: i64,
    },
    /// It did not switch on (a latched fault, a refused state request).
    EnableRefused,
}

/// Progress of the last safe action on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SafeProgress {
    /// None asked for.
    #[default]
    None,
    /// Sent (or queued); its confirmation has not come yet.
    Pending,
    /// Confirmed: acknowledged by the adapter and answered by the device, or read back.
    Confirmed,
}

/// A device's lifecycle status, polled by the executor every tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceStatus {
    /// Where it is.
    pub phase: Phase,
    /// Why bring-up failed (with [`Phase::Failed`]), or why the last enable did not happen.
    pub failure: Option<Failure>,
    /// A watchdog trip or a fault took it to its safe state: setpoints are refused until it is
    /// enabled again.
    pub tripped: bool,
    /// Fault bits the device reports (Dynamixel Hardware Error Status, MIT error code, ODrive
    /// axis error); 0 = none.
    pub fault: u32,
    /// The last safe action's progress.
    pub safe: SafeProgress,
    /// The model number it reported, where the bus carries one.
    pub model: Option<u16>,
}

impl DeviceStatus {
    /// The status of a device that has no lifecycle (a bare driver, a simulated channel).
    pub const UNMANAGED: DeviceStatus = DeviceStatus {
        phase: Phase::Unmanaged,
        failure: None,
        tripped: false,
        fault: 0,
        safe: SafeProgress::None,
        model: None,
    };

    /// A managed device starting its bring-up.
    pub const fn probing() -> Self {
        DeviceStatus {
            phase: Phase::Probing,
            ..Self::UNMANAGED
        }
    }

    /// Whether it has a lifecycle.
    pub fn managed(&self) -> bool {
        self.phase != Phase::Unmanaged
    }

    /// Whether it is driving its actuator.
    pub fn driving(&self) -> bool {
        matches!(
            self.phase,
            Phase::Enabled | Phase::Holding | Phase::Unmanaged
        )
    }
}

/// How many times a lifecycle request is sent before the device counts as not answering, and
/// how far apart (a rebooting servo takes a while to answer again).
pub(crate) const PROBE_TRIES: u8 = 20;
/// Time between probe attempts (ns): 20 tries span one second.
pub(crate) const PROBE_SPACING_NS: u64 = 50_000_000;
/// Attempts of any other lifecycle step before it fails (a reply lost to noise, or late behind
/// a busy USB adapter, is not a refusal).
pub(crate) const STEP_TRIES: u8 = 10;
/// A safe action not yet confirmed is sent again this often (ns), until it is confirmed or
/// the executor stops waiting.
pub(crate) const SAFE_RETRY_NS: u64 = 20_000_000;
/// An optional device that failed is probed again this often (ns).
pub const REPROBE_NS: u64 = 1_000_000_000;

/// Exponential back-off between automatic recoveries (reboots after a fault): 1 s doubling to
/// 30 s, back to 1 s after a minute without a fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Backoff {
    next_ns: u64,
    last_fault_ns: Option<u64>,
}

impl Backoff {
    const FIRST_NS: u64 = 1_000_000_000;
    const MAX_NS: u64 = 30_000_000_000;
    const CALM_NS: u64 = 60_000_000_000;

    pub(crate) const fn new() -> Self {
        Self {
            next_ns: Self::FIRST_NS,
            last_fault_ns: None,
        }
    }

    /// A fault at `now`: returns when to act on it.
    pub(crate) fn fault_at(&mut self, now_ns: u64) -> u64 {
        if self
            .last_fault_ns
            .is_some_and(|t| now_ns.saturating_sub(t) > Self::CALM_NS)
        {
            self.next_ns = Self::FIRST_NS;
        }
        self.last_fault_ns = Some(now_ns);
        let wait = self.next_ns;
        self.next_ns = (self.next_ns * 2).min(Self::MAX_NS);
        now_ns + wait
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_to_a_cap_and_calms_down() {
        let mut b = Backoff::new();
        let s = 1_000_000_000;
        assert_eq!(b.fault_at(0), s);
        assert_eq!(b.fault_at(2 * s), 4 * s);
        assert_eq!(b.fault_at(5 * s), 9 * s);
        for _ in 0..10 {
            b.fault_at(10 * s);
        }
        assert_eq!(b.fault_at(11 * s), 41 * s, "capped at 30 s");
        assert_eq!(b.fault_at(100 * s), 101 * s, "a calm minute resets it");
    }

    #[test]
    fn startup_names() {
        for n in Startup::CHOICES {
            assert!(Startup::from_name(n).is_some());
        }
        assert_eq!(Startup::from_name("on"), None);
    }
}
