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
/// Rounds of a lifecycle step (other than the probe and a safe action) lost to the line — a
/// request or its reply damaged or missing — that are sent again before the losses count as
/// tries: on a noisy bus a round of bundled requests is lost often, which says nothing about
/// the device.
pub(crate) const LOST_ROUNDS: u8 = 60;
/// How long a lifecycle round on a CAN bus may go without any answer before it counts as
/// lost (ns).
pub(crate) const ROUND_TIMEOUT_NS: u64 = 250_000_000;
/// The same on a register bus, where a round may wait behind the others of a large bus (the
/// bring-up of 41 servos takes that long), and every request is answered, if only `Missing`,
/// unless its answer itself was lost in the stage (ns).
pub(crate) const REG_ROUND_TIMEOUT_NS: u64 = 2_000_000_000;
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

/// Where a managed device's lifecycle should end.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Goal {
    /// Enabled, accepting setpoints.
    Drive,
    /// Powered at its present position (or with its safe command), refusing setpoints
    /// (tripped with a `hold` action).
    Hold,
    /// Torque off (out of motor mode, axis idle).
    Limp,
}

/// The steps of a device's lifecycle, as far as the shared rules need to know them: each
/// device has its own step enum and names these three.
pub(crate) trait LifeStep: Copy + PartialEq {
    /// No step under way.
    const NONE: Self;
    /// Looking for the device: retried [`PROBE_TRIES`] times, [`PROBE_SPACING_NS`] apart.
    const PROBE: Self;
    /// A safe action waiting for its confirmation: sent again every [`SAFE_RETRY_NS`] until it
    /// is confirmed (the executor bounds the wait). Every other step is retried
    /// [`STEP_TRIES`] times, at once.
    const SAFE: Self;
}

/// Implements [`LifeStep`] for a device's step enum whose variants `None`, `Probe` and `Safe`
/// are the three the shared rules name (every managed device's enum has them).
macro_rules! life_step {
    ($step:ident) => {
        impl $crate::lifecycle::LifeStep for $step {
            const NONE: Self = $step::None;
            const PROBE: Self = $step::Probe;
            const SAFE: Self = $step::Safe;
        }
    };
}
pub(crate) use life_step;

/// The lifecycle bookkeeping every managed device keeps: its status, where it should end, and
/// the step under way with its retries. Plain data: nothing here allocates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Lifecycle<S> {
    pub(crate) status: DeviceStatus,
    pub(crate) startup: Startup,
    /// Where it should end up.
    pub(crate) goal: Goal,
    /// The user switched it off through its `enable` channel (a hold-off device then waits for
    /// `enable = 1`, not for any setpoint).
    pub(crate) user_off: bool,
    /// It was driving when its bus vanished: it resumes driving when the bus returns.
    pub(crate) resume_on: bool,
    pub(crate) step: S,
    /// The step's requests are out.
    pub(crate) sent: bool,
    /// The tick they went out in: a reply to an older request (a round given up and sent
    /// again) says nothing about this round.
    pub(crate) sent_tick: u64,
    /// When they went out (ns): a round that got neither an answer nor a `Missing` by
    /// [`ROUND_TIMEOUT_NS`] ([`REG_ROUND_TIMEOUT_NS`] on a register bus) later is lost (a CAN
    /// motor's frame superseded unsent by a newer one for the same motor is answered by
    /// nothing).
    pub(crate) sent_ns: u64,
    pub(crate) tries: u8,
    /// Rounds of the step lost to the line (see [`LOST_ROUNDS`]).
    pub(crate) lost: u8,
    /// The step's requests go out again no earlier than this.
    pub(crate) next_try_ns: u64,
}

impl<S: LifeStep> Lifecycle<S> {
    /// An unmanaged device's (a bare driver until it is brought up).
    pub(crate) fn new() -> Self {
        Self {
            status: DeviceStatus::UNMANAGED,
            startup: Startup::Enable,
            goal: Goal::Limp,
            user_off: false,
            resume_on: false,
            step: S::NONE,
            sent: false,
            sent_tick: 0,
            sent_ns: 0,
            tries: 0,
            lost: 0,
            next_try_ns: 0,
        }
    }

