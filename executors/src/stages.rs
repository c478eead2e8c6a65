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

use conductor_bus::status;
use conductor_devices::kinds::{self, BuildError, Capacity};
use conductor_devices::{
    Bounded, Credential, Device, Link, Reply, Request, SafeAction, TickCtx, Update,
};

use crate::manifest::{Calibration, SafeSpec, Subsystem};

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
}

struct StateRt {
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
    /// Setpoint (device units) waiting for the state's tick.
    pending: Option<f64>,
}

impl StateRt {
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
        s
    }
}

/// Per channel: what the states asked for since the device's last tick.
#[derive(Clone, Copy, Default)]
struct ChannelCache {
    sample: bool,
    write: Option<f64>,
}

struct DeviceRt {
    dev: Box<dyn Device>,
    link: usize,
    divisor: u64,
    cache: Vec<ChannelCache>,
    up: Bounded<Reply>,
    updates: Bounded<Update>,
    channel_state: Vec<Option<usize>>,
    safe: Option<SafeAction>,
}

struct LinkRt {
    link: Box<dyn Link>,
    protocol_divisor: u64,
    hardware_divisor: u64,
    requests: Bounded<Request>,
    replies: Bounded<Reply>,
    creds: Vec<(Credential, usize)>,
    urgent: bool,
}

struct Watchdog {
    timeout_ns: Option<u64>,
    last_frame_ns: Option<u64>,
    tripped: bool,
}

/// A subsystem's components, scheduled tick by tick.
pub struct Stages {
    states: Vec<StateRt>,
    devices: Vec<DeviceRt>,
    links: Vec<LinkRt>,
    watchdog: Watchdog,
    counters: Counters,
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
        for d in &sub.devices {
            devices.push(kinds::build_device(&d.kind, &d.params, d.credential)?);
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
        let mut link_rt: Vec<LinkRt> = links
            .into_iter()
            .zip(&sub.protocols)
            .zip(&caps)
            .map(|((link, p), cap)| LinkRt {
                link,
                protocol_divisor: u64::from(p.divisor),
                hardware_divisor: u64::from(sub.hardware[p.hardware].divisor),
                requests: Bounded::with_capacity(cap.in_flight),
                replies: Bounded::with_capacity(2 * cap.in_flight),
                creds: Vec::with_capacity(cap.devices),
                urgent: false,
            })
            .collect();
        let mut dev_rt = Vec::with_capacity(devices.len());
        for (i, (dev, d)) in devices.into_iter().zip(&sub.devices).enumerate() {
            let channels = d.channels.len();
            let link = &mut link_rt[d.protocol];
            link.creds.push((d.credential, i));
            let ratio = link.protocol_divisor.div_ceil(u64::from(d.divisor)) as usize;
            let up = per_device_tick(channels) * (ratio + 2) * 2;
            let mut channel_state = vec![None; channels];
            for (si, s) in sub.states.iter().enumerate() {
                if s.device == i {
                    channel_state[s.channel] = Some(si);
                }
            }
            let writable = sub.states.iter().any(|s| s.device == i && s.writable);
            let safe = writable.then(|| match d.safe {
                SafeSpec::Hold => SafeAction::Hold,
                SafeSpec::TorqueOff => SafeAction::TorqueOff,
                SafeSpec::Setpoint { state, value } => {
                    let s = &sub.states[state];
                    SafeAction::Setpoint {
                        channel: s.channel,
                        value: s.calibration.to_device(value),
                    }
                }
            });
            dev_rt.push(DeviceRt {
                dev,
                link: d.protocol,
                divisor: u64::from(d.divisor),
                cache: vec![ChannelCache::default(); channels],
                up: Bounded::with_capacity(up),
                updates: Bounded::with_capacity(up * channels.max(1)),
                channel_state,
                safe,
            });
        }
        let states = sub
            .states
            .iter()
            .enumerate()
            .map(|(i, s)| StateRt {
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
                pending: None,
            })
            .collect();
        Self {
            states,
            devices: dev_rt,
            links: link_rt,
            watchdog: Watchdog {
                timeout_ns: sub.watchdog_ns,
                last_frame_ns: None,
                tripped: false,
            },
            counters: Counters::default(),
        }
    }

