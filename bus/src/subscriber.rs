//! [`StateSubscriber`]: the raw sample stream of one state, with loss accounting.

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::{MessagingPattern, PortFactory as _, ZeroCopySend};

use crate::abi::StateSample;
use crate::bus::{Bus, StateService};
use crate::discovery::StateInfo;
use crate::error::{BusError, Result};
use crate::metadata::ServiceKind;
use crate::variant::RtIpc;

/// Default queue depth a subscriber asks for (capped at what the service offers).
pub const DEFAULT_BUFFER: usize = 64;

/// Subscribes to one state's samples and counts what it missed.
///
/// A gap in `seq` means the publisher overwrote samples this subscriber had not read yet (its
/// queue was full); they are counted in [`missed`](Self::missed). A `seq` that goes backwards
/// means the owner restarted; counting starts over from the new sequence.
pub struct StateSubscriber {
    info: StateInfo,
    port: Subscriber<RtIpc, StateSample, ()>,
    next_seq: Option<u64>,
    received: u64,
    missed: u64,
    restarts: u64,
    latest: Option<StateSample>,
    _service: StateService,
}

impl core::fmt::Debug for StateSubscriber {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("StateSubscriber")
            .field("state", &self.info.qualified_name())
            .field("received", &self.received)
            .field("missed", &self.missed)
            .finish()
    }
}

impl StateSubscriber {
    /// Subscribes to `name` (`subsystem/state`, or a unique bare state name) with the default
    /// queue depth.
    pub fn new(bus: &Bus, name: &str) -> Result<Self> {
        Self::with_buffer(bus, name, DEFAULT_BUFFER)
    }

    /// Subscribes with a queue of up to `buffer` samples (capped at the service's maximum).
    pub fn with_buffer(bus: &Bus, name: &str, buffer: usize) -> Result<Self> {
        Self::from_info(bus, bus.resolve(name)?, buffer)
    }

    /// Subscribes to a state discovery already found (no second look-up: what a process that
    /// subscribes to many states at once, like a bridge, wants).
    pub fn from_info(bus: &Bus, info: StateInfo, buffer: usize) -> Result<Self> {
        let service_name = info.service_name();
        let service = bus
            .node()
            .service_builder(&Bus::service_name(&service_name)?)
            .publish_subscribe::<StateSample>()
            .open()
            .map_err(|e| open_error(bus, &service_name, e))?;
        let cap = service.static_config().subscriber_max_buffer_size();
        let port = service
            .subscriber_builder()
            .buffer_size(buffer.clamp(1, cap))
            .create()
            .map_err(|e| BusError::iceoryx(format!("subscribing to {service_name:?}"), e))?;
        Ok(Self {
            info,
            port,
            next_seq: None,
            received: 0,
            missed: 0,
            restarts: 0,
            latest: None,
            _service: service,
        })
    }

    /// What discovery knows about the state.
    pub fn info(&self) -> &StateInfo {
        &self.info
    }

    /// The next queued sample, if any, updating the loss counters.
    #[inline]
    pub fn receive(&mut self) -> Result<Option<StateSample>> {
        let sample = match self.port.receive() {
            Ok(Some(s)) => *s,
            Ok(None) => return Ok(None),
            Err(e) => return Err(BusError::iceoryx("receiving a state sample", e)),
        };
        match self.next_seq {
            Some(expected) if sample.seq > expected => self.missed += sample.seq - expected,
            Some(expected) if sample.seq < expected => self.restarts += 1,
            _ => {}
        }
        self.next_seq = Some(sample.seq + 1);
        self.received += 1;
        self.latest = Some(sample);
        Ok(Some(sample))
    }

    /// Calls `f` for every queued sample, oldest first; returns how many there were.
    pub fn drain(&mut self, mut f: impl FnMut(&StateSample)) -> Result<usize> {
        let mut n = 0;
        while let Some(s) = self.receive()? {
            f(&s);
            n += 1;
        }
        Ok(n)
    }

    /// The most recent sample received so far (after draining the queue).
    pub fn latest(&mut self) -> Result<Option<StateSample>> {
        while self.receive()?.is_some() {}
        Ok(self.latest)
    }

    /// Samples received.
    pub fn received(&self) -> u64 {
        self.received
    }

    /// Samples the publisher overwrote before this subscriber read them.
    pub fn missed(&self) -> u64 {
        self.missed
    }

    /// Times the owner restarted (its `seq` went backwards).
    pub fn restarts(&self) -> u64 {
        self.restarts
    }
}

/// Turns an iceoryx2 open failure into the typed error a user can act on.
pub(crate) fn open_error(
    bus: &Bus,
    service: &str,
    e: iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError,
) -> BusError {
    use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError as E;
    match e {
        E::IncompatibleTypes => {
            // Explain what is there instead.
            if let Ok(Some(d)) = bus.details(service, MessagingPattern::PublishSubscribe) {
                // SAFETY: type_name() has no preconditions.
                let tn = unsafe { StateSample::type_name() };
                if let Err(err) = bus.check_conductor_service(service, &d, ServiceKind::State, tn) {
                    return err;
                }
            }
            BusError::WrongServiceType {
                service: service.into(),
                expected: "state".into(),
                found: "an incompatible payload type".into(),
            }
        }
        other => BusError::iceoryx(format!("opening {service:?}"), other),
    }
}
