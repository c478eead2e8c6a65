//! [`Executor`]: one subsystem's [`Stages`] attached to the bus — command frames in, state
//! samples, the tick event and health statistics out — and [`run`], its deadline loop.

use std::sync::atomic::AtomicBool;

use conductor_bus::{
    monotonic_ns, Bus, BusError, CommandReceiver, ExecutorStats, Histogram, StateMeta,
    StatePublisher, StateSpec, StatsPublisher,
};
use conductor_devices::kinds::BuildError;
use conductor_devices::TickCtx;

use crate::events::{EventLog, Names};
use crate::profile::{TickPhase, TickProfile};
use crate::rt::RtStatus;
use crate::schedule::{sleep_until, Schedule, Wake};
use crate::stages::{Stages, Unconfirmed};
use conductor_manifest::Subsystem;

/// Stats are published about this often.
pub const STATS_INTERVAL_NS: u64 = 100_000_000;

/// Why an executor could not start.
#[derive(Debug, thiserror::Error)]
pub enum ExecutorError {
    /// The bus refused a service.
    #[error("bus: {0}")]
    Bus(#[from] BusError),
    /// A component could not be built (a port that cannot be opened, ...).
    #[error("building the components: {0}")]
    Build(#[from] BuildError),
}

/// Health figures kept by the loop.
#[derive(Debug, Clone, Default)]
struct Health {
    ticks: u64,
    misses: u64,
    hist: Histogram,
    publish_errors: u64,
    command_errors: u64,
    stats_seq: u64,
    next_stats_ns: u64,
    last_stats_ticks: u64,
    last_stats_ns: u64,
}

/// A subsystem on the bus.
pub struct Executor {
    rate_hz: f64,
    stages: Stages,
    publisher: StatePublisher,
    commands: CommandReceiver,
    stats: StatsPublisher,
    health: Health,
    rt: RtStatus,
    states: u32,
    events: EventLog,
    names: Names,
    optional: Vec<bool>,
    /// During bring-up, each device's phases are told once, at its end, not one by one.
    bringing_up: bool,
}

/// How a stop went.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StopReport {
    /// One line per device whose safe action was not confirmed on the wire.
    pub unconfirmed: Vec<String>,
    /// Devices whose safe action was confirmed on the wire.
    pub confirmed: usize,
    /// Devices without a lifecycle (simulated channels) whose safe action was sent; there is
    /// nothing to confirm it with.
    pub sent: usize,
}

/// How the bring-up went.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct BringUp {
    /// Non-optional devices that could not be brought up, one line each: the executor must
    /// not run.
    pub failed: Vec<String>,
    /// Optional devices that did not come up (their states stay STALE; they are looked for
    /// again every second), one line each.
    pub missing: Vec<String>,
    /// One line per device that is up: model, read layout, configuration.
    pub up: Vec<String>,
    /// Whether every device settled before the time allowed ran out.
    pub settled: bool,
}

impl core::fmt::Debug for Executor {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Executor")
            .field("subsystem", &self.publisher.subsystem())
            .field("stages", &self.stages)
            .finish()
    }
}

/// The bus declaration of every state of `sub` (metadata as service attributes).
pub fn state_specs(sub: &Subsystem) -> Vec<StateSpec> {
    sub.states
        .iter()
        .enumerate()
        .map(|(i, s)| StateSpec {
            name: s.name.clone(),
            meta: StateMeta {
                index: i as u32,
                units: s.units.clone(),
                writable: s.writable,
                rate_hz: sub.rate_of(s.divisor),
                min: s.min,
                max: s.max,
                device: sub.devices[s.device].name.clone(),
            },
            buffer: s.history,
        })
        .collect()
}

impl Executor {
    /// Builds the components of `sub` and creates its services on `bus`.
    pub fn new(bus: &Bus, sub: &Subsystem) -> Result<Self, ExecutorError> {
        let stages = Stages::new(sub)?;
        Self::with_stages(bus, sub, stages)
    }

