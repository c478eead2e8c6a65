//! The stage scheduler: runs a subsystem's States, Devices, Protocols and Hardware at their own
//! divisors of the base tick, caching work between stage ticks in fixed-capacity buffers.
//!
//! One base tick, in this fixed order (thesis Fig. 2.1, §3 of the architecture):
//!
//! ```text
//!  0. command frames (applied by the caller through `apply_frame`, all setpoints at once)
//!  1. watchdog      no frame for `watchdog_ms` → safe action of every writable device, now
//!  2. State    ↓    at its tick: its pending setpoint and a sample request go to its device
//!  3. Device   ↓    at its tick: writes, then samples, then flush → the link's request queue
//!  4. Protocol ↓    at its tick: ALL requests queued since its last tick, in one encode call
//!  5. Hardware ↕    at its tick: transmit pending words, collect received ones
//!  6. Protocol ↑    at its tick: decode words (and expire overdue requests) into replies,
//!                   which are routed to devices by credential
//!  7. Device   ↑    at its tick: replies → channel updates (device units) → states (calibrated)
//!  8. State    ↑    at its tick: publish the newest value with its sample time and flags
//! ```
//!
//! Between a stage's ticks its inputs wait in its cache: state→device requests are coalesced
//! per channel (the newest setpoint wins, one sample request), device→protocol requests queue in
//! a [`Bounded`] queue, replies queue per device. Every capacity is fixed by [`Stages::new`];
//! a full queue is counted as a bus error, never grown. Nothing here allocates, locks or blocks.
//!
//! **The hardware edge.** The first tick brings every device up (its own lifecycle: probe,
//! configuration, enable from where it is; see `conductor_devices::lifecycle`). Every tick the
//! stages poll each device's status and each link's state, and act on transitions:
//!
//! * a setpoint for a device that cannot take it now (disabled, tripped, being brought up) is
//!   refused: `REJECTED` on its state, counted, never silently dropped;
//! * a device fault trips the device (its safe action, ahead of anything queued on its bus);
//! * the watchdog trips every writable device the same way; a tripped device refuses
//!   setpoints until its `enable` state is written 1;
//! * a vanished bus makes its devices' states `STALE`; when the link has reopened it, its
//!   devices are brought up again and resume;
//! * each transition is an [`Event`] (drained by the executor into its log, never printed here).

use crate::profile::{TickPhase, TickProfile};
use conductor_bus::status;
use conductor_devices::kinds::{self, BuildError, Capacity};
use conductor_devices::lifecycle::REPROBE_NS;
use conductor_devices::{
    Bounded, BusCondition, ControllerState, Credential, Device, DeviceStatus, Errno, Failure, Link,
    LinkState, Phase, Reply, Request, SafeAction, SafeProgress, Startup, TickCtx, Update,
};

use conductor_manifest::{Calibration, SafeSpec, Subsystem};

/// A value ready to publish for one state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Publish {
    /// State index (the bus index).
    pub index: usize,
    /// Tick of the bus cycle that produced the value.
    pub tick: u64,
    /// Sample time (CLOCK_MONOTONIC ns).
    pub t_sample_ns: u64,
    /// Value in state units.
    pub value: f64,
    /// [`status`] flags.
    pub status: u32,
}

/// Counters the executor reports in its stats.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Command frames applied.
    pub frames: u64,
    /// Setpoints rejected (NaN/inf, unknown index, read-only state).
    pub rejected: u64,
    /// Setpoints clamped to their limits.
    pub clamped: u64,
    /// Watchdog trips.
    pub watchdog_trips: u64,
    /// Transport errors reported by hardware.
    pub hw_errors: u64,
    /// Replies whose credential matched no device on the link.
    pub unmatched_replies: u64,
    /// Work dropped because a fixed-capacity queue was full.
    pub overflows: u64,
    /// Setpoints refused because their device could not take them (disabled, tripped).
    pub refused: u64,
    /// Device fault transitions (a fault raised or changed).
    pub faults: u64,
    /// Events that did not fit the event queue (the log missed them).
    pub events_lost: u64,
}

/// Why a device was tripped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TripCause {
    /// No command frame within the watchdog timeout.
    Watchdog,
    /// The device reported a fault.
    Fault,
}

