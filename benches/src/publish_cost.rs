//! The CPU cost of publishing states in one process: a raw iceoryx2 publish of the state payload
//! with the states' own service configuration (the denominator of the executor's per-state
//! cost) beside [`StatePublisher::publish`], per state and per tick of N states plus the tick
//! event. Used by the `state_publish` criterion bench and by `conductor bench` (same run as
//! the stress test, so the ratio compares like with like).
//!
//! Both paths use the same variant ([`RtIpc`]), payload ([`StateSample`]), settings
//! ([`qos::state_service`] with the default state buffer, [`qos::tick_event`]) and the same
//! subscribers: `subscribers` per state in this process, drained between timed batches (the
//! drain is not timed), and one tick listener when there are subscribers.

use std::time::Instant;

use conductor_bus::{
    monotonic_ns, qos, Bus, Domain, RtIpc, StateMeta, StatePublisher, StateSample, StateSpec,
    StateSubscriber, TickWaiter,
};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

use crate::pingpong::{raw_publish, raw_state_service, PingPongError};

/// Ticks published between two (untimed) drains of the subscribers: below the state buffer, so
/// no subscriber queue overflows.
pub const BATCH: u64 = 128;

/// Which path a [`PublishRig`] times.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Path {
    /// Raw iceoryx2: one clock read per tick, then loan, write in place, send per state; raw
    /// event notify.
    Raw,
    /// `StatePublisher::publish_at` with one clock read per tick (what the executor does), and
    /// `notify_tick`.
    State,
    /// `StatePublisher::publish` (a clock read per state), and `notify_tick`.
    StateClockPerState,
    /// What the executor does: `StatePublisher::stage_at` every state with one clock read per
    /// tick, `flush_states` (the subsystem's snapshot, then every state), and `notify_tick`.
    Staged,
}

impl Path {
    /// Every path, the floor first.
    pub const ALL: [Path; 4] = [
        Path::Raw,
        Path::State,
        Path::StateClockPerState,
        Path::Staged,
    ];

    /// `raw`, `state` or `state-clock-per-state`.
    pub fn name(self) -> &'static str {
        match self {
            Path::Raw => "raw",
            Path::State => "state",
            Path::StateClockPerState => "state-clock-per-state",
            Path::Staged => "staged",
        }
    }
}

type RawService =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<RtIpc, StateSample, ()>;

/// N states published both ways, with their subscribers.
pub struct PublishRig {
    states: usize,
    raw: Vec<Publisher<RtIpc, StateSample, ()>>,
    raw_subs: Vec<Subscriber<RtIpc, StateSample, ()>>,
    notifier: Notifier<RtIpc>,
    listener: Option<Listener<RtIpc>>,
    state: StatePublisher,
    state_subs: Vec<StateSubscriber>,
    tick: Option<TickWaiter>,
    seq: u64,
    _raw_services: Vec<RawService>,
    _event: iceoryx2::service::port_factory::event::PortFactory<RtIpc>,
    _bus: Bus,
    _node: Node<RtIpc>,
}

impl core::fmt::Debug for PublishRig {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("PublishRig")
            .field("states", &self.states)
            .field("subscribers", &self.raw_subs.len())
            .finish()
    }
}

fn iox(what: &'static str) -> impl FnOnce(String) -> PingPongError {
    move |e| PingPongError::Iox(format!("{what}: {e}"))
}

impl PublishRig {
    /// `states` states (at least 1), `subscribers` subscribers to each, in a fresh domain.
    pub fn new(states: usize, subscribers: usize) -> Result<Self, PingPongError> {
        let states = states.max(1);
        conductor_bus::prepare_thread();
        let d = Domain::unique("benchpub")?;
        let node = NodeBuilder::new()
            .config(d.iceoryx2_config())
            .create::<RtIpc>()
            .map_err(|e| iox("node")(e.to_string()))?;
        let mut services = Vec::with_capacity(states);
        let mut raw = Vec::with_capacity(states);
        let mut raw_subs = Vec::new();
        for i in 0..states {
            let svc = raw_state_service(&node, &format!("rawpub/s{i}"), qos::STATE_BUFFER)?;
            raw.push(
                svc.publisher_builder()
                    .create()
                    .map_err(|e| iox("publisher")(e.to_string()))?,
            );
            for _ in 0..subscribers {
                raw_subs.push(
                    svc.subscriber_builder()
                        .buffer_size(qos::STATE_BUFFER)
                        .create()
                        .map_err(|e| iox("subscriber")(e.to_string()))?,
                );
            }
            services.push(svc);
        }
        let sn: ServiceName = "rawpub/tick"
            .try_into()
            .map_err(|e| iox("service name")(format!("{e:?}")))?;
        let event = qos::tick_event(node.service_builder(&sn).event())
            .open_or_create()
            .map_err(|e| iox("event")(e.to_string()))?;
        let notifier = event
            .notifier_builder()
            .create()
            .map_err(|e| iox("notifier")(e.to_string()))?;
        let listener = if subscribers > 0 {
            Some(
                event
                    .listener_builder()
                    .create()
                    .map_err(|e| iox("listener")(e.to_string()))?,
            )
        } else {
            None
        };

        let bus = Bus::open(&d, "benchpub")?;
        let names: Vec<String> = (0..states).map(|i| format!("s{i}")).collect();
        let state = StatePublisher::create(
            &bus,
            "pub",
            &StateSpec::numbered(names.iter().cloned(), &StateMeta::default()),
        )?;
        let mut state_subs = Vec::new();
        for n in &names {
            for _ in 0..subscribers {
                state_subs.push(StateSubscriber::with_buffer(
                    &bus,
                    &format!("pub/{n}"),
                    qos::STATE_BUFFER,
                )?);
            }
        }
        let tick = if subscribers > 0 {
            Some(TickWaiter::new(&bus, "pub")?)
        } else {
            None
        };
        Ok(Self {
            states,
            raw,
            raw_subs,
            notifier,
            listener,
            state,
            state_subs,
            tick,
            seq: 0,
            _raw_services: services,
            _event: event,
            _bus: bus,
            _node: node,
        })
    }