    /// Whether it has been brought up (it has a lifecycle).
    pub(crate) fn managed(&self) -> bool {
        self.status.phase != Phase::Unmanaged
    }

    /// Starts `step`: its requests go out at the next flush, with a fresh count of tries.
    pub(crate) fn go(&mut self, step: S) {
        self.step = step;
        self.sent = false;
        self.tries = 0;
        self.lost = 0;
    }

    /// Marks the step's requests as sent now.
    pub(crate) fn mark_sent(&mut self, tick: u64, now_ns: u64) {
        self.sent = true;
        self.sent_tick = tick;
        self.sent_ns = now_ns;
    }

    /// Whether the round out since [`mark_sent`](Self::mark_sent) has had no answer for
    /// `timeout_ns`.
    pub(crate) fn round_overdue(&self, now_ns: u64, timeout_ns: u64) -> bool {
        self.sent && self.step != S::NONE && now_ns >= self.sent_ns + timeout_ns
    }

    /// The step's round was lost to the line (a reply missing): sent again at once while
    /// fewer than [`LOST_ROUNDS`] were lost, else counted as a try like
    /// [`retry_exhausted`](Self::retry_exhausted) (the probe and a safe action count every
    /// loss as a try: they have their own spacing and budget).
    pub(crate) fn lost_exhausted(&mut self, now_ns: u64) -> bool {
        if self.step != S::PROBE && self.step != S::SAFE && self.lost < LOST_ROUNDS {
            self.lost += 1;
            self.sent = false;
            self.next_try_ns = now_ns;
            return false;
        }
        self.retry_exhausted(now_ns)
    }

    /// The step's request went unanswered (or was refused): counts the try and, below the
    /// step's limit, arranges a retry (sent again after the step's spacing). Returns whether
    /// the limit is reached: then nothing is arranged, and the device gives up its own way.
    pub(crate) fn retry_exhausted(&mut self, now_ns: u64) -> bool {
        self.tries = self.tries.saturating_add(1);
        let (limit, spacing) = if self.step == S::PROBE {
            (PROBE_TRIES, PROBE_SPACING_NS)
        } else if self.step == S::SAFE {
            // A safe action is sent again until it is confirmed; the executor bounds the wait.
            (u8::MAX, SAFE_RETRY_NS)
        } else {
            (STEP_TRIES, 0)
        };
        if self.tries < limit {
            self.sent = false;
            self.next_try_ns = now_ns + spacing;
            return false;
        }
        true
    }

    /// Whether a setpoint is taken now: always while unmanaged or enabled; while disabled, only
    /// by a hold-off device never tripped nor switched off by the user (its first setpoint
    /// enables it from where it is).
    pub(crate) fn accepts_setpoints(&self) -> bool {
        match self.status.phase {
            Phase::Unmanaged | Phase::Enabled => true,
            Phase::Disabled => {
                self.startup == Startup::HoldOff && !self.status.tripped && !self.user_off
            }
            _ => false,
        }
    }

    /// A trip (watchdog, fault): it will not resume driving by itself, a managed device counts
    /// as tripped, and its goal is limp until its safe action says otherwise.
    pub(crate) fn begin_trip(&mut self) {
        self.resume_on = false;
        if self.managed() {
            self.status.tripped = true;
        }
        self.goal = Goal::Limp;
    }

    /// What a write of `value` to the `enable` channel asks of a managed device: `Some(true)`
    /// start enabling (from where it is; nothing if it already is or is on its way),
    /// `Some(false)` switch off, `None` nothing.
    pub(crate) fn enable_request(&self, value: f64) -> Option<bool> {
        if value >= 0.5 {
            (!matches!(self.status.phase, Phase::Enabled | Phase::Enabling)).then_some(true)
        } else {
            Some(false)
        }
    }