/// A transition worth a log line. Indices are the manifest's (links are protocols).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    /// A bus vanished.
    BusDown {
        /// Protocol index.
        link: usize,
        /// The OS error, where there was one.
        cause: Option<Errno>,
    },
    /// A CAN controller changed state (error-warning, error-passive, bus-off, back to
    /// error-active), as its driver's error frames say.
    Controller {
        /// Protocol index.
        link: usize,
        /// The new state.
        state: ControllerState,
    },
    /// The OS's transmit queue filled (frames refused, ENOBUFS) or takes frames again.
    TxQueue {
        /// Protocol index.
        link: usize,
        /// Full now.
        full: bool,
    },
    /// A bus is back (its devices are brought up again).
    BusUp {
        /// Protocol index.
        link: usize,
        /// How long it was gone (ns).
        outage_ns: u64,
    },
    /// A device changed phase.
    Phase {
        /// Device index.
        device: usize,
        /// The new phase.
        phase: Phase,
        /// Why, when it failed or an enable was refused.
        failure: Option<Failure>,
    },
    /// A device reports a fault (or a different one).
    Fault {
        /// Device index.
        device: usize,
        /// Fault bits or code.
        bits: u32,
    },
    /// A device's fault has cleared.
    FaultCleared {
        /// Device index.
        device: usize,
    },
    /// A device was tripped to its safe action.
    Tripped {
        /// Device index.
        device: usize,
        /// Why.
        cause: TripCause,
    },
    /// A device's safe action was confirmed on the wire.
    SafeConfirmed {
        /// Device index.
        device: usize,
    },
    /// A setpoint for a device that cannot take it was refused (first one per device until the
    /// device drives again).
    Refused {
        /// State index.
        state: usize,
        /// Its device's phase.
        phase: Phase,
        /// Its device is tripped.
        tripped: bool,
    },
}

/// One state as the stages schedule it: its device channel, divisor and calibration, the newest
/// value and the status flags it is published with.
struct ScheduledState {
    device: usize,
    channel: usize,
    divisor: u64,
    calib: Calibration,
    min: f64,
    max: f64,
    writable: bool,
    readable: bool,
    simulated: bool,
    // Newest value.
    have_value: bool,
    value: f64,
    t_sample_ns: u64,
    sample_tick: u64,
    // Flags.
    stale: bool,
    fault: bool,
    clamped: bool,
    rejected: bool,
    watchdog: bool,
    disabled: bool,
    tripped: bool,
    /// Setpoint (device units) waiting for the state's tick.
    pending: Option<f64>,
}

impl ScheduledState {
    fn status(&self) -> u32 {
        let mut s = 0;
        if self.stale {
            s |= status::STALE;
        }
        if self.clamped {
            s |= status::CLAMPED;
        }
        if self.rejected {
            s |= status::REJECTED;
        }
        if self.watchdog {
            s |= status::WATCHDOG;
        }
        if self.fault {
            s |= status::DEVICE_FAULT;
        }
        if self.simulated {
            s |= status::SIMULATED;
        }
        if self.disabled {
            s |= status::DISABLED;
        }
        if self.tripped {
            s |= status::TRIPPED;
        }
        s
    }
}

/// Per channel: what the states asked for since the device's last tick.
#[derive(Clone, Copy, Default)]
struct ChannelCache {
    sample: bool,
    write: Option<f64>,
}

/// One device as the stages schedule it: the driver, its link, its request cache and lifecycle.
struct ScheduledDevice {
    dev: Box<dyn Device>,
    link: usize,
    divisor: u64,
    cache: Vec<ChannelCache>,
    up: Bounded<Reply>,
    updates: Bounded<Update>,
    channel_state: Vec<Option<usize>>,
    /// Every state on this device (indices into `Stages::states`), so the per-tick lifecycle
    /// pass visits its own states rather than filtering all of them (O(n) per tick, not O(n²)).
    states: Vec<usize>,
    safe: Option<SafeAction>,
    startup: Startup,
    optional: bool,
    /// Its status at the end of the last tick.
    status: DeviceStatus,
    /// A failed optional device is looked for again then.
    reprobe_ns: Option<u64>,
    /// A refusal was logged since it last drove.
    refusal_logged: bool,
    /// It has been up (driving or limp) at least once: only then can it owe a safe action.
    ever_up: bool,
    /// Tripped by the watchdog (its states carry WATCHDOG until it is enabled again).
    watchdog: bool,
}

/// One link (protocol over hardware) as the stages schedule it: its queues, the credentials that
/// route its replies, and the bus's condition.
struct ScheduledLink {
    link: Box<dyn Link>,
    protocol_divisor: u64,
    hardware_divisor: u64,
    requests: Bounded<Request>,
    replies: Bounded<Reply>,
    creds: Vec<(Credential, usize)>,
    urgent: bool,
    state: LinkState,
    condition: BusCondition,
}

struct Watchdog {
    timeout_ns: Option<u64>,
    last_frame_ns: Option<u64>,
    tripped: bool,
}

/// A subsystem's components, scheduled tick by tick.
pub struct Stages {
    states: Vec<ScheduledState>,
    devices: Vec<ScheduledDevice>,
    links: Vec<ScheduledLink>,
    watchdog: Watchdog,
    counters: Counters,
    events: Bounded<Event>,
    started: bool,
    /// Per-phase time of the ticks (opt-in; a no-op unless enabled).
    profile: TickProfile,
}

