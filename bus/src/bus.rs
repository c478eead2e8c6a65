//! [`Bus`]: one process's handle on a domain (an iceoryx2 node), and the service QoS in one place.

use std::rc::Rc;

use iceoryx2::node::{Node, NodeBuilder};
use iceoryx2::prelude::{AttributeSpecifier, AttributeVerifier, MessagingPattern, Service as _};
use iceoryx2::service::port_factory::{event, publish_subscribe};
use iceoryx2::service::service_name::ServiceName;
use iceoryx2::service::static_config::messaging_pattern::MessagingPattern as StaticPattern;
use iceoryx2::service::ServiceDetails;

use crate::abi::{StateSample, ABI_VERSION};
use crate::domain::Domain;
use crate::error::{BusError, Result};
use crate::metadata::{self, ServiceKind, KEY_ABI, KEY_KIND};
use crate::naming;
use crate::variant::RtIpc;

/// Quality of service of every Conductor service. Owners create services with these values;
/// clients open them without requirements, so the two never disagree. Public so that a
/// benchmark's raw iceoryx2 floor can use the very configuration the states use
/// ([`qos::state_service`], [`qos::tick_event`]).
pub mod qos {
    use iceoryx2::service::builder::{event, publish_subscribe};
    use iceoryx2::service::Service;

    /// Processes that may attach to one service (executor, controllers, CLI, recorder, ...).
    pub const MAX_NODES: usize = 32;
    /// Publishers per state: the owner, plus one while a restarted owner replaces a dead one.
    pub const STATE_PUBLISHERS: usize = 2;
    /// Subscribers per state.
    pub const STATE_SUBSCRIBERS: usize = 16;
    /// Default per-subscriber queue depth of a state (samples kept for a slow reader).
    pub const STATE_BUFFER: usize = 256;
    /// Command senders per subsystem.
    pub const COMMAND_PUBLISHERS: usize = 8;
    /// Command receivers per subsystem (the executor and a recorder).
    pub const COMMAND_SUBSCRIBERS: usize = 4;
    /// Frames queued for the executor between two of its ticks.
    pub const COMMAND_BUFFER: usize = 32;
    /// Stats subscribers.
    pub const STATS_SUBSCRIBERS: usize = 8;
    /// Tick listeners.
    pub const TICK_LISTENERS: usize = 32;
    /// Notifiers per tick event: the owner, plus one while a restarted owner replaces a dead one.
    pub const TICK_NOTIFIERS: usize = 2;

    /// A state service's settings: publishers, subscribers, nodes, a history of one sample (a
    /// late subscriber gets the current value), per-subscriber queues of up to `buffer` samples
    /// (at least 1), and safe overflow (a slow reader loses its oldest sample, the owner never
    /// blocks).
    pub fn state_service<T, S>(
        b: publish_subscribe::Builder<T, (), S>,
        buffer: usize,
    ) -> publish_subscribe::Builder<T, (), S>
    where
        T: core::fmt::Debug + iceoryx2::prelude::ZeroCopySend + 'static,
        S: Service,
    {
        b.max_publishers(STATE_PUBLISHERS)
            .max_subscribers(STATE_SUBSCRIBERS)
            .max_nodes(MAX_NODES)
            .history_size(1)
            .subscriber_max_buffer_size(buffer.max(1))
            .enable_safe_overflow(true)
    }

    /// Subscribers of a subsystem's snapshot (as many as of a state).
    pub const SNAPSHOT_SUBSCRIBERS: usize = 16;
    /// Most snapshots a snapshot subscriber may queue: a controller wants the newest only; a
    /// logger that must see every tick reads them all and loses none while it is held off the
    /// CPU for up to this many ticks (6.4 ms at 10 kHz). The service's shared memory is about
    /// subscribers × this × states × 48 bytes (2 MB for 41 states).
    pub const SNAPSHOT_BUFFER: usize = 64;

    /// A snapshot service's settings: as a state's (two publishers, history of one, safe
    /// overflow), with queues of at most [`SNAPSHOT_BUFFER`] snapshots.
    pub fn snapshot_service<T, S>(
        b: publish_subscribe::Builder<T, (), S>,
    ) -> publish_subscribe::Builder<T, (), S>
    where
        T: core::fmt::Debug
            + iceoryx2::prelude::IceoryxSend
            + iceoryx2::prelude::ZeroCopySend
            + ?Sized
            + 'static,
        S: Service,
    {
        b.max_publishers(STATE_PUBLISHERS)
            .max_subscribers(SNAPSHOT_SUBSCRIBERS)
            .max_nodes(MAX_NODES)
            .history_size(1)
            .subscriber_max_buffer_size(SNAPSHOT_BUFFER)
            .enable_safe_overflow(true)
    }