    /// An enable asked for while the device cannot take it yet is remembered instead of
    /// started: offline, it drives again once its bus is back; during its bring-up (probing,
    /// configuring, a reboot's probe), the bring-up goes on and ends enabled. Starting the
    /// enable then would send it to a bus that is not there (and give up: "did not switch
    /// on"), or skip the model check and the configuration's verification. Returns whether it
    /// was deferred.
    pub(crate) fn defer_enable(&mut self) -> bool {
        match self.status.phase {
            Phase::Offline => self.resume_on = true,
            Phase::Probing | Phase::Configuring => self.goal = Goal::Drive,
            _ => return false,
        }
        self.user_off = false;
        true
    }

    /// An accepted setpoint while disabled is a hold-off device's first command: it enables
    /// the device from where it is before it applies.
    pub(crate) fn setpoint_enables(&self) -> bool {
        self.status.phase == Phase::Disabled
    }

    /// Bring-up with `startup`: where it should end (driving again if it was, or per `startup`
    /// unless the user or a trip switched it off; holding again if it held), and a fresh
    /// probing status keeping the trip and the fault. The device then starts its probe step.
    pub(crate) fn bring_up(&mut self, startup: Startup) {
        let tripped = self.status.tripped;
        self.startup = startup;
        self.goal = if self.resume_on || (startup == Startup::Enable && !self.user_off && !tripped)
        {
            Goal::Drive
        } else if tripped && self.goal == Goal::Hold {
            Goal::Hold
        } else {
            Goal::Limp
        };
        self.status = DeviceStatus {
            tripped,
            fault: self.status.fault,
            ..DeviceStatus::probing()
        };
        self.next_try_ns = 0;
    }

    /// Its bus vanished: offline, resuming driving when the bus is back if it was driving (or
    /// enabling); a pending safe action did not arrive; no step under way.
    pub(crate) fn bus_lost(&mut self) {
        self.resume_on = matches!(self.status.phase, Phase::Enabled | Phase::Enabling);
        self.status.phase = Phase::Offline;
        if self.status.safe == SafeProgress::Pending {
            // Whatever was on its way did not arrive.
            self.status.safe = SafeProgress::None;
        }
        self.step = S::NONE;
    }

    /// A safe action is asked for: pending. Returns whether the device is up to take it; if it
    /// is not, nothing can be sent and the action stays unconfirmed (no step under way).
    pub(crate) fn begin_safe(&mut self) -> bool {
        self.status.safe = SafeProgress::Pending;
        let up = matches!(
            self.status.phase,
            Phase::Enabled | Phase::Enabling | Phase::Holding | Phase::Disabled
        );
        if !up {
            self.step = S::NONE;
        }
        up
    }

    /// Bring-up failed for `f`.
    pub(crate) fn fail(&mut self, f: Failure) {
        self.status.failure = Some(f);
        self.status.phase = Phase::Failed;
        self.step = S::NONE;
    }

    /// Up, but it did not switch on: limp, and say why.
    pub(crate) fn refuse_enable(&mut self) {
        self.status.failure = Some(Failure::EnableRefused);
        self.status.phase = Phase::Disabled;
        self.goal = Goal::Limp;
        self.step = S::NONE;
    }

    /// It switched on: holding (its trip's `hold` action confirmed) or enabled (driving, the
    /// trip and the last failure cleared).
    pub(crate) fn switched_on(&mut self) {
        if self.goal == Goal::Hold {
            self.status.phase = Phase::Holding;
            self.status.safe = SafeProgress::Confirmed;
        } else {
            self.status.phase = Phase::Enabled;
            self.status.failure = None;
            self.status.tripped = false;
            self.status.safe = SafeProgress::None;
        }
        self.step = S::NONE;
    }

    /// It is limp, as its goal said: disabled; a trip's safe action is thereby confirmed.
    pub(crate) fn settle_limp(&mut self) {
        self.status.phase = Phase::Disabled;
        self.step = S::NONE;
        if self.status.tripped {
            self.status.safe = SafeProgress::Confirmed;
        }
    }