impl core::fmt::Debug for Stages {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Stages")
            .field("states", &self.states.len())
            .field("devices", &self.devices.len())
            .field("links", &self.links.len())
            .finish()
    }
}

/// Requests one device can queue in one of its ticks: a write and a sample per channel, plus a
/// safe action's few requests.
fn per_device_tick(channels: usize) -> usize {
    2 * channels + 4
}

impl Stages {
    /// Builds every component of `sub` by kind (opening hardware) and sizes every queue.
    pub fn new(sub: &Subsystem) -> Result<Self, BuildError> {
        let caps = capacities(sub);
        let mut links = Vec::with_capacity(sub.protocols.len());
        for (p, cap) in sub.protocols.iter().zip(&caps) {
            let hw = &sub.hardware[p.hardware];
            links.push(kinds::build_link(
                &p.kind, &p.params, &hw.kind, &hw.params, *cap,
            )?);
        }
        let mut devices = Vec::with_capacity(sub.devices.len());
        for (i, d) in sub.devices.iter().enumerate() {
            let mut dev = kinds::build_device(&d.kind, &d.params, d.credential)?;
            // A simulated device starts where its state reads a value inside the state's
            // limits (real ones ignore this: they are where they are).
            for s in sub.states.iter().filter(|s| s.device == i) {
                dev.start_at(s.channel, s.calibration.to_device(rest(s.min, s.max)));
            }
            let sampled: Vec<usize> = sub
                .states
                .iter()
                .filter(|s| s.device == i && s.readable)
                .map(|s| s.channel)
                .collect();
            dev.configure_reads(&sampled);
            devices.push(dev);
        }
        Ok(Self::from_parts(sub, links, devices))
    }

    /// Schedules already-built components: `links[i]` realises `sub.protocols[i]` with its
    /// hardware, `devices[i]` realises `sub.devices[i]`. (Tests use it to observe the stages.)
    ///
    /// # Panics
    ///
    /// If the numbers of links or devices differ from the manifest's protocols or devices.
    pub fn from_parts(
        sub: &Subsystem,
        links: Vec<Box<dyn Link>>,
        devices: Vec<Box<dyn Device>>,
    ) -> Self {
        assert_eq!(links.len(), sub.protocols.len(), "one link per protocol");
        assert_eq!(devices.len(), sub.devices.len(), "one device per device");
        let caps = capacities(sub);
        let mut scheduled_links: Vec<ScheduledLink> = links
            .into_iter()
            .zip(&sub.protocols)
            .zip(&caps)
            .map(|((link, p), cap)| ScheduledLink {
                link,
                protocol_divisor: u64::from(p.divisor),
                hardware_divisor: u64::from(sub.hardware[p.hardware].divisor),
                requests: Bounded::with_capacity(cap.in_flight),
                replies: Bounded::with_capacity(2 * cap.in_flight),
                creds: Vec::with_capacity(cap.devices),
                urgent: false,
                state: LinkState::Up,
                condition: BusCondition::default(),
            })
            .collect();
        let mut scheduled_devices = Vec::with_capacity(devices.len());
        for (i, (dev, d)) in devices.into_iter().zip(&sub.devices).enumerate() {
            let channels = d.channels.len();
            let link = &mut scheduled_links[d.protocol];
            link.creds.push((d.credential, i));
            let ratio = link.protocol_divisor.div_ceil(u64::from(d.divisor)) as usize;
            let up = per_device_tick(channels) * (ratio + 2) * 2;
            let mut channel_state = vec![None; channels];
            let mut own_states = Vec::new();
            for (si, s) in sub.states.iter().enumerate() {
                if s.device == i {
                    channel_state[s.channel] = Some(si);
                    own_states.push(si);
                }
            }
            let writable = sub.states.iter().any(|s| s.device == i && s.writable);
            let kd = d.params.float("kd").unwrap_or(1.0);
            let safe = writable.then(|| match d.safe {
                SafeSpec::Hold => SafeAction::Hold,
                SafeSpec::TorqueOff => SafeAction::TorqueOff,
                SafeSpec::Damp { kd: k } => SafeAction::Damp {
                    kd: k.unwrap_or(kd),
                },
                SafeSpec::Setpoint { state, value } => {
                    let s = &sub.states[state];
                    SafeAction::Setpoint {
                        channel: s.channel,
                        value: s.calibration.to_device(value),
                    }
                }
            });
            scheduled_devices.push(ScheduledDevice {
                dev,
                link: d.protocol,
                divisor: u64::from(d.divisor),
                cache: vec![ChannelCache::default(); channels],
                up: Bounded::with_capacity(up),
                updates: Bounded::with_capacity(up * channels.max(1)),
                channel_state,
                states: own_states,
                safe,
                startup: d.startup,
                optional: d.optional,
                status: DeviceStatus::UNMANAGED,
                reprobe_ns: None,
                refusal_logged: false,
                ever_up: false,
                watchdog: false,
            });
        }
        // Replies are routed by credential with a binary search (a stable sort keeps the
        // first-declared device first among equal credentials, as a linear search found it).
        for l in &mut scheduled_links {
            l.creds.sort_by_key(|&(c, _)| c);
        }
        let states = sub
            .states
            .iter()
            .enumerate()
            .map(|(i, s)| ScheduledState {
                device: s.device,
                channel: s.channel,
                divisor: u64::from(s.divisor),
                calib: s.calibration,
                min: s.min,
                max: s.max,
                writable: s.writable,
                readable: s.readable,
                simulated: sub.state_is_simulated(i),
                have_value: false,
                value: 0.0,
                t_sample_ns: 0,
                sample_tick: 0,
                stale: false,
                fault: false,
                clamped: false,
                rejected: false,
                watchdog: false,
                disabled: false,
                tripped: false,
                pending: None,
            })
            .collect();
        Self {
            states,
            devices: scheduled_devices,
            links: scheduled_links,
            watchdog: Watchdog {
                timeout_ns: sub.watchdog_ns,
                last_frame_ns: None,
                tripped: false,
            },
            counters: Counters::default(),
            events: Bounded::with_capacity(256),
            started: false,
            profile: TickProfile::default(),
        }
    }