    /// A tick event's settings: listeners, notifiers, nodes.
    pub fn tick_event<S: Service>(b: event::Builder<S>) -> event::Builder<S> {
        b.max_listeners(TICK_LISTENERS)
            .max_notifiers(TICK_NOTIFIERS)
            .max_nodes(MAX_NODES)
    }
}

pub(crate) type StateService = publish_subscribe::PortFactory<RtIpc, StateSample, ()>;
pub(crate) type EventService = event::PortFactory<RtIpc>;

struct Inner {
    domain: Domain,
    node: Node<RtIpc>,
}

/// A process's connection to one [`Domain`]: an iceoryx2 node from which every publisher,
/// subscriber and controller is made. Cheap to clone; not `Send` (iceoryx2 ports are
/// single-threaded), so each thread opens its own.
#[derive(Clone)]
pub struct Bus {
    inner: Rc<Inner>,
}

impl core::fmt::Debug for Bus {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Bus")
            .field("domain", &self.inner.domain.name())
            .finish()
    }
}

impl Bus {
    /// Joins `domain` as a node called `node_name` (shown by `iox2 node list`).
    pub fn open(domain: &Domain, node_name: &str) -> Result<Self> {
        domain.prepare_dirs()?;
        let name = node_name
            .try_into()
            .map_err(|e| BusError::iceoryx(format!("node name {node_name:?}"), e))?;
        let node = NodeBuilder::new()
            .name(&name)
            .config(domain.iceoryx2_config())
            .create::<RtIpc>()
            .map_err(|e| BusError::iceoryx(format!("joining domain {:?}", domain.name()), e))?;
        Ok(Self {
            inner: Rc::new(Inner {
                domain: domain.clone(),
                node,
            }),
        })
    }

    /// Joins the domain named by `CONDUCTOR_DOMAIN`.
    pub fn from_env(node_name: &str) -> Result<Self> {
        Self::open(&Domain::from_env()?, node_name)
    }

    /// The domain this bus is attached to.
    pub fn domain(&self) -> &Domain {
        &self.inner.domain
    }

    pub(crate) fn node(&self) -> &Node<RtIpc> {
        &self.inner.node
    }

    pub(crate) fn service_name(name: &str) -> Result<ServiceName> {
        name.try_into()
            .map_err(|e| BusError::iceoryx(format!("service name {name:?}"), e))
    }

    /// Static details of a service, if it exists.
    pub(crate) fn details(
        &self,
        name: &str,
        pattern: MessagingPattern,
    ) -> Result<Option<ServiceDetails<RtIpc>>> {
        RtIpc::details(
            &Self::service_name(name)?,
            self.domain().iceoryx2_config(),
            pattern,
        )
        .map_err(|e| BusError::iceoryx(format!("reading service {name:?}"), e))
    }

    /// Checks that an existing service is a Conductor service of `kind` speaking our ABI.
    pub(crate) fn check_conductor_service(
        &self,
        name: &str,
        details: &ServiceDetails<RtIpc>,
        kind: ServiceKind,
        type_name: &str,
    ) -> Result<()> {
        let attrs = details.static_details.attributes();
        let abi = metadata::get(attrs, KEY_ABI);
        let found_kind = metadata::get(attrs, KEY_KIND);
        let found_type = match details.static_details.messaging_pattern() {
            StaticPattern::PublishSubscribe(_) => details
                .static_details
                .publish_subscribe()
                .message_type_details()
                .payload
                .type_name()
                .to_string(),
            _ => String::new(),
        };
        match abi {
            None => {
                return Err(BusError::WrongServiceType {
                    service: name.into(),
                    expected: format!("{} ({type_name})", kind.as_str()),
                    found: if found_type.is_empty() {
                        "a service without Conductor attributes".into()
                    } else {
                        format!("a foreign service with payload type {found_type:?}")
                    },
                })
            }
            Some(v) if v != ABI_VERSION.to_string() => {
                return Err(BusError::AbiMismatch {
                    service: name.into(),
                    found: v,
                    expected: ABI_VERSION,
                })
            }
            Some(_) => {}
        }
        if found_kind.as_deref() != Some(kind.as_str()) {
            return Err(BusError::WrongServiceType {
                service: name.into(),
                expected: kind.as_str().into(),
                found: format!("kind {:?}", found_kind.unwrap_or_default()),
            });
        }
        if !type_name.is_empty() && found_type != type_name {
            return Err(BusError::WrongServiceType {
                service: name.into(),
                expected: format!("payload {type_name}"),
                found: format!("payload {found_type:?}"),
            });
        }
        Ok(())
    }

