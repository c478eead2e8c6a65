//! The owner side, used by executors: publish states, notify ticks, drain commands, publish stats.
//!
//! Everything is created up front; the per-tick calls (`publish`, `notify_tick`, `drain`,
//! `StatsPublisher::publish`) loan fixed-size samples from iceoryx2's pre-allocated shared
//! memory and never allocate on the heap (checked by the counting-allocator test).

use core::time::Duration;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;

use iceoryx2::prelude::{AttributeSpecifier, PortFactory as _};

use crate::abi::{CommandFrame, ExecutorStats, StateSample};
use crate::bus::{notifier, qos, Bus, EventService, StateService};
use crate::clock::monotonic_ns;
use crate::error::{BusError, Result};
use crate::metadata::{
    base_attributes, command_attributes, state_attributes, ServiceKind, StateMeta,
};
use crate::naming;
use crate::snapshot::{SnapshotWriter, NOT_YET};
use crate::variant::RtIpc;

/// Declaration of one state an executor owns.
#[derive(Debug, Clone)]
pub struct StateSpec {
    /// State name (unique within the subsystem).
    pub name: String,
    /// Metadata published as service attributes. `meta.index` must equal the position of this
    /// spec in the list given to [`StatePublisher::create`].
    pub meta: StateMeta,
    /// Maximum per-subscriber queue depth a client may ask for.
    pub buffer: usize,
}

impl StateSpec {
    /// A spec with the default subscriber buffer.
    pub fn new(name: impl Into<String>, meta: StateMeta) -> Self {
        Self {
            name: name.into(),
            meta,
            buffer: qos::STATE_BUFFER,
        }
    }

    /// One spec per name with the default buffer, numbered in order (`meta.index` = position,
    /// as [`StatePublisher::create`] requires) and otherwise `meta`.
    pub fn numbered<N: Into<String>>(
        names: impl IntoIterator<Item = N>,
        meta: &StateMeta,
    ) -> Vec<Self> {
        names
            .into_iter()
            .enumerate()
            .map(|(i, name)| {
                let meta = StateMeta {
                    index: i as u32,
                    ..meta.clone()
                };
                Self::new(name, meta)
            })
            .collect()
    }
}

/// Publishes every state of one subsystem, its snapshot and its tick event.
///
/// Two ways to publish a tick: [`publish_at`](Self::publish_at) each state then
/// [`notify_tick`](Self::notify_tick) (snapshot, then tick event), or, what an executor does,
/// [`stage_at`](Self::stage_at) each state, [`flush_states`](Self::flush_states), which sends the
/// snapshot first, so a snapshot reader does not wait for the per-state services, then
/// `notify_tick`.
pub struct StatePublisher {
    subsystem: String,
    ports: Vec<Publisher<RtIpc, StateSample, ()>>,
    seqs: Vec<u64>,
    /// Every state's last sample, by index: the snapshot.
    latest: Vec<StateSample>,
    /// Indices staged since the last flush, each once (`is_staged`).
    staged: Vec<usize>,
    is_staged: Vec<bool>,
    snapshot: SnapshotWriter,
    /// States were published since the last snapshot: `notify_tick` sends one first.
    snapshot_due: bool,
    notifier: Notifier<RtIpc>,
    // Keep the services alive for as long as we publish on them.
    _services: Vec<StateService>,
    _tick: EventService,
}

impl core::fmt::Debug for StatePublisher {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("StatePublisher")
            .field("subsystem", &self.subsystem)
            .field("states", &self.ports.len())
            .finish()
    }
}

impl StatePublisher {
    /// Creates the services `conductor/<subsystem>/<state>` for every spec, and the tick event.
    pub fn create(bus: &Bus, subsystem: &str, specs: &[StateSpec]) -> Result<Self> {
        naming::validate("subsystem", subsystem)?;
        let mut services = Vec::with_capacity(specs.len());
        let mut ports = Vec::with_capacity(specs.len());
        for (i, spec) in specs.iter().enumerate() {
            naming::validate("state", &spec.name)?;
            if spec.meta.index as usize != i {
                return Err(BusError::InvalidName {
                    what: "state",
                    name: spec.name.clone(),
                    reason: "meta.index must equal the state's position in the subsystem",
                });
            }
            let name = naming::state(subsystem, &spec.name);
            let attrs = state_attributes(&spec.meta)?;
            let service = bus.create_or_reopen_pubsub::<StateSample>(&name, &attrs, |b| {
                qos::state_service(b, spec.buffer)
            })?;
            let port = service
                .publisher_builder()
                .create()
                .map_err(|e| BusError::iceoryx(format!("publisher for {name:?}"), e))?;
            services.push(service);
            ports.push(port);
        }
        let snapshot = SnapshotWriter::create(bus, subsystem, ports.len())?;
        let tick = bus.tick_event(subsystem)?;
        let notifier = notifier(&tick, "tick notifier")?;
        let n = ports.len();
        Ok(Self {
            subsystem: subsystem.into(),
            seqs: vec![0; n],
            latest: vec![NOT_YET; n],
            staged: Vec::with_capacity(n),
            is_staged: vec![false; n],
            snapshot,
            snapshot_due: false,
            ports,
            notifier,
            _services: services,
            _tick: tick,
        })
    }

