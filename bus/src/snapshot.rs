//! A subsystem's tick as one sample: `conductor/<subsystem>/snapshot`.
//!
//! Beside each state's own service, the owner publishes every tick one slice of
//! [`StateSample`]s, entry `i` being the state of index `i` as of that tick, and then notifies the
//! event of the same name. A controller of the whole subsystem wakes once, takes one sample and
//! reads every joint of the same tick: one IPC hop instead of one per state, and it does not wait
//! for the per-state services, which the owner publishes after the snapshot (`bus/ABI.md`,
//! *Snapshot*).

use core::ops::Deref;
use core::time::Duration;
use std::time::Instant;

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::FileDescriptorBased;
use iceoryx2::sample::Sample;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;

use crate::abi::{status, StateSample};
use crate::bus::{listener, notifier, qos, Bus, EventService};
use crate::error::{BusError, Result};
use crate::metadata::{base_attributes, ServiceKind};
use crate::naming;
use crate::tick::poll_readable;
use crate::variant::RtIpc;

type SnapshotService = PortFactory<RtIpc, [StateSample], ()>;

/// What a snapshot holds for a state that has not been published yet: no time, no value.
pub const NOT_YET: StateSample = StateSample {
    seq: 0,
    tick: 0,
    t_sample_ns: 0,
    t_publish_ns: 0,
    value: f64::NAN,
    status: status::STALE,
    reserved: 0,
};

/// The owner's side: one slice per tick and the event that announces it. Sized at creation; a
/// send loans, copies and notifies without allocating.
pub(crate) struct SnapshotWriter {
    port: Publisher<RtIpc, [StateSample], ()>,
    notifier: Notifier<RtIpc>,
    _service: SnapshotService,
    _event: EventService,
}

impl SnapshotWriter {
    /// Creates (or, for a restarted owner, re-opens) the snapshot of `subsystem` for `states`
    /// states.
    pub(crate) fn create(bus: &Bus, subsystem: &str, states: usize) -> Result<Self> {
        let name = naming::snapshot(subsystem);
        let attrs = base_attributes(ServiceKind::Snapshot)?;
        let service =
            bus.create_or_reopen_pubsub::<[StateSample]>(&name, &attrs, qos::snapshot_service)?;
        let port = service
            .publisher_builder()
            .initial_max_slice_len(states.max(1))
            .create()
            .map_err(|e| BusError::iceoryx(format!("publisher for {name:?}"), e))?;
        let event = bus.snapshot_event(subsystem)?;
        let notifier = notifier(&event, "snapshot notifier")?;
        Ok(Self {
            port,
            notifier,
            _service: service,
            _event: event,
        })
    }

    /// Publishes `samples` as one snapshot and wakes its listeners.
    #[inline]
    pub(crate) fn send(&mut self, samples: &[StateSample]) -> Result<usize> {
        let sample = self
            .port
            .loan_slice_uninit(samples.len())
            .map_err(|e| BusError::iceoryx("loaning a snapshot", e))?;
        let reached = sample
            .write_from_slice(samples)
            .send()
            .map_err(|e| BusError::iceoryx("sending a snapshot", e))?;
        self.notifier
            .notify()
            .map_err(|e| BusError::iceoryx("notifying a snapshot", e))?;
        Ok(reached)
    }
}

/// One tick of a subsystem, read in place in shared memory: entry `i` is the state of index `i`
/// (the `conductor.index` attribute). A state not published on this tick (a slower rate) keeps
/// its last sample, with its own `tick`; one never published is [`NOT_YET`].
pub struct Snapshot(Sample<RtIpc, [StateSample], ()>);

impl Snapshot {
    /// The tick the snapshot was published on (the newest `tick` of its entries).
    pub fn tick(&self) -> u64 {
        self.iter().map(|s| s.tick).max().unwrap_or(0)
    }
}

impl Deref for Snapshot {
    type Target = [StateSample];

    fn deref(&self) -> &[StateSample] {
        self.0.payload()
    }
}

impl core::fmt::Debug for Snapshot {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Snapshot")
            .field("tick", &self.tick())
            .field("states", &self.len())
            .finish()
    }
}

/// Reads a subsystem's snapshots: sleeps on their event, hands out the newest.
pub struct SnapshotReader {
    port: Subscriber<RtIpc, [StateSample], ()>,
    listener: Listener<RtIpc>,
    _service: SnapshotService,
    _event: EventService,
}