    /// The per-phase profile of the ticks (recording only once enabled with
    /// [`set_profile`](Self::set_profile)).
    pub fn profile(&self) -> &TickProfile {
        &self.profile
    }

    /// Replaces the per-phase profile (enable it with `TickProfile::new(true)`).
    pub fn set_profile(&mut self, profile: TickProfile) {
        self.profile = profile;
    }

    /// The profile, for the executor's own phase boundaries.
    pub(crate) fn profile_mut(&mut self) -> &mut TickProfile {
        &mut self.profile
    }

    /// Applies every setpoint of one command frame at once (thesis `sendCtrl`): each value is
    /// checked (finite, known, writable, and its device able to take it now), clamped to its
    /// limits and converted to device units; it goes downstream at its state's next tick.
    /// `sched_ns` is the current tick's scheduled time (it restarts the watchdog).
    pub fn apply_frame(&mut self, setpoints: &[conductor_bus::Setpoint], sched_ns: u64) {
        self.counters.frames += 1;
        self.watchdog.last_frame_ns = Some(sched_ns);
        if self.watchdog.tripped {
            // The watchdog may trip again; the devices it tripped stay tripped until enabled.
            self.watchdog.tripped = false;
            for s in self.states.iter_mut() {
                if !self.devices[s.device].status.managed() {
                    s.watchdog = false;
                }
            }
        }
        for sp in setpoints {
            let Some(s) = self.states.get_mut(sp.index as usize) else {
                self.counters.rejected += 1;
                continue;
            };
            if !s.writable || !sp.value.is_finite() {
                s.rejected = true;
                self.counters.rejected += 1;
                continue;
            }
            let d = &mut self.devices[s.device];
            if !d.dev.accepts(s.channel) {
                // It cannot take effect: refused loudly, never dropped silently.
                s.rejected = true;
                s.pending = None;
                self.counters.rejected += 1;
                self.counters.refused += 1;
                if !d.refusal_logged {
                    d.refusal_logged = true;
                    let e = Event::Refused {
                        state: sp.index as usize,
                        phase: d.status.phase,
                        tripped: d.status.tripped,
                    };
                    if self.events.push(e).is_err() {
                        self.counters.events_lost += 1;
                    }
                }
                continue;
            }
            let v = sp.value.clamp(s.min, s.max);
            s.clamped = v != sp.value;
            s.rejected = false;
            if s.clamped {
                self.counters.clamped += 1;
            }
            s.pending = Some(s.calib.to_device(v));
            if !s.readable {
                // A write-only state publishes what it was last told.
                s.value = v;
            }
        }
    }

    fn event(&mut self, e: Event) {
        if self.events.push(e).is_err() {
            self.counters.events_lost += 1;
        }
    }

    /// Brings every device up (called by the first tick).
    fn start(&mut self, ctx: TickCtx) {
        self.started = true;
        for d in &mut self.devices {
            d.dev.bring_up(d.startup, ctx);
            d.status = d.dev.status();
        }
    }

