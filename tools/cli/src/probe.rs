//! A look inside a state's service for `conductor list`: which processes publish it (the
//! writer) and its latest sample (the age). Uses iceoryx2 directly, on the domain's config,
//! because the bus API deliberately hides port details from controllers.

use iceoryx2::node::{Node, NodeBuilder, NodeState, NodeView};
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::{CallbackProgression, PortFactory as _};
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;

use conductor_bus::{BusError, Domain, RtIpc, StateInfo, StateSample};

use crate::error::Result;

/// An iceoryx2 node for probing services.
pub struct Probe {
    node: Node<RtIpc>,
    domain: Domain,
}

/// One opened state service.
pub struct Probed {
    service: PortFactory<RtIpc, StateSample, ()>,
    sub: Subscriber<RtIpc, StateSample, ()>,
    latest: Option<StateSample>,
}

impl Probe {
    /// Joins `domain` as node `conductor-cli/probe`.
    pub fn new(domain: &Domain) -> Result<Self> {
        let name = "conductor-cli/probe"
            .try_into()
            .map_err(|e| BusError::iceoryx("node name", e))?;
        domain.prepare_dirs()?;
        let node = NodeBuilder::new()
            .name(&name)
            .config(domain.iceoryx2_config())
            .create::<RtIpc>()
            .map_err(|e| BusError::iceoryx("joining the domain", e))?;
        Ok(Self {
            node,
            domain: domain.clone(),
        })
    }

    /// Opens the service of `info` and subscribes with a one-sample queue.
    pub fn open(&self, info: &StateInfo) -> Result<Probed> {
        let name = info.service_name();
        let sname = name
            .as_str()
            .try_into()
            .map_err(|e| BusError::iceoryx("service name", e))?;
        let service = self
            .node
            .service_builder(&sname)
            .publish_subscribe::<StateSample>()
            .open()
            .map_err(|e| BusError::iceoryx(format!("opening {name:?}"), e))?;
        let sub = service
            .subscriber_builder()
            .buffer_size(1)
            .create()
            .map_err(|e| BusError::iceoryx(format!("subscribing to {name:?}"), e))?;
        Ok(Probed {
            service,
            sub,
            latest: None,
        })
    }

    /// Names of the live nodes of the domain, by id.
    pub fn node_names(&self) -> Result<Vec<(iceoryx2::identifiers::UniqueNodeId, String)>> {
        let mut out = Vec::new();
        Node::<RtIpc>::list(self.domain.iceoryx2_config(), |state| {
            if let NodeState::Alive(view) = state {
                if let Some(d) = view.details() {
                    out.push((*view.id(), d.name().to_string()));
                }
            }
            CallbackProgression::Continue
        })
        .map_err(|e| BusError::iceoryx("listing nodes", e))?;
        Ok(out)
    }
}

impl Probed {
    /// Pulls the newest sample, if one arrived; returns whether we have one.
    pub fn poll(&mut self) -> Result<bool> {
        loop {
            match self.sub.receive() {
                Ok(Some(s)) => self.latest = Some(*s),
                Ok(None) => return Ok(self.latest.is_some()),
                Err(e) => return Err(BusError::iceoryx("receiving", e).into()),
            }
        }
    }

    /// The newest sample received.
    pub fn latest(&self) -> Option<StateSample> {
        self.latest
    }

    /// Names of the nodes that own a publisher on this state.
    pub fn writers(&self, names: &[(iceoryx2::identifiers::UniqueNodeId, String)]) -> Vec<String> {
        let mut ids = Vec::new();
        self.service.dynamic_config().list_publishers(|p| {
            ids.push(p.node_id);
            CallbackProgression::Continue
        });
        ids.iter()
            .map(|id| {
                names
                    .iter()
                    .find(|(n, _)| n == id)
                    .map_or_else(|| format!("node {id}"), |(_, name)| name.clone())
            })
            .collect()
    }
}