impl core::fmt::Debug for SnapshotReader {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("SnapshotReader")
    }
}

impl SnapshotReader {
    /// Opens the snapshot of `subsystem`, which its owner must have created, queueing at most
    /// two snapshots (a controller takes the newest).
    pub fn new(bus: &Bus, subsystem: &str) -> Result<Self> {
        Self::with_buffer(bus, subsystem, 2)
    }

    /// [`new`](Self::new) with a queue of `buffer` snapshots (1 to
    /// [`qos::SNAPSHOT_BUFFER`]), for a reader that takes every one with
    /// [`receive`](Self::receive).
    pub fn with_buffer(bus: &Bus, subsystem: &str, buffer: usize) -> Result<Self> {
        naming::validate("subsystem", subsystem)?;
        let name = naming::snapshot(subsystem);
        let service =
            bus.open_conductor_pubsub::<[StateSample]>(subsystem, &name, ServiceKind::Snapshot)?;
        let port = service
            .subscriber_builder()
            .buffer_size(buffer.clamp(1, qos::SNAPSHOT_BUFFER))
            .create()
            .map_err(|e| BusError::iceoryx("snapshot subscriber", e))?;
        let event = bus.snapshot_event(subsystem)?;
        let listener = listener(&event, "snapshot listener")?;
        Ok(Self {
            port,
            listener,
            _service: service,
            _event: event,
        })
    }

    /// The oldest queued snapshot, without waiting.
    pub fn receive(&mut self) -> Result<Option<Snapshot>> {
        self.port
            .receive()
            .map(|s| s.map(Snapshot))
            .map_err(|e| BusError::iceoryx("receiving a snapshot", e))
    }

    /// The newest snapshot queued since the last call, without waiting (older ones are dropped:
    /// a snapshot is a latest value).
    pub fn latest(&mut self) -> Result<Option<Snapshot>> {
        let mut newest = None;
        while let Some(s) = self.receive()? {
            newest = Some(s);
        }
        Ok(newest)
    }

    /// The newest snapshot, sleeping on the snapshot event until one arrives or `timeout`
    /// passes (`None` then).
    pub fn wait(&mut self, timeout: Duration) -> Result<Option<Snapshot>> {
        let deadline = Instant::now() + timeout;
        loop {
            // Consume the wake-ups of what is about to be read, so the next wait sleeps.
            self.consume()?;
            if let Some(s) = self.latest()? {
                return Ok(Some(s));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            self.listener
                .timed_wait(|_| {}, left)
                .map_err(|e| BusError::iceoryx("waiting for a snapshot", e))?;
        }
    }

    /// Sleeps until one of `readers` (up to 16) is notified of a snapshot or `timeout` passes,
    /// and consumes their notifications; then take each one's [`latest`](Self::latest).
    /// Allocation-free: the way a controller of several subsystems waits.
    pub fn wait_any(readers: &mut [SnapshotReader], timeout: Duration) -> Result<()> {
        poll_readable(
            readers.iter().map(SnapshotReader::raw_fd),
            timeout,
            "snapshot readers",
        )?;
        readers.iter_mut().try_for_each(SnapshotReader::consume)
    }

    /// Whether a snapshot is queued, without taking it or touching the event: what a reader
    /// that busy-polls checks (a shared-memory read, no system call), so it sees a snapshot as
    /// soon as it is sent, before the owner's notification.
    pub fn has_snapshots(&self) -> Result<bool> {
        self.port
            .has_samples()
            .map_err(|e| BusError::iceoryx("checking for snapshots", e))
    }

    /// Consumes the notifications received so far without waiting, so that the event's
    /// descriptor ([`raw_fd`](Self::raw_fd)) is readable again only for a later snapshot: for
    /// readers that wait in their own event loop.
    pub fn try_consume(&mut self) -> Result<()> {
        self.consume()
    }

    fn consume(&mut self) -> Result<()> {
        self.listener
            .try_wait(|_| {})
            .map(drop)
            .map_err(|e| BusError::iceoryx("polling the snapshot event", e))
    }

    /// The event listener's file descriptor number, for foreign event loops (epoll, tokio).
    pub fn raw_fd(&self) -> i32 {
        // SAFETY: the descriptor is owned by `self.listener` and stays valid while `self` lives;
        // only its number is reported.
        unsafe { self.listener.file_descriptor().native_handle() }
    }
}