    /// The safe action under way is confirmed.
    pub(crate) fn safe_confirmed(&mut self) {
        self.status.safe = SafeProgress::Confirmed;
        self.step = S::NONE;
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

    /// A device's steps, as the shared rules see them.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    enum S {
        None,
        Probe,
        Other,
        Safe,
    }

    life_step!(S);

    fn in_phase(phase: Phase) -> Lifecycle<S> {
        let mut l = Lifecycle::new();
        l.status.phase = phase;
        l
    }

    /// Retries `step` from its start at `t0`: how many misses it takes to exhaust it, and the
    /// spacing asked for before the last retry.
    fn exhaust(step: S, t0: u64) -> (u32, u64) {
        let mut l = in_phase(Phase::Probing);
        l.go(step);
        let mut misses = 0;
        let mut spacing = 0;
        loop {
            l.sent = true;
            misses += 1;
            let now = t0 + misses as u64;
            if l.retry_exhausted(now) {
                assert!(l.sent, "an exhausted step is not sent again");
                assert_eq!(l.step, step, "the device decides what follows");
                return (misses, spacing);
            }
            assert!(!l.sent, "below the limit the step goes out again");
            spacing = l.next_try_ns - now;
            assert_eq!(l.tries as u32, misses);
        }
    }

    #[test]
    fn retry_limits_per_step_kind() {
        assert_eq!(
            exhaust(S::Probe, 1_000),
            (PROBE_TRIES as u32, PROBE_SPACING_NS)
        );
        assert_eq!(exhaust(S::Other, 1_000), (STEP_TRIES as u32, 0));
        assert_eq!(exhaust(S::Safe, 1_000), (u8::MAX as u32, SAFE_RETRY_NS));
        assert_eq!(PROBE_TRIES, 20);
        assert_eq!(STEP_TRIES, 10);
    }

    #[test]
    fn go_starts_a_step_afresh() {
        let mut l = in_phase(Phase::Probing);
        l.go(S::Probe);
        l.sent = true;
        assert!(!l.retry_exhausted(0));
        assert_eq!(l.tries, 1);
        l.go(S::Other);
        assert_eq!((l.step, l.sent, l.tries), (S::Other, false, 0));
        assert_eq!(l.next_try_ns, PROBE_SPACING_NS, "go keeps the retry time");
    }

    #[test]
    fn setpoints_accepted_per_phase() {
        let mut accepted = 0;
        for phase in [
            Phase::Unmanaged,
            Phase::Offline,
            Phase::Probing,
            Phase::Configuring,
            Phase::Enabling,
            Phase::Enabled,
            Phase::Holding,
            Phase::Disabled,
            Phase::Failed,
        ] {
            for startup in [Startup::Enable, Startup::HoldOff] {
                for tripped in [false, true] {
                    for user_off in [false, true] {
                        let mut l = in_phase(phase);
                        l.startup = startup;
                        l.status.tripped = tripped;
                        l.user_off = user_off;
                        // Only these, and a hold-off device never tripped nor switched off.
                        let want = matches!(phase, Phase::Unmanaged | Phase::Enabled)
                            || (phase, startup, tripped, user_off)
                                == (Phase::Disabled, Startup::HoldOff, false, false);
                        accepted += want as u32;
                        assert_eq!(
                            l.accepts_setpoints(),
                            want,
                            "{phase:?} {startup:?} tripped {tripped} user_off {user_off}"
                        );
                    }
                }
            }
        }
        assert_eq!(accepted, 2 * 8 + 1);
        let mut hold_off = in_phase(Phase::Disabled);
        hold_off.startup = Startup::HoldOff;
        assert!(
            hold_off.accepts_setpoints(),
            "a hold-off device's first setpoint"
        );
        hold_off.status.tripped = true;
        assert!(!hold_off.accepts_setpoints(), "not after a trip");
    }

