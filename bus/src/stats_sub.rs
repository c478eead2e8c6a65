//! Reading an executor's health from `conductor/<subsystem>/stats`.

use iceoryx2::port::subscriber::Subscriber;

use iceoryx2::service::port_factory::publish_subscribe::PortFactory;

use crate::abi::ExecutorStats;
use crate::bus::Bus;
use crate::error::{BusError, Result};
use crate::metadata::ServiceKind;
use crate::naming;
use crate::variant::RtIpc;

/// Subscribes to an executor's [`ExecutorStats`].
pub struct StatsSubscriber {
    port: Subscriber<RtIpc, ExecutorStats, ()>,
    latest: Option<ExecutorStats>,
    _service: PortFactory<RtIpc, ExecutorStats, ()>,
}

impl core::fmt::Debug for StatsSubscriber {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("StatsSubscriber")
    }
}

impl StatsSubscriber {
    /// Opens the stats of `subsystem`.
    pub fn new(bus: &Bus, subsystem: &str) -> Result<Self> {
        naming::validate("subsystem", subsystem)?;
        let name = naming::stats(subsystem);
        let service =
            bus.open_conductor_pubsub::<ExecutorStats>(subsystem, &name, ServiceKind::Stats)?;
        let port = service
            .subscriber_builder()
            .create()
            .map_err(|e| BusError::iceoryx("stats subscriber", e))?;
        Ok(Self {
            port,
            latest: None,
            _service: service,
        })
    }

    /// The newest stats received so far (drains the queue).
    pub fn latest(&mut self) -> Result<Option<ExecutorStats>> {
        loop {
            match self.port.receive() {
                Ok(Some(s)) => self.latest = Some(*s),
                Ok(None) => return Ok(self.latest),
                Err(e) => return Err(BusError::iceoryx("receiving stats", e)),
            }
        }
    }
}