    /// Attaches already-built stages to the bus.
    pub fn with_stages(bus: &Bus, sub: &Subsystem, stages: Stages) -> Result<Self, ExecutorError> {
        let publisher = StatePublisher::create(bus, &sub.name, &state_specs(sub))?;
        let watchdog = sub.watchdog_ns.map(std::time::Duration::from_nanos);
        let commands = CommandReceiver::with_watchdog(bus, &sub.name, watchdog)?;
        let stats = StatsPublisher::create(bus, &sub.name)?;
        let names = Names::of(sub);
        Ok(Self {
            rate_hz: sub.rate_hz,
            stages,
            publisher,
            commands,
            stats,
            health: Health::default(),
            rt: RtStatus::default(),
            states: sub.states.len() as u32,
            events: EventLog::spawn(names.clone()),
            names,
            optional: sub.devices.iter().map(|d| d.optional).collect(),
            bringing_up: false,
        })
    }

    /// Records what the real-time set-up achieved (reported in the stats).
    pub fn set_rt_status(&mut self, rt: RtStatus) {
        self.rt = rt;
    }

    /// One base tick: drain and apply command frames, run the stages, publish what they produced,
    /// notify the tick event, and publish stats when due. Allocation-free.
    pub fn tick(&mut self, wake: &Wake, now_ns: u64) {
        self.stages.profile_mut().begin();
        let h = &mut self.health;
        h.ticks += 1;
        h.misses += wake.skipped;
        h.hist.record(wake.late_ns);

        let stages = &mut self.stages;
        if self
            .commands
            .drain(|f| stages.apply_frame(f.setpoints(), wake.sched_ns))
            .is_err()
        {
            h.command_errors += 1;
        }
        stages.profile_mut().mark(TickPhase::Commands);
        let publisher = &mut self.publisher;
        let mut errors = 0;
        // One clock read per tick: every state of the tick carries the time its first state
        // was published (bus/ABI.md, `t_publish_ns`). Staged, not sent: the flush sends the
        // subsystem's snapshot first, then the per-state samples; the tick event follows.
        let mut t_publish_ns = 0;
        let ticked = stages.tick(wake.slot, wake.sched_ns, now_ns, |p| {
            if t_publish_ns == 0 {
                t_publish_ns = monotonic_ns();
            }
            if publisher
                .stage_at(
                    p.index,
                    p.tick,
                    p.t_sample_ns,
                    p.value,
                    p.status,
                    t_publish_ns,
                )
                .is_err()
            {
                errors += 1;
            }
        });
        let flushed = publisher.flush_states();
        h.publish_errors += errors + flushed.errors;
        stages.profile_mut().mark(TickPhase::Publish);
        if ticked > 0 && publisher.notify_tick().is_err() {
            h.publish_errors += 1;
        }
        stages.profile_mut().mark(TickPhase::TickEvent);
        let (events, quiet) = (&mut self.events, self.bringing_up);
        stages.drain_events(|e| {
            let phase = matches!(e, crate::stages::Event::Phase { .. });
            if !(quiet && phase) {
                events.send(e);
            }
        });
        if now_ns >= h.next_stats_ns {
            self.publish_stats(now_ns);
        }
        self.stages.profile_mut().mark(TickPhase::Stats);
    }