    #[test]
    fn trip_preamble() {
        let mut l = in_phase(Phase::Enabled);
        l.goal = Goal::Drive;
        l.resume_on = true;
        l.begin_trip();
        assert!(l.status.tripped);
        assert!(!l.resume_on);
        assert_eq!(l.goal, Goal::Limp);
        assert_eq!(l.status.phase, Phase::Enabled, "the safe action moves it");

        let mut bare = Lifecycle::<S>::new();
        bare.goal = Goal::Drive;
        bare.resume_on = true;
        bare.begin_trip();
        assert!(!bare.status.tripped, "a bare driver has no trip to clear");
        assert!(!bare.resume_on);
        assert_eq!(bare.goal, Goal::Limp);
    }

    #[test]
    fn bring_up_goals() {
        let goal_after = |startup, resume_on, user_off, tripped, goal| {
            let mut l = in_phase(Phase::Disabled);
            l.resume_on = resume_on;
            l.user_off = user_off;
            l.status.tripped = tripped;
            l.status.fault = 7;
            l.status.failure = Some(Failure::EnableRefused);
            l.goal = goal;
            l.next_try_ns = 99;
            l.bring_up(startup);
            assert_eq!(l.startup, startup);
            assert_eq!(l.status.phase, Phase::Probing);
            assert_eq!(l.status.failure, None);
            assert_eq!((l.status.tripped, l.status.fault), (tripped, 7));
            assert_eq!(l.next_try_ns, 0);
            l.goal
        };
        use Startup::*;
        assert_eq!(
            goal_after(Enable, false, false, false, Goal::Limp),
            Goal::Drive
        );
        assert_eq!(
            goal_after(HoldOff, false, false, false, Goal::Drive),
            Goal::Limp
        );
        assert_eq!(
            goal_after(HoldOff, true, false, false, Goal::Limp),
            Goal::Drive
        );
        assert_eq!(
            goal_after(Enable, false, true, false, Goal::Drive),
            Goal::Limp
        );
        assert_eq!(
            goal_after(Enable, false, false, true, Goal::Limp),
            Goal::Limp
        );
        assert_eq!(
            goal_after(Enable, false, false, true, Goal::Hold),
            Goal::Hold
        );
        assert_eq!(
            goal_after(Enable, true, false, true, Goal::Hold),
            Goal::Drive
        );
    }

    #[test]
    fn bus_lost_resumes_what_was_driving() {
        for (phase, resume) in [
            (Phase::Enabled, true),
            (Phase::Enabling, true),
            (Phase::Holding, false),
            (Phase::Disabled, false),
        ] {
            let mut l = in_phase(phase);
            l.go(S::Safe);
            l.status.safe = SafeProgress::Pending;
            l.bus_lost();
            assert_eq!(l.resume_on, resume, "{phase:?}");
            assert_eq!(l.status.phase, Phase::Offline);
            assert_eq!(l.status.safe, SafeProgress::None);
            assert_eq!(l.step, S::None);
        }
        let mut confirmed = in_phase(Phase::Holding);
        confirmed.status.safe = SafeProgress::Confirmed;
        confirmed.bus_lost();
        assert_eq!(confirmed.status.safe, SafeProgress::Confirmed);
    }

    #[test]
    fn safe_action_needs_a_device_up() {
        for phase in [
            Phase::Enabled,
            Phase::Enabling,
            Phase::Holding,
            Phase::Disabled,
        ] {
            let mut l = in_phase(phase);
            l.go(S::Safe);
            assert!(l.begin_safe(), "{phase:?}");
            assert_eq!((l.status.safe, l.step), (SafeProgress::Pending, S::Safe));
        }
        for phase in [
            Phase::Offline,
            Phase::Probing,
            Phase::Configuring,
            Phase::Failed,
        ] {
            let mut l = in_phase(phase);
            l.go(S::Safe);
            assert!(!l.begin_safe(), "{phase:?}");
            assert_eq!((l.status.safe, l.step), (SafeProgress::Pending, S::None));
        }
    }