    /// Number of states.
    pub fn len(&self) -> usize {
        self.ports.len()
    }

    /// Whether the subsystem has no states.
    pub fn is_empty(&self) -> bool {
        self.ports.is_empty()
    }

    /// The subsystem name.
    pub fn subsystem(&self) -> &str {
        &self.subsystem
    }

    /// Publishes a sample of state `index`; `seq` and `t_publish_ns` (now) are filled in here.
    /// Returns the number of subscribers reached.
    #[inline]
    pub fn publish(
        &mut self,
        index: usize,
        tick: u64,
        t_sample_ns: u64,
        value: f64,
        status: u32,
    ) -> Result<usize> {
        self.publish_at(index, tick, t_sample_ns, value, status, monotonic_ns())
    }

    /// [`publish`](Self::publish) with the caller's `t_publish_ns`: an executor reads the clock
    /// once per tick, just before it publishes the tick's first state, and stamps every state
    /// of the tick with it (`bus/ABI.md`), rather than once per state.
    #[inline]
    pub fn publish_at(
        &mut self,
        index: usize,
        tick: u64,
        t_sample_ns: u64,
        value: f64,
        status: u32,
        t_publish_ns: u64,
    ) -> Result<usize> {
        self.record(index, tick, t_sample_ns, value, status, t_publish_ns)?;
        self.snapshot_due = true;
        self.send_state(index)
    }

    /// Records a sample of state `index` for the tick that [`flush_states`](Self::flush_states)
    /// sends; `seq` is assigned here. Staging a state twice in a tick sends its last sample.
    #[inline]
    pub fn stage_at(
        &mut self,
        index: usize,
        tick: u64,
        t_sample_ns: u64,
        value: f64,
        status: u32,
        t_publish_ns: u64,
    ) -> Result<()> {
        self.record(index, tick, t_sample_ns, value, status, t_publish_ns)?;
        if let Some(staged @ false) = self.is_staged.get_mut(index) {
            *staged = true;
            self.staged.push(index);
        }
        Ok(())
    }

    /// Sends the staged tick: the snapshot (and its event) first, then each staged state's
    /// sample; [`notify_tick`](Self::notify_tick) comes after. Nothing is sent when nothing was
    /// staged. A failed send does not stop the others; it is counted in the result.
    #[inline]
    pub fn flush_states(&mut self) -> Flushed {
        let mut out = Flushed::default();
        if self.staged.is_empty() {
            return out;
        }
        self.snapshot_due = false;
        if self.snapshot.send(&self.latest).is_err() {
            out.errors += 1;
        }
        for k in 0..self.staged.len() {
            let index = self.staged[k];
            self.is_staged[index] = false;
            match self.send_state(index) {
                Ok(_) => out.published += 1,
                Err(_) => out.errors += 1,
            }
        }
        self.staged.clear();
        out
    }

    fn record(
        &mut self,
        index: usize,
        tick: u64,
        t_sample_ns: u64,
        value: f64,
        status: u32,
        t_publish_ns: u64,
    ) -> Result<()> {
        let (Some(seq), Some(latest)) = (self.seqs.get_mut(index), self.latest.get_mut(index))
        else {
            return Err(BusError::NoSuchIndex {
                index,
                count: self.ports.len(),
            });
        };
        *latest = StateSample {
            seq: *seq,
            tick,
            t_sample_ns,
            t_publish_ns,
            value,
            status,
            reserved: 0,
        };
        *seq += 1;
        Ok(())
    }

    /// Sends state `index`'s recorded sample on its own service.
    #[inline]
    fn send_state(&mut self, index: usize) -> Result<usize> {
        let (port, sample) = (&self.ports[index], self.latest[index]);
        port.loan_uninit()
            .map_err(|e| BusError::iceoryx("loaning a state sample", e))?
            .write_payload(sample)
            .send()
            .map_err(|e| BusError::iceoryx("sending a state sample", e))
    }

    /// Number of subscribers currently attached to state `index` (0 if out of range).
    pub fn subscribers(&self, index: usize) -> usize {
        self._services
            .get(index)
            .map_or(0, |s| s.dynamic_config().number_of_subscribers())
    }

    /// Wakes every tick listener once; call after the batch of a tick is published. States
    /// published with `publish_at` since the last snapshot are first sent as one.
    #[inline]
    pub fn notify_tick(&mut self) -> Result<usize> {
        let snapshot = if core::mem::take(&mut self.snapshot_due) {
            self.snapshot.send(&self.latest).map(drop)
        } else {
            Ok(())
        };
        let woken = self
            .notifier
            .notify()
            .map_err(|e| BusError::iceoryx("notifying tick", e))?;
        snapshot?;
        Ok(woken)
    }
}