    /// The static details of `subsystem`'s existing service `name`, checked to be a Conductor
    /// pub/sub service of `kind` carrying `T` (`UnknownSubsystem` when there is none).
    pub(crate) fn conductor_details<T: Payload + ?Sized>(
        &self,
        subsystem: &str,
        name: &str,
        kind: ServiceKind,
    ) -> Result<ServiceDetails<RtIpc>> {
        let Some(details) = self.details(name, MessagingPattern::PublishSubscribe)? else {
            return Err(BusError::UnknownSubsystem {
                name: subsystem.into(),
                domain: self.domain().name().into(),
                service: name.into(),
            });
        };
        self.check_conductor_service(name, &details, kind, T::conductor_type_name())?;
        Ok(details)
    }

    /// Opens `subsystem`'s existing Conductor pub/sub service `name` of `kind` carrying `T`,
    /// after the checks of [`conductor_details`](Self::conductor_details).
    pub(crate) fn open_conductor_pubsub<T>(
        &self,
        subsystem: &str,
        name: &str,
        kind: ServiceKind,
    ) -> Result<publish_subscribe::PortFactory<RtIpc, T, ()>>
    where
        T: core::fmt::Debug + iceoryx2::prelude::IceoryxSend + Payload + ?Sized + 'static,
        iceoryx2::service::builder::publish_subscribe::Builder<T, (), RtIpc>: CreateOrOpen<T>,
    {
        self.conductor_details::<T>(subsystem, name, kind)?;
        self.node()
            .service_builder(&Self::service_name(name)?)
            .publish_subscribe::<T>()
            .open_with(&AttributeVerifier::new())
            .map_err(|e| BusError::iceoryx(format!("opening {name:?}"), e))
    }

    /// Creates `name` with `attrs`, or opens it if a (restarted) owner finds it still held open
    /// by clients; opening then requires the same attributes. The service a killed owner left
    /// can vanish between the two (the dead node's resources are cleaned up meanwhile, by this
    /// process or another): then it is created again, a bounded number of times.
    pub(crate) fn create_or_reopen_pubsub<T>(
        &self,
        name: &str,
        attrs: &AttributeSpecifier,
        configure: impl Fn(
            iceoryx2::service::builder::publish_subscribe::Builder<T, (), RtIpc>,
        )
            -> iceoryx2::service::builder::publish_subscribe::Builder<T, (), RtIpc>,
    ) -> Result<publish_subscribe::PortFactory<RtIpc, T, ()>>
    where
        T: core::fmt::Debug + iceoryx2::prelude::IceoryxSend + ?Sized + 'static,
        iceoryx2::service::builder::publish_subscribe::Builder<T, (), RtIpc>: CreateOrOpen<T>,
    {
        use iceoryx2::service::builder::publish_subscribe::PublishSubscribeCreateError as CE;
        use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError as OE;
        /// Create-then-open rounds before the race with a cleanup counts as an error.
        const ROUNDS: u32 = 100;
        let sname = Self::service_name(name)?;
        let builder = || configure(self.node().service_builder(&sname).publish_subscribe::<T>());
        let mut round = 0;
        loop {
            round += 1;
            match builder().create_with(attrs) {
                Ok(f) => return Ok(f),
                Err(CE::AlreadyExists) | Err(CE::IsBeingCreatedByAnotherInstance) => {}
                Err(e) => return Err(BusError::iceoryx(format!("creating {name:?}"), e)),
            }
            match builder().open_with(&verifier(attrs)?) {
                Ok(f) => return Ok(f),
                // Gone (or going) since the create found it: create it again.
                Err(OE::DoesNotExist | OE::IsMarkedForDestruction | OE::HangsInCreation)
                    if round < ROUNDS =>
                {
                    std::thread::sleep(std::time::Duration::from_millis(2));
                }
                Err(e) => {
                    return Err(BusError::iceoryx(
                        format!("re-opening {name:?} as its owner"),
                        e,
                    ))
                }
            }
        }
    }

    /// Opens (or creates) the tick event of `subsystem`.
    pub(crate) fn tick_event(&self, subsystem: &str) -> Result<EventService> {
        self.event(&naming::tick(subsystem), ServiceKind::Tick)
    }