    /// Number of states.
    pub fn states(&self) -> usize {
        self.states
    }

    /// Publishes one sample of every state along `path`; with `notify`, then the tick event.
    #[inline]
    pub fn tick(&mut self, path: Path, notify: bool) -> Result<(), PingPongError> {
        self.seq += 1;
        let v = self.seq as f64;
        match path {
            Path::Raw => {
                let t = monotonic_ns();
                for p in &self.raw {
                    raw_publish(p, self.seq, v, t)?;
                }
                if notify {
                    self.notifier
                        .notify()
                        .map_err(|e| iox("notify")(e.to_string()))?;
                }
            }
            Path::State => {
                let t = monotonic_ns();
                for i in 0..self.states {
                    self.state.publish_at(i, self.seq, self.seq, v, 0, t)?;
                }
                if notify {
                    self.state.notify_tick()?;
                }
            }
            Path::StateClockPerState => {
                for i in 0..self.states {
                    self.state.publish(i, self.seq, self.seq, v, 0)?;
                }
                if notify {
                    self.state.notify_tick()?;
                }
            }
            Path::Staged => {
                let t = monotonic_ns();
                for i in 0..self.states {
                    self.state.stage_at(i, self.seq, self.seq, v, 0, t)?;
                }
                let sent = self.state.flush_states();
                if sent.errors > 0 {
                    return Err(iox("flush")(format!("{} sends failed", sent.errors)));
                }
                if notify {
                    self.state.notify_tick()?;
                }
            }
        }
        Ok(())
    }

    /// Empties every subscriber queue and consumes the tick events (not part of any timing).
    pub fn drain(&mut self) -> Result<(), PingPongError> {
        for s in &self.raw_subs {
            while s
                .receive()
                .map_err(|e| iox("receive")(e.to_string()))?
                .is_some()
            {}
        }
        for s in &mut self.state_subs {
            while s.receive()?.is_some() {}
        }
        if let Some(l) = &self.listener {
            l.try_wait(|_| {})
                .map_err(|e| iox("listener")(e.to_string()))?;
        }
        if let Some(t) = &mut self.tick {
            t.try_consume()?;
        }
        Ok(())
    }

    /// Times `ticks` ticks along `path` in batches of [`BATCH`], draining between batches;
    /// returns the nanoseconds spent publishing (drains excluded).
    pub fn time(&mut self, path: Path, notify: bool, ticks: u64) -> Result<u64, PingPongError> {
        let mut spent = 0u64;
        let mut left = ticks;
        while left > 0 {
            let n = left.min(BATCH);
            let t0 = Instant::now();
            for _ in 0..n {
                self.tick(path, notify)?;
            }
            spent += t0.elapsed().as_nanos() as u64;
            self.drain()?;
            left -= n;
        }
        Ok(spent)
    }
}

/// One path's cost per published state, median over rounds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PublishCost {
    /// The path.
    pub path: Path,
    /// Median ns per state sample published (loan + write + send), no tick event.
    pub per_state_ns: f64,
    /// Median ns per tick of all the rig's states plus the tick event.
    pub per_tick_ns: f64,
}

/// The cost of every [`Path`] for `states` states with `subscribers` each, measured
/// interleaved (`rounds` rounds of `ticks` ticks per path, medians), so all see the same
/// machine. In [`Path::ALL`] order.
pub fn measure(
    states: usize,
    subscribers: usize,
    ticks: u64,
    rounds: usize,
) -> Result<Vec<PublishCost>, PingPongError> {
    let mut rig = PublishRig::new(states, subscribers)?;
    let ticks = ticks.max(1);
    // Warm up every path (first touches of every sample slot).
    for p in Path::ALL {
        rig.time(p, true, 2 * BATCH)?;
    }
    let n = rig.states() as f64;
    let mut per_state = vec![Vec::new(); Path::ALL.len()];
    let mut per_tick = vec![Vec::new(); Path::ALL.len()];
    for _ in 0..rounds.max(1) {
        for (k, p) in Path::ALL.into_iter().enumerate() {
            per_state[k].push(rig.time(p, false, ticks)? as f64 / (ticks as f64 * n));
            per_tick[k].push(rig.time(p, true, ticks)? as f64 / ticks as f64);
        }
    }
    Ok(Path::ALL
        .into_iter()
        .zip(per_state.into_iter().zip(per_tick))
        .map(|(path, (s, t))| PublishCost {
            path,
            per_state_ns: median(s),
            per_tick_ns: median(t),
        })
        .collect())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}