    /// Applies every setpoint of one command frame at once (thesis `sendCtrl`): each value is
    /// checked (finite, known, writable), clamped to its limits and converted to device units; it
    /// goes downstream at its state's next tick. `sched_ns` is the current tick's scheduled time
    /// (it restarts the watchdog).
    pub fn apply_frame(&mut self, setpoints: &[conductor_bus::Setpoint], sched_ns: u64) {
        self.counters.frames += 1;
        self.watchdog.last_frame_ns = Some(sched_ns);
        if self.watchdog.tripped {
            self.watchdog.tripped = false;
            for s in &mut self.states {
                s.watchdog = false;
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

        // 4–6. Protocol down, hardware, protocol up.
        for l in &mut self.links {
            let proto = l.urgent || tick.is_multiple_of(l.protocol_divisor);
            let hw = l.urgent || tick.is_multiple_of(l.hardware_divisor);
            l.urgent = false;
            if proto {
                l.link.encode(l.requests.as_slice(), ctx);
                l.requests.clear();
            }
            if hw && l.link.exchange(ctx).is_err() {
                self.counters.hw_errors += 1;
            }
            if proto {
                let before = l.replies.overflows();
                l.link.decode(&mut l.replies, ctx);
                self.counters.overflows += l.replies.overflows() - before;
                for r in l.replies.as_slice() {
                    match l.creds.iter().find(|(c, _)| *c == r.cred) {
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
        }

        // 7. Device stage, upstream.
        for d in &mut self.devices {
            if !tick.is_multiple_of(d.divisor) {
                continue;
            }
            let before = d.updates.overflows();
            for r in d.up.as_slice() {
                d.dev.reply(r, &mut d.updates);
            }
            d.up.clear();
            self.counters.overflows += d.updates.overflows() - before;
            for u in d.updates.as_slice() {
                let Some(Some(si)) = d.channel_state.get(u.channel) else {
                    continue;
                };
                let s = &mut self.states[*si];
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
        n
    }

    fn check_watchdog(&mut self, sched_ns: u64, ctx: TickCtx) {
        let w = &mut self.watchdog;
        let (Some(timeout), Some(last)) = (w.timeout_ns, w.last_frame_ns) else {
            return;
        };
        if w.tripped || sched_ns.saturating_sub(last) < timeout {
            return;
        }
        w.tripped = true;
        self.counters.watchdog_trips += 1;
        self.safe_all(ctx, true);
    }

    /// Every writable device's safe action, sent on this tick whatever the stage divisors.
    fn safe_all(&mut self, ctx: TickCtx, flag: bool) {
        for (di, d) in self.devices.iter_mut().enumerate() {
            let Some(action) = d.safe else { continue };
            let l = &mut self.links[d.link];
            // Setpoints still waiting in the caches would undo the safe action.
            for c in &mut d.cache {
                c.write = None;
            }
            let before = l.requests.overflows();
            d.dev.safe(action, ctx, &mut l.requests);
            self.counters.overflows += l.requests.overflows() - before;
            l.urgent = true;
            for s in self.states.iter_mut().filter(|s| s.device == di) {
                s.pending = None;
                if flag {
                    s.watchdog = true;
                }
            }
        }
    }

    /// Orderly stop, step 1: queue every writable device's safe action (flushed by
    /// [`flush_links`](Self::flush_links)).
    pub fn begin_shutdown(&mut self, ctx: TickCtx) {
        self.safe_all(ctx, false);
    }

    /// Encodes, exchanges and decodes on every link now, whatever the divisors (used while
    /// stopping, so that safe actions reach the bus).
    pub fn flush_links(&mut self, ctx: TickCtx) {
        for l in &mut self.links {
            l.link.encode(l.requests.as_slice(), ctx);
            l.requests.clear();
            if l.link.exchange(ctx).is_err() {
                self.counters.hw_errors += 1;
            }
            l.link.decode(&mut l.replies, ctx);
            l.replies.clear();
        }
    }

    /// Orderly stop, last step: quiet every hardware.
    pub fn shutdown_hardware(&mut self) {
        for l in &mut self.links {
            l.link.shutdown();
        }
    }

    /// Counters since start.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Bus errors: protocol errors (rejected packets, missing replies, dropped requests) of every
    /// link, transport errors, unmatched replies and queue overflows.
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

    /// States currently flagged stale.
    pub fn stale_states(&self) -> u32 {
        self.states.iter().filter(|s| s.stale).count() as u32
    }

    /// Whether the watchdog has fired and no frame has arrived since.
    pub fn watchdog_tripped(&self) -> bool {
        self.watchdog.tripped
    }
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