    fn publish_stats(&mut self, now_ns: u64) {
        let h = &mut self.health;
        let c = self.stages.counters();
        let dt = now_ns.saturating_sub(h.last_stats_ns);
        let achieved = if h.last_stats_ns > 0 && dt > 0 {
            (h.ticks - h.last_stats_ticks) as f64 * 1e9 / dt as f64
        } else {
            0.0
        };
        h.stats_seq += 1;
        let (seq, ticks, misses) = (h.stats_seq, h.ticks, h.misses);
        let hist = &h.hist;
        let bus_errors = self.stages.bus_errors() + h.publish_errors + h.command_errors;
        let stale = self.stages.stale_states();
        let dev = self.stages.health();
        let (rate, states, rt) = (self.rate_hz, self.states, &self.rt);
        let _ = self.stats.publish(|s: &mut ExecutorStats| {
            s.seq = seq;
            s.t_ns = now_ns;
            s.ticks = ticks;
            s.misses = misses;
            s.base_rate_hz = rate;
            s.achieved_rate_hz = achieved;
            s.lateness_p50_ns = hist.quantile(0.5);
            s.lateness_p99_ns = hist.quantile(0.99);
            s.lateness_p999_ns = hist.quantile(0.999);
            s.lateness_max_ns = hist.max();
            s.bus_errors = bus_errors;
            s.frames_applied = c.frames;
            s.setpoints_rejected = c.rejected;
            s.setpoints_clamped = c.clamped;
            s.watchdog_trips = c.watchdog_trips;
            s.stale_states = stale;
            s.states = states;
            s.rt_active = u32::from(rt.fifo);
            s.cpu = rt.cpu.map_or(-1, |c| c as i32);
            s.bus_outages = dev.outages;
            s.device_faults = c.faults;
            s.late_replies = dev.late_replies;
            s.setpoints_refused = c.refused;
            s.devices = dev.devices;
            s.devices_enabled = dev.enabled;
            s.devices_tripped = dev.tripped;
            s.devices_faulted = dev.faulted;
            s.links_down = dev.links_down;
            s.histogram = *hist.counts();
        });
        h.last_stats_ns = now_ns;
        h.last_stats_ticks = h.ticks;
        h.next_stats_ns = now_ns + STATS_INTERVAL_NS;
    }

    /// Orderly stop: every writable device's safe action is put on the wire ahead of anything
    /// queued, and the executor keeps the buses going (every `period_ns`, at most 5 ms) until
    /// each action is confirmed (answered by the device, acknowledged by the adapter, read
    /// back) or `timeout_ns` has passed; then final stats are published and the hardware is
    /// closed. Reports each device that could not be confirmed.
    pub fn shutdown(&mut self, period_ns: u64, slot: u64, timeout_ns: u64) -> StopReport {
        let t0 = monotonic_ns();
        self.stages.begin_shutdown(TickCtx {
            tick: slot,
            now_ns: t0,
        });
        let never = AtomicBool::new(false);
        let step = period_ns.clamp(500_000, 5_000_000);
        let mut k = 1;
        loop {
            let now = monotonic_ns();
            self.stages.stop_tick(TickCtx {
                tick: slot + k,
                now_ns: now,
            });
            k += 1;
            if self.stages.stopped() || now.saturating_sub(t0) >= timeout_ns {
                break;
            }
            sleep_until(now + step, 0, &never);
        }
        // Off the real-time path now: tell what happened on the way.
        let names = &self.names;
        self.stages
            .drain_events(|e| crate::note!("{}", names.describe(e)));
        let mut report = StopReport {
            unconfirmed: Vec::new(),
            confirmed: 0,
            sent: self.stages.unmanaged_with_safe_action(),
        };
        let unconfirmed: Vec<(usize, Unconfirmed)> = self.stages.unconfirmed().collect();
        for (i, why) in &unconfirmed {
            let who = self.names.device(*i);
            report.unconfirmed.push(format!(
                "{who}: safe action NOT confirmed{}",
                match why {
                    Unconfirmed::BusDown => ": its bus is gone",
                    Unconfirmed::NotUp =>
                        ": the device is not up (it never answered, or is being brought up again)",
                    Unconfirmed::NoAnswer =>
                        " within the time allowed (no answer, no acknowledgement)",
                }
            ));
        }
        report.confirmed = self
            .stages
            .device_status()
            .filter(|s| s.safe == conductor_devices::SafeProgress::Confirmed)
            .count();
        self.stages.shutdown_hardware();
        self.publish_stats(monotonic_ns());
        report
    }

