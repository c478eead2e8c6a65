//! [`Executor`]: one subsystem's [`Stages`] attached to the bus — command frames in, state
//! samples, the tick event and health statistics out — and [`run`], its deadline loop.

use std::sync::atomic::AtomicBool;

use conductor_bus::{
    monotonic_ns, Bus, BusError, CommandReceiver, ExecutorStats, Histogram, StateMeta,
    StatePublisher, StateSpec, StatsPublisher,
};
use conductor_devices::kinds::BuildError;
use conductor_devices::TickCtx;

use crate::manifest::Subsystem;
use crate::rt::RtStatus;
use crate::schedule::{sleep_until, Schedule, Wake};
use crate::stages::Stages;

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
        let commands = CommandReceiver::create(bus, &sub.name)?;
        let stats = StatsPublisher::create(bus, &sub.name)?;
        Ok(Self {
            rate_hz: sub.rate_hz,
            stages,
            publisher,
            commands,
            stats,
            health: Health::default(),
            rt: RtStatus::default(),
            states: sub.states.len() as u32,
        })
    }

    /// Records what the real-time set-up achieved (reported in the stats).
    pub fn set_rt_status(&mut self, rt: RtStatus) {
        self.rt = rt;
    }

    /// One base tick: drain and apply command frames, run the stages, publish what they produced,
    /// notify the tick event, and publish stats when due. Allocation-free.
    pub fn tick(&mut self, wake: &Wake, now_ns: u64) {
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
        let publisher = &mut self.publisher;
        let mut errors = 0;
        let published = stages.tick(wake.slot, wake.sched_ns, now_ns, |p| {
            if publisher
                .publish(p.index, p.tick, p.t_sample_ns, p.value, p.status)
                .is_err()
            {
                errors += 1;
            }
        });
        h.publish_errors += errors;
        if published > 0 && publisher.notify_tick().is_err() {
            h.publish_errors += 1;
        }
        if now_ns >= h.next_stats_ns {
            self.publish_stats(now_ns);
        }
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
            s.histogram = *hist.counts();
        });
        h.last_stats_ns = now_ns;
        h.last_stats_ticks = h.ticks;
        h.next_stats_ns = now_ns + STATS_INTERVAL_NS;
    }

    /// Orderly stop: every writable device's safe action is sent, the links are flushed for a few
    /// base periods, final stats are published and the hardware is quieted.
    pub fn shutdown(&mut self, period_ns: u64, slot: u64) {
        let now = monotonic_ns();
        self.stages.begin_shutdown(TickCtx {
            tick: slot,
            now_ns: now,
        });
        let never = AtomicBool::new(false);
        for i in 0..3 {
            let now = monotonic_ns();
            self.stages.flush_links(TickCtx {
                tick: slot + i,
                now_ns: now,
            });
            sleep_until(now + period_ns.min(10_000_000), 0, &never);
        }
        self.stages.shutdown_hardware();
        self.publish_stats(monotonic_ns());
    }

    /// The stages (tests inspect them).
    pub fn stages(&self) -> &Stages {
        &self.stages
    }

    /// Ticks executed and deadlines missed so far.
    pub fn ticks_and_misses(&self) -> (u64, u64) {
        (self.health.ticks, self.health.misses)
    }

    /// The lateness histogram so far.
    pub fn lateness(&self) -> &Histogram {
        &self.health.hist
    }
}

/// The deadline loop: sleeps until each base deadline (optionally spinning the last `spin_ns`),
/// ticks, and returns the last slot when `stop` is set.
pub fn run(exec: &mut Executor, period_ns: u64, spin_ns: u64, stop: &AtomicBool) -> u64 {
    let mut sched = Schedule::new(monotonic_ns() + period_ns, period_ns);
    let mut slot = 0;
    while sleep_until(sched.deadline_ns(), spin_ns, stop) {
        let now = monotonic_ns();
        let wake = sched.wake(now);
        exec.tick(&wake, now);
        slot = wake.slot;
        sched.advance();
    }
    slot
}