    /// Opens (or creates) the snapshot event of `subsystem` (beside the snapshot pub/sub service
    /// of the same name).
    pub(crate) fn snapshot_event(&self, subsystem: &str) -> Result<EventService> {
        self.event(&naming::snapshot(subsystem), ServiceKind::Snapshot)
    }

    /// Opens (or creates) the event `name` of `kind`, with the tick event's settings.
    fn event(&self, name: &str, kind: ServiceKind) -> Result<EventService> {
        qos::tick_event(
            self.node()
                .service_builder(&Self::service_name(name)?)
                .event(),
        )
        .open_or_create_with_attributes(&verifier(&metadata::base_attributes(kind)?)?)
        .map_err(|e| BusError::iceoryx(format!("opening event {name:?}"), e))
    }
}

/// Creating and opening a pub/sub service, which iceoryx2 implements apart for a fixed-size
/// payload and for a slice: one retry loop serves both.
pub(crate) trait CreateOrOpen<T: core::fmt::Debug + iceoryx2::prelude::IceoryxSend + ?Sized> {
    /// `create_with_attributes`.
    fn create_with(
        self,
        attrs: &AttributeSpecifier,
    ) -> core::result::Result<
        publish_subscribe::PortFactory<RtIpc, T, ()>,
        iceoryx2::service::builder::publish_subscribe::PublishSubscribeCreateError,
    >;
    /// `open_with_attributes`.
    fn open_with(
        self,
        verifier: &AttributeVerifier,
    ) -> core::result::Result<
        publish_subscribe::PortFactory<RtIpc, T, ()>,
        iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError,
    >;
}

/// A Conductor payload as its service declares it: `T`, or a slice of `T` (the snapshot).
pub(crate) trait Payload {
    /// The iceoryx2 type name its service carries (a slice's is its element's).
    fn conductor_type_name() -> &'static str;
}

impl<T: iceoryx2::prelude::ZeroCopySend> Payload for T {
    fn conductor_type_name() -> &'static str {
        // SAFETY: type_name() has no preconditions; it is unsafe only for implementors.
        unsafe { <T as iceoryx2::prelude::ZeroCopySend>::type_name() }
    }
}

impl<T: iceoryx2::prelude::ZeroCopySend> Payload for [T] {
    fn conductor_type_name() -> &'static str {
        // SAFETY: as above.
        unsafe { <T as iceoryx2::prelude::ZeroCopySend>::type_name() }
    }
}

macro_rules! create_or_open {
    ($(<$t:ident> $payload:ty),*) => {$(
        impl<$t> CreateOrOpen<$payload>
            for iceoryx2::service::builder::publish_subscribe::Builder<$payload, (), RtIpc>
        where
            $t: core::fmt::Debug + iceoryx2::prelude::ZeroCopySend + 'static,
        {
            fn create_with(
                self,
                attrs: &AttributeSpecifier,
            ) -> core::result::Result<
                publish_subscribe::PortFactory<RtIpc, $payload, ()>,
                iceoryx2::service::builder::publish_subscribe::PublishSubscribeCreateError,
            > {
                self.create_with_attributes(attrs)
            }
            fn open_with(
                self,
                verifier: &AttributeVerifier,
            ) -> core::result::Result<
                publish_subscribe::PortFactory<RtIpc, $payload, ()>,
                iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError,
            > {
                self.open_with_attributes(verifier)
            }
        }
    )*};
}
create_or_open!(<T> T, <T> [T]);

/// A notifier of `event`; `what` names it in the error.
pub(crate) fn notifier(
    event: &EventService,
    what: &'static str,
) -> Result<iceoryx2::port::notifier::Notifier<RtIpc>> {
    event
        .notifier_builder()
        .create()
        .map_err(|e| BusError::iceoryx(what, e))
}

/// A listener of `event`; `what` names it in the error.
pub(crate) fn listener(
    event: &EventService,
    what: &'static str,
) -> Result<iceoryx2::port::listener::Listener<RtIpc>> {
    event
        .listener_builder()
        .create()
        .map_err(|e| BusError::iceoryx(what, e))
}

/// An attribute verifier that requires every key/value of `spec`.
fn verifier(spec: &AttributeSpecifier) -> Result<AttributeVerifier> {
    let mut v = AttributeVerifier::new();
    for a in spec.attributes().iter() {
        v = v
            .require(a.key(), a.value())
            .map_err(|e| BusError::iceoryx("attribute verifier", e))?;
    }
    Ok(v)
}