/// What [`StatePublisher::flush_states`] sent.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Flushed {
    /// State samples sent on their own services.
    pub published: usize,
    /// Sends (snapshot, state samples) that failed.
    pub errors: u64,
}

/// Receives the command frames of one subsystem.
pub struct CommandReceiver {
    port: Subscriber<RtIpc, CommandFrame, ()>,
    _service:
        iceoryx2::service::port_factory::publish_subscribe::PortFactory<RtIpc, CommandFrame, ()>,
}

impl core::fmt::Debug for CommandReceiver {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("CommandReceiver")
    }
}

impl CommandReceiver {
    /// Creates `conductor/<subsystem>/commands` (owner side) without saying whether the owner
    /// runs a command watchdog (no `conductor.watchdog_ms` attribute).
    pub fn create(bus: &Bus, subsystem: &str) -> Result<Self> {
        Self::create_with(bus, subsystem, base_attributes(ServiceKind::Commands)?)
    }

    /// Creates `conductor/<subsystem>/commands` for an owner whose command watchdog fires after
    /// `watchdog` without a command (`None`: no watchdog); the period is published as the
    /// service's `conductor.watchdog_ms` attribute, so clients can read the contract.
    pub fn with_watchdog(bus: &Bus, subsystem: &str, watchdog: Option<Duration>) -> Result<Self> {
        Self::create_with(bus, subsystem, command_attributes(watchdog)?)
    }

    fn create_with(bus: &Bus, subsystem: &str, attrs: AttributeSpecifier) -> Result<Self> {
        naming::validate("subsystem", subsystem)?;
        let name = naming::commands(subsystem);
        let service = bus.create_or_reopen_pubsub::<CommandFrame>(&name, &attrs, |b| {
            b.max_publishers(qos::COMMAND_PUBLISHERS)
                .max_subscribers(qos::COMMAND_SUBSCRIBERS)
                .max_nodes(qos::MAX_NODES)
                .history_size(0)
                .subscriber_max_buffer_size(qos::COMMAND_BUFFER)
                .enable_safe_overflow(true)
        })?;
        let port = service
            .subscriber_builder()
            .buffer_size(qos::COMMAND_BUFFER)
            .create()
            .map_err(|e| BusError::iceoryx("command subscriber", e))?;
        Ok(Self {
            port,
            _service: service,
        })
    }

    /// Hands every queued frame, oldest first, to `apply` (zero-copy: the frame stays in shared
    /// memory). Returns the number of frames drained.
    #[inline]
    pub fn drain(&mut self, mut apply: impl FnMut(&CommandFrame)) -> Result<usize> {
        let mut n = 0;
        loop {
            match self.port.receive() {
                Ok(Some(frame)) => {
                    apply(&frame);
                    n += 1;
                }
                Ok(None) => return Ok(n),
                Err(e) => return Err(BusError::iceoryx("receiving commands", e)),
            }
        }
    }
}

/// Publishes [`ExecutorStats`] on `conductor/<subsystem>/stats`.
pub struct StatsPublisher {
    port: Publisher<RtIpc, ExecutorStats, ()>,
    _service:
        iceoryx2::service::port_factory::publish_subscribe::PortFactory<RtIpc, ExecutorStats, ()>,
}

impl core::fmt::Debug for StatsPublisher {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("StatsPublisher")
    }
}

impl StatsPublisher {
    /// Creates the stats service of `subsystem`.
    pub fn create(bus: &Bus, subsystem: &str) -> Result<Self> {
        naming::validate("subsystem", subsystem)?;
        let name = naming::stats(subsystem);
        let attrs = base_attributes(ServiceKind::Stats)?;
        let service = bus.create_or_reopen_pubsub::<ExecutorStats>(&name, &attrs, |b| {
            b.max_publishers(2)
                .max_subscribers(qos::STATS_SUBSCRIBERS)
                .max_nodes(qos::MAX_NODES)
                .history_size(1)
                .subscriber_max_buffer_size(4)
                .enable_safe_overflow(true)
        })?;
        let port = service
            .publisher_builder()
            .create()
            .map_err(|e| BusError::iceoryx("stats publisher", e))?;
        Ok(Self {
            port,
            _service: service,
        })
    }

    /// Publishes a stats snapshot (written straight into shared memory).
    pub fn publish(&mut self, fill: impl FnOnce(&mut ExecutorStats)) -> Result<()> {
        let sample = self
            .port
            .loan_uninit()
            .map_err(|e| BusError::iceoryx("loaning stats", e))?;
        let mut stats = ExecutorStats::default();
        fill(&mut stats);
        sample
            .write_payload(stats)
            .send()
            .map_err(|e| BusError::iceoryx("sending stats", e))?;
        Ok(())
    }
}

/// Keeps a tick listener type in scope for the client module.
pub(crate) type TickListener = Listener<RtIpc>;