    #[test]
    fn endings() {
        let mut l = in_phase(Phase::Probing);
        l.go(S::Probe);
        l.fail(Failure::NoAnswer);
        assert_eq!(l.status.phase, Phase::Failed);
        assert_eq!(l.status.failure, Some(Failure::NoAnswer));
        assert_eq!(l.step, S::None);

        let mut l = in_phase(Phase::Enabling);
        l.goal = Goal::Drive;
        l.go(S::Other);
        l.refuse_enable();
        assert_eq!(l.status.phase, Phase::Disabled);
        assert_eq!(l.status.failure, Some(Failure::EnableRefused));
        assert_eq!((l.goal, l.step), (Goal::Limp, S::None));

        // Enabled again after a trip: driving, the trip and the failure cleared.
        let mut l = in_phase(Phase::Enabling);
        l.goal = Goal::Drive;
        l.status.tripped = true;
        l.status.failure = Some(Failure::EnableRefused);
        l.status.safe = SafeProgress::Confirmed;
        l.go(S::Other);
        l.switched_on();
        assert_eq!(l.status.phase, Phase::Enabled);
        assert_eq!(l.status.failure, None);
        assert!(!l.status.tripped);
        assert_eq!((l.status.safe, l.step), (SafeProgress::None, S::None));

        // Holding after a trip: the hold confirmed, still tripped.
        let mut l = in_phase(Phase::Enabling);
        l.goal = Goal::Hold;
        l.status.tripped = true;
        l.status.failure = Some(Failure::EnableRefused);
        l.go(S::Other);
        l.switched_on();
        assert_eq!(l.status.phase, Phase::Holding);
        assert!(l.status.tripped);
        assert_eq!(l.status.failure, Some(Failure::EnableRefused));
        assert_eq!((l.status.safe, l.step), (SafeProgress::Confirmed, S::None));

        for tripped in [false, true] {
            let mut l = in_phase(Phase::Configuring);
            l.status.tripped = tripped;
            l.go(S::Other);
            l.settle_limp();
            assert_eq!((l.status.phase, l.step), (Phase::Disabled, S::None));
            let want = if tripped {
                SafeProgress::Confirmed
            } else {
                SafeProgress::None
            };
            assert_eq!(l.status.safe, want);
        }

        let mut l = in_phase(Phase::Holding);
        l.go(S::Safe);
        l.status.safe = SafeProgress::Pending;
        l.safe_confirmed();
        assert_eq!((l.status.safe, l.step), (SafeProgress::Confirmed, S::None));
    }

    #[test]
    fn new_is_unmanaged() {
        let l = Lifecycle::<S>::new();
        assert!(!l.managed());
        assert_eq!(l.status, DeviceStatus::UNMANAGED);
        assert_eq!(
            (l.goal, l.step, l.startup),
            (Goal::Limp, S::None, Startup::Enable)
        );
        assert!(in_phase(Phase::Offline).managed());
        // Plain data: copied, never allocated.
        let copy = l;
        assert_eq!(copy, l);
    }

    /// `enable = 1` starts enabling unless it is already enabled or enabling; `enable = 0`
    /// always switches off; only a disabled device is enabled by a setpoint.
    #[test]
    fn enable_writes_and_first_setpoints() {
        for phase in [
            Phase::Probing,
            Phase::Disabled,
            Phase::Enabling,
            Phase::Enabled,
            Phase::Offline,
        ] {
            let l = in_phase(phase);
            let on = !matches!(phase, Phase::Enabling | Phase::Enabled);
            assert_eq!(l.enable_request(1.0), on.then_some(true), "{phase:?}");
            assert_eq!(l.enable_request(0.0), Some(false), "{phase:?}");
            assert_eq!(l.setpoint_enables(), phase == Phase::Disabled, "{phase:?}");
        }
    }

    #[test]
    fn startup_names() {
        for n in Startup::CHOICES {
            assert!(Startup::from_name(n).is_some());
        }
        assert_eq!(Startup::from_name("on"), None);
    }
}