    /// Runs ticks (sleep-based, at the base period) until every device has been brought up
    /// (enabled, limp, or failed), `timeout_ns` has passed, or `stop` is set. Returns the last
    /// slot and what came up.
    pub fn bring_up(
        &mut self,
        period_ns: u64,
        timeout_ns: u64,
        stop: &AtomicBool,
    ) -> (u64, BringUp) {
        let t0 = monotonic_ns();
        self.bringing_up = true;
        let last = run_from(self, period_ns, 0, stop, 0, |x| {
            x.stages.settled() || monotonic_ns().saturating_sub(t0) >= timeout_ns
        });
        self.bringing_up = false;
        let mut b = BringUp {
            settled: self.stages.settled(),
            ..BringUp::default()
        };
        let names = &self.names;
        let statuses: Vec<_> = self.stages.device_status().collect();
        for (i, st) in statuses.iter().enumerate() {
            let who = names.device(i);
            let optional = self.optional.get(i).copied().unwrap_or(false);
            match (st.phase, st.failure) {
                (conductor_devices::Phase::Failed, Some(f))
                | (conductor_devices::Phase::Disabled, Some(f)) => {
                    let line = format!("{who}: {}", names.failure(i, f));
                    if optional {
                        b.missing.push(line);
                    } else {
                        b.failed.push(line);
                    }
                }
                (p, _) if !p.is_settled() => {
                    let line = format!("{who}: still {} when the bring-up time ran out", p.name());
                    if optional {
                        b.missing.push(line);
                    } else {
                        b.failed.push(line);
                    }
                }
                (p, _) if st.managed() => b.up.push(format!(
                    "{who} is {}: {}",
                    p.name(),
                    self.stages.describe(i)
                )),
                _ => {}
            }
        }
        (last, b)
    }

    /// The names events are told with.
    pub fn names(&self) -> &Names {
        &self.names
    }

    /// The stages (tests inspect them).
    pub fn stages(&self) -> &Stages {
        &self.stages
    }

    /// Ticks executed and deadlines missed so far.
    pub fn ticks_and_misses(&self) -> (u64, u64) {
        (self.health.ticks, self.health.misses)
    }

    /// Starts recording the per-phase profile of the ticks from now on (zeroed), or stops it.
    pub fn enable_profile(&mut self, enabled: bool) {
        self.stages.set_profile(TickProfile::new(enabled));
    }

    /// The per-phase profile of the ticks since [`enable_profile`](Self::enable_profile).
    pub fn profile(&self) -> &TickProfile {
        self.stages.profile()
    }

    /// The lateness histogram so far.
    pub fn lateness(&self) -> &Histogram {
        &self.health.hist
    }
}

/// The deadline loop: sleeps until each base deadline (optionally spinning the last `spin_ns`),
/// ticks, and returns the last slot when `stop` is set.
pub fn run(exec: &mut Executor, period_ns: u64, spin_ns: u64, stop: &AtomicBool) -> u64 {
    run_from(exec, period_ns, spin_ns, stop, 0, |_| false)
}

/// [`run`], numbering slots from `first_slot`, until `stop` is set or `done` says so after a
/// tick.
pub fn run_from(
    exec: &mut Executor,
    period_ns: u64,
    spin_ns: u64,
    stop: &AtomicBool,
    first_slot: u64,
    mut done: impl FnMut(&Executor) -> bool,
) -> u64 {
    let mut sched = Schedule::new(monotonic_ns() + period_ns, period_ns);
    let mut slot = first_slot;
    while sleep_until(sched.deadline_ns(), spin_ns, stop) {
        let now = monotonic_ns();
        let mut wake = sched.wake(now);
        wake.slot += first_slot;
        exec.tick(&wake, now);
        slot = wake.slot;
        sched.advance();
        if done(exec) {
            break;
        }
    }
    slot
}