    /// Runs one base tick. `sched_ns` is the tick's scheduled time (watchdog clock), `now_ns`
    /// the time it actually started (the sample time of its requests). Every state that ticks
    /// and has a value is handed to `publish`; returns how many were.
    pub fn tick(
        &mut self,
        tick: u64,
        sched_ns: u64,
        now_ns: u64,
        mut publish: impl FnMut(&Publish),
    ) -> usize {
        let ctx = TickCtx { tick, now_ns };
        if !self.started {
            self.start(ctx);
        }
        self.check_watchdog(sched_ns, ctx);

        // 2. State stage, downstream.
        for s in &mut self.states {
            if !tick.is_multiple_of(s.divisor) {
                continue;
            }
            let c = &mut self.devices[s.device].cache[s.channel];
            if let Some(v) = s.pending.take() {
                c.write = Some(v);
            }
            if s.readable {
                c.sample = true;
            } else if s.writable {
                s.have_value = true;
                s.t_sample_ns = now_ns;
                s.sample_tick = tick;
            }
        }

        // 3. Device stage, downstream: writes first, then samples, then flush.
        for d in &mut self.devices {
            if !tick.is_multiple_of(d.divisor) {
                continue;
            }
            let out = &mut self.links[d.link].requests;
            let before = out.overflows();
            for (ch, c) in d.cache.iter_mut().enumerate() {
                if let Some(v) = c.write.take() {
                    d.dev.write(ch, v, ctx);
                }
            }
            for (ch, c) in d.cache.iter_mut().enumerate() {
                if core::mem::take(&mut c.sample) {
                    d.dev.sample(ch, ctx, out);
                }
            }
            d.dev.flush(ctx, out);
            self.counters.overflows += out.overflows() - before;
        }
        self.profile.mark(TickPhase::Down);

        // 4–6. Hardware in, protocol down, hardware out, protocol up.
        for li in 0..self.links.len() {
            let l = &mut self.links[li];
            let proto = l.urgent || tick.is_multiple_of(l.protocol_divisor);
            let hw = l.urgent || tick.is_multiple_of(l.hardware_divisor);
            l.urgent = false;
            if hw {
                l.link.receive(ctx);
                self.profile.mark(TickPhase::HardwareIo);
            }
            let l = &mut self.links[li];
            if proto {
                l.link.encode(l.requests.as_slice(), ctx);
                l.requests.clear();
                self.profile.mark(TickPhase::Protocol);
            }
            let l = &mut self.links[li];
            if hw {
                if l.link.exchange(ctx).is_err() {
                    self.counters.hw_errors += 1;
                }
                self.profile.mark(TickPhase::HardwareIo);
            }
            if proto {
                self.route_replies(li, ctx);
            }
            self.watch_link(li, ctx);
            self.profile.mark(TickPhase::Protocol);
        }

        // 7. Device stage, upstream.
        self.devices_up(tick, ctx);
        self.watch_devices(ctx);
        self.profile.mark(TickPhase::DeviceUp);

        // 8. State stage, upstream.
        let mut n = 0;
        for (index, s) in self.states.iter().enumerate() {
            if !tick.is_multiple_of(s.divisor) || !s.have_value {
                continue;
            }
            publish(&Publish {
                index,
                tick: s.sample_tick,
                t_sample_ns: s.t_sample_ns,
                value: s.value,
                status: s.status(),
            });
            n += 1;
        }
        self.profile.published(n);
        self.profile.mark(TickPhase::Publish);
        n
    }

    /// Decodes a link's replies and hands each to the device with its credential.
    fn route_replies(&mut self, li: usize, ctx: TickCtx) {
        let l = &mut self.links[li];
        let before = l.replies.overflows();
        l.link.decode(&mut l.replies, ctx);
        self.counters.overflows += l.replies.overflows() - before;
        for r in l.replies.as_slice() {
            let at = l.creds.partition_point(|(c, _)| *c < r.cred);
            match l.creds.get(at).filter(|(c, _)| *c == r.cred) {
                Some(&(_, di)) => {
                    if self.devices[di].up.push(*r).is_err() {
                        self.counters.overflows += 1;
                    }
                }
                None => self.counters.unmatched_replies += 1,
            }
        }
        l.replies.clear();
    }

    /// A link that went down or came back: its devices lose their bus, or are brought up again.
    fn watch_link(&mut self, li: usize, ctx: TickCtx) {
        // What the controller and the OS say about a bus that is there: one event per change.
        let cond = self.links[li].link.condition();
        let had = self.links[li].condition;
        if cond != had && self.links[li].link.state() == LinkState::Up {
            self.links[li].condition = cond;
            if cond.controller != had.controller {
                self.event(Event::Controller {
                    link: li,
                    state: cond.controller,
                });
            }
            if cond.tx_full != had.tx_full {
                self.event(Event::TxQueue {
                    link: li,
                    full: cond.tx_full,
                });
            }
        }
        let now = self.links[li].link.state();
        let was = self.links[li].state;
        if now == was {
            return;
        }
        self.links[li].state = now;
        match (was, now) {
            (LinkState::Up, LinkState::Down { cause, .. }) => {
                for d in self.devices.iter_mut().filter(|d| d.link == li) {
                    d.dev.bus_lost();
                    for c in &mut d.cache {
                        c.write = None;
                    }
                }
                self.event(Event::BusDown { link: li, cause });
            }
            (LinkState::Down { since_ns, .. }, LinkState::Up) => {
                for d in self.devices.iter_mut().filter(|d| d.link == li) {
                    d.dev.bring_up(d.startup, ctx);
                }
                self.event(Event::BusUp {
                    link: li,
                    outage_ns: ctx.now_ns.saturating_sub(since_ns),
                });
            }
            _ => {}
        }
    }

    /// Replies → devices → channel updates → states.
    fn devices_up(&mut self, tick: u64, ctx: TickCtx) {
        for d in &mut self.devices {
            if !tick.is_multiple_of(d.divisor) {
                continue;
            }
            let before = d.updates.overflows();
            for r in d.up.as_slice() {
                d.dev.reply(r, &mut d.updates);
            }
            d.up.clear();
            d.dev.report(ctx, &mut d.updates);
            self.counters.overflows += d.updates.overflows() - before;
            for u in d.updates.as_slice() {
                let Some(Some(si)) = d.channel_state.get(u.channel) else {
                    continue;
                };
                let s = &mut self.states[*si];
                if s.have_value && u.t_sample_ns < s.t_sample_ns {
                    // A reading older than the one the state has (a late reply, an earlier
                    // round's): a state's sample time never goes backwards.
                    continue;
                }
                match u.value {
                    Some(v) => {
                        s.value = s.calib.to_state(v);
                        s.t_sample_ns = u.t_sample_ns;
                        s.sample_tick = u.tick;
                        s.have_value = true;
                        s.stale = false;
                    }
                    None => s.stale = true,
                }
                s.fault = u.fault;
            }
            d.updates.clear();
        }
    }

    /// Each device's lifecycle: events on transitions, a fault trips it, its states' flags.
    fn watch_devices(&mut self, ctx: TickCtx) {
        for di in 0..self.devices.len() {
            let st = self.devices[di].dev.status();
            let was = self.devices[di].status;
            self.devices[di].status = st;
            if matches!(st.phase, Phase::Enabled | Phase::Holding | Phase::Disabled) {
                self.devices[di].ever_up = true;
            }
            if st.phase != was.phase {
                self.event(Event::Phase {
                    device: di,
                    phase: st.phase,
                    failure: st.failure,
                });
                if st.phase == Phase::Enabled {
                    self.devices[di].refusal_logged = false;
                    self.devices[di].watchdog = false;
                }
                if st.phase == Phase::Failed && self.devices[di].optional {
                    self.devices[di].reprobe_ns = Some(ctx.now_ns + REPROBE_NS);
                }
            }
            if st.fault != was.fault {
                if st.fault == 0 {
                    self.event(Event::FaultCleared { device: di });
                } else {
                    self.counters.faults += 1;
                    self.event(Event::Fault {
                        device: di,
                        bits: st.fault,
                    });
                    // A fault is fatal to driving: the device's safe action, now.
                    if !st.tripped && self.devices[di].safe.is_some() && st.managed() {
                        self.trip(di, ctx);
                        self.event(Event::Tripped {
                            device: di,
                            cause: TripCause::Fault,
                        });
                    }
                }
            }
            if st.safe == SafeProgress::Confirmed && was.safe != SafeProgress::Confirmed {
                self.event(Event::SafeConfirmed { device: di });
            }
            let d = &mut self.devices[di];
            if let Some(at) = d.reprobe_ns {
                if ctx.now_ns >= at {
                    d.reprobe_ns = None;
                    d.dev.bring_up(d.startup, ctx);
                }
            }
            let st = d.dev.status();
            let absent = matches!(st.phase, Phase::Offline | Phase::Probing | Phase::Failed);
            let watchdog = d.watchdog;
            for &si in &d.states {
                let s = &mut self.states[si];
                s.disabled = st.managed() && !st.driving();
                s.tripped = st.tripped;
                s.fault |= st.fault != 0;
                if absent {
                    s.stale = true;
                }
                if st.managed() {
                    s.watchdog = watchdog && st.tripped;
                }
            }
        }
    }

    fn check_watchdog(&mut self, sched_ns: u64, ctx: TickCtx) {
        let w = &mut self.watchdog;
        let (Some(timeout), Some(last)) = (w.timeout_ns, w.last_frame_ns) else {
            return;
        };
        if !w.tripped && sched_ns.saturating_sub(last) < timeout {
            return;
        }
        // While the source stays silent the watchdog holds: a device that sets out to drive
        // meanwhile (an enable asked for just before the source died, completing after the
        // timeout) is tripped as well, whether or not an earlier trip still marks it.
        let first = !w.tripped;
        if first {
            w.tripped = true;
            self.counters.watchdog_trips += 1;
        }
        for di in 0..self.devices.len() {
            let d = &self.devices[di];
            let setting_out =
                d.status.managed() && matches!(d.status.phase, Phase::Enabling | Phase::Enabled);
            // Devices already tripped (or limp by their own choice) stay as they are.
            if d.safe.is_none() || !(setting_out || (first && !d.status.tripped)) {
                continue;
            }
            self.trip(di, ctx);
            self.devices[di].watchdog = true;
            for s in self.states.iter_mut().filter(|s| s.device == di) {
                s.watchdog = true;
            }
            if self.devices[di].status.managed() {
                self.event(Event::Tripped {
                    device: di,
                    cause: TripCause::Watchdog,
                });
            }
        }
    }

    /// Device `di`'s safe action as a trip: ahead of anything queued on its bus, sent this tick
    /// whatever the divisors; setpoints refused until it is enabled again.
    fn trip(&mut self, di: usize, ctx: TickCtx) {
        self.act(di, ctx, true);
    }

    /// Device `di`'s safe action (`trip`: latched until re-enabled).
    fn act(&mut self, di: usize, ctx: TickCtx, trip: bool) {
        let d = &mut self.devices[di];
        let Some(action) = d.safe else { return };
        let l = &mut self.links[d.link];
        if !l.urgent {
            // Queued traffic would go first otherwise.
            l.link.preempt();
            l.requests.clear();
            l.urgent = true;
        }
        // Setpoints still waiting in the caches would undo the safe action.
        for c in &mut d.cache {
            c.write = None;
        }
        let before = l.requests.overflows();
        if trip {
            d.dev.trip(action, ctx, &mut l.requests);
        } else {
            d.dev.safe(action, ctx, &mut l.requests);
        }
        self.counters.overflows += l.requests.overflows() - before;
        for s in self.states.iter_mut().filter(|s| s.device == di) {
            s.pending = None;
        }
    }

    /// Orderly stop, step 1: every writable device's safe action, ahead of anything queued.
    /// Then call [`stop_tick`](Self::stop_tick) until [`stopped`](Self::stopped).
    pub fn begin_shutdown(&mut self, ctx: TickCtx) {
        for di in 0..self.devices.len() {
            self.act(di, ctx, false);
        }
    }

    /// One tick while stopping: no samples or setpoints, only the devices' own requests (safe
    /// action retries), the links, and the replies that confirm the actions.
    pub fn stop_tick(&mut self, ctx: TickCtx) {
        for d in &mut self.devices {
            let out = &mut self.links[d.link].requests;
            d.dev.flush(ctx, out);
        }
        for li in 0..self.links.len() {
            let l = &mut self.links[li];
            l.link.receive(ctx);
            l.link.encode(l.requests.as_slice(), ctx);
            l.requests.clear();
            if l.link.exchange(ctx).is_err() {
                self.counters.hw_errors += 1;
            }
            self.route_replies(li, ctx);
            self.watch_link(li, ctx);
        }
        for d in &mut self.devices {
            for r in d.up.as_slice() {
                d.dev.reply(r, &mut d.updates);
            }
            d.up.clear();
            d.updates.clear();
            d.status = d.dev.status();
        }
    }

    /// Whether every safe action that can still be confirmed has been, and every link has
    /// flushed what it took.
    pub fn stopped(&self) -> bool {
        let waiting = self.devices.iter().any(|d| {
            d.safe.is_some()
                && d.status.safe == SafeProgress::Pending
                && self.links[d.link].state == LinkState::Up
                && !matches!(
                    d.status.phase,
                    Phase::Offline | Phase::Probing | Phase::Failed
                )
        });
        !waiting && self.links.iter().all(|l| l.link.flushed())
    }

    /// The devices whose safe action was not confirmed on the wire (managed devices with a
    /// safe action), with why: `None` means it got no confirmation in time.
    pub fn unconfirmed(&self) -> impl Iterator<Item = (usize, Unconfirmed)> + '_ {
        self.devices.iter().enumerate().filter_map(|(i, d)| {
            // A device that never came up drives nothing: it owes no safe action.
            if d.safe.is_none()
                || !d.status.managed()
                || d.status.safe == SafeProgress::Confirmed
                || !d.ever_up
            {
                return None;
            }
            let why = if self.links[d.link].state != LinkState::Up {
                Unconfirmed::BusDown
            } else if matches!(
                d.status.phase,
                Phase::Offline | Phase::Probing | Phase::Failed
            ) {
                Unconfirmed::NotUp
            } else {
                Unconfirmed::NoAnswer
            };
            Some((i, why))
        })
    }

    /// Devices without a lifecycle that have a safe action (sent, never confirmed).
    pub fn unmanaged_with_safe_action(&self) -> usize {
        self.devices
            .iter()
            .filter(|d| d.safe.is_some() && !d.status.managed())
            .count()
    }

    /// Orderly stop, last step: quiet every hardware.
    pub fn shutdown_hardware(&mut self) {
        for l in &mut self.links {
            l.link.shutdown();
        }
    }

    /// Every event since the last call, oldest first.
    pub fn drain_events(&mut self, mut f: impl FnMut(&Event)) {
        for e in self.events.as_slice() {
            f(e);
        }
        self.events.clear();
    }

    /// Counters since start.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Bus errors: protocol and hardware errors of every link (rejected packets, missing
    /// replies, dropped requests, adapter refusals and timeouts, transport errors), unmatched
    /// replies and queue overflows.
    pub fn bus_errors(&self) -> u64 {
        let c = &self.counters;
        self.links
            .iter()
            .map(|l| l.link.counters().bus_errors())
            .sum::<u64>()
            + c.hw_errors
            + c.unmatched_replies
            + c.overflows
    }

    /// Health of the subsystem's buses and devices, for the stats.
    pub fn health(&self) -> Health {
        let mut h = Health::default();
        for l in &self.links {
            let c = l.link.counters();
            h.outages += c.outages;
            h.late_replies += c.protocol.late_replies;
            h.links_down += u32::from(l.state != LinkState::Up);
        }
        for d in &self.devices {
            h.devices += 1;
            // A device without a lifecycle (simulated) drives whenever it is not tripped.
            h.enabled += u32::from(match d.status.phase {
                Phase::Enabled => true,
                Phase::Unmanaged => !d.status.tripped,
                _ => false,
            });
            h.tripped += u32::from(d.status.tripped);
            h.faulted += u32::from(d.status.fault != 0);
        }
        h
    }

    /// States currently flagged stale.
    pub fn stale_states(&self) -> u32 {
        self.states.iter().filter(|s| s.stale).count() as u32
    }

    /// Whether the watchdog has fired and no frame has arrived since.
    pub fn watchdog_tripped(&self) -> bool {
        self.watchdog.tripped
    }

    /// Every device's status (as of the end of the last tick).
    pub fn device_status(&self) -> impl Iterator<Item = DeviceStatus> + '_ {
        self.devices.iter().map(|d| d.status)
    }

    /// Whether every device has finished its bring-up (enabled, limp, or failed).
    pub fn settled(&self) -> bool {
        self.started && self.devices.iter().all(|d| d.status.phase.is_settled())
    }

    /// One line describing device `i` (model, read layout, configuration); off the RT path.
    pub fn describe(&self, i: usize) -> String {
        self.devices[i].dev.describe()
    }

    /// Each link's state.
    pub fn link_states(&self) -> impl Iterator<Item = LinkState> + '_ {
        self.links.iter().map(|l| l.state)
    }
}

/// Why a safe action could not be confirmed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unconfirmed {
    /// Its bus is gone.
    BusDown,
    /// The device is not up (never answered, or being brought up again).
    NotUp,
    /// It did not confirm within the time allowed.
    NoAnswer,
}

/// Health of a subsystem's buses and devices.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Health {
    /// Times a bus vanished.
    pub outages: u64,
    /// Late replies (counted and dropped).
    pub late_replies: u64,
    /// Buses down now.
    pub links_down: u32,
    /// Devices.
    pub devices: u32,
    /// Devices driving: enabled, or without a lifecycle and not tripped.
    pub enabled: u32,
    /// Devices tripped.
    pub tripped: u32,
    /// Devices reporting a fault.
    pub faulted: u32,
}

/// Queue sizes per link, from the manifest: how many requests its devices can queue between two
/// protocol ticks.
fn capacities(sub: &Subsystem) -> Vec<Capacity> {
    sub.protocols
        .iter()
        .enumerate()
        .map(|(pi, p)| {
            let devs: Vec<_> = sub.devices.iter().filter(|d| d.protocol == pi).collect();
            let requests: usize = devs
                .iter()
                .map(|d| {
                    let ticks = u64::from(p.divisor).div_ceil(u64::from(d.divisor)) as usize;
                    per_device_tick(d.channels.len()) * ticks
                })
                .sum::<usize>()
                + 16;
            Capacity {
                words: 32 * requests + 256,
                in_flight: 4 * requests,
                devices: devs.len().max(1),
            }
        })
        .collect()
}

/// Where a simulated state starts: 0 when the limits allow it, else the middle of finite
/// limits, else the finite one.
fn rest(min: f64, max: f64) -> f64 {
    if (min..=max).contains(&0.0) {
        0.0
    } else if min.is_finite() && max.is_finite() {
        min + (max - min) / 2.0
    } else if min.is_finite() {
        min
    } else {
        max
    }
}
