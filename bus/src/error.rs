//! Typed errors of the bus API.

use std::borrow::Cow;

use iceoryx2::node::{NodeCreationFailure, NodeListFailure};
use iceoryx2::port::listener::{ListenerCreateError, ListenerWaitError};
use iceoryx2::port::notifier::{NotifierCreateError, NotifierNotifyError};
use iceoryx2::port::publisher::PublisherCreateError;
use iceoryx2::port::subscriber::SubscriberCreateError;
use iceoryx2::port::update_connections::ConnectionFailure;
use iceoryx2::port::{LoanError, ReceiveError, SendError};
use iceoryx2::prelude::SemanticStringError;
use iceoryx2::service::attribute::AttributeDefinitionError;
use iceoryx2::service::builder::event::EventOpenOrCreateError;
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeCreateError, PublishSubscribeOpenError,
};
use iceoryx2::service::service_name::ServiceNameError;
use iceoryx2::service::{ServiceDetailsError, ServiceListError};
use nix::errno::Errno;
use thiserror::Error;

/// Everything that can go wrong on the bus, with enough context to act on it.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum BusError {
    /// A domain, subsystem or state name is not usable.
    #[error("invalid {what} name {name:?}: {reason}")]
    InvalidName {
        /// "domain", "subsystem" or "state".
        what: &'static str,
        /// The offending name.
        name: String,
        /// What was expected.
        reason: &'static str,
    },
    /// A state index past the publisher's states (a caller's bug; reported without allocating,
    /// as it is found on the real-time path).
    #[error("state index {index} out of range ({count} states)")]
    NoSuchIndex {
        /// The index given.
        index: usize,
        /// How many states the publisher has.
        count: usize,
    },
    /// No state of that name exists in the domain (the owning executor is not running?).
    #[error("unknown state {name:?} in domain {domain:?}{}", hint(known))]
    UnknownState {
        /// The name that was asked for.
        name: String,
        /// The domain searched.
        domain: String,
        /// States that do exist (at most a handful, for the message).
        known: Vec<String>,
    },
    /// A state name without subsystem matches states in several subsystems.
    #[error("state name {name:?} is ambiguous in domain {domain:?}: {}", candidates.join(", "))]
    AmbiguousState {
        /// The name that was asked for.
        name: String,
        /// The domain searched.
        domain: String,
        /// The fully qualified candidates.
        candidates: Vec<String>,
    },
    /// No executor for that subsystem publishes in the domain.
    #[error("unknown subsystem {name:?} in domain {domain:?} (no `{service}` service)")]
    UnknownSubsystem {
        /// The subsystem asked for.
        name: String,
        /// The domain searched.
        domain: String,
        /// The service that was looked for.
        service: String,
    },
    /// A command frame reached no receiver: no executor listens on the subsystem's commands
    /// service (it stopped, or the states belong to something that takes no commands).
    #[error(
        "not delivered: no executor listens for commands of subsystem {subsystem:?} in domain \
         {domain:?} (its executor is not running, or the state's owner takes no commands)"
    )]
    NotDelivered {
        /// The subsystem.
        subsystem: String,
        /// The domain.
        domain: String,
    },
    /// A service of that name exists but is not a Conductor service of the expected kind/type.
    #[error("service {service:?} is not a Conductor {expected}: {found}")]
    WrongServiceType {
        /// The service name.
        service: String,
        /// What we expected, e.g. "state (conductor.StateSample.v1)".
        expected: String,
        /// What is there instead.
        found: String,
    },
    /// The service speaks another version of the payload ABI.
    #[error("service {service:?} uses Conductor ABI {found}, this program speaks ABI {expected}; rebuild one side")]
    AbiMismatch {
        /// The service name.
        service: String,
        /// The version found in the service attributes or type name.
        found: String,
        /// Our [`crate::ABI_VERSION`].
        expected: u32,
    },
    /// A command frame has no room for another setpoint.
    #[error("command frame for subsystem {subsystem:?} is full ({capacity} setpoints); send_ctrl() first")]
    FrameFull {
        /// The subsystem whose frame is full.
        subsystem: String,
        /// [`crate::MAX_SETPOINTS`].
        capacity: usize,
    },
    /// The state exists but does not accept commands.
    #[error("state {name:?} is read-only")]
    ReadOnly {
        /// The state.
        name: String,
    },
    /// A value that can never be a setpoint (NaN or infinite).
    #[error("setpoint for {name:?} is not finite ({value})")]
    NotFinite {
        /// The state.
        name: String,
        /// The rejected value.
        value: f64,
    },
    /// A read of the history outside what the history holds.
    #[error("time {t} s is outside the history ({oldest} s .. {newest} s)")]
    OutOfHistory {
        /// Requested time relative to the newest sample (s).
        t: f64,
        /// Oldest available time (s, ≤ 0).
        oldest: f64,
        /// Newest allowed time (s, ≥ 0 with extrapolation).
        newest: f64,
    },
    /// Not enough samples yet for the requested computation.
    #[error("need {needed} samples, have {have}")]
    NotEnoughSamples {
        /// Samples required.
        needed: usize,
        /// Samples held.
        have: usize,
    },
    /// A control vector whose length differs from the list of state names.
    #[error("{names} state names but {values} values")]
    DimensionMismatch {
        /// Number of names.
        names: usize,
        /// Number of values.
        values: usize,
    },
    /// More of something than a fixed capacity allows.
    #[error("too many {what}: at most {max}")]
    Capacity {
        /// What there were too many of.
        what: &'static str,
        /// The limit.
        max: usize,
    },
    /// The domain's directory cannot be used safely by this process (see `docs/permissions.md`).
    #[error("domain {domain:?}: {path}: {reason}")]
    DomainAccess {
        /// The domain.
        domain: String,
        /// The directory concerned.
        path: String,
        /// What is wrong and how to fix it.
        reason: String,
    },
    /// A failure inside iceoryx2, with what we were doing. The cause is iceoryx2's own `Copy`
    /// error, kept typed: match on `source`, not on the message. Built without allocating when
    /// `context` is a literal (the real-time paths: loaning, sending, receiving, notifying).
    #[error("{context}: {source}")]
    Iceoryx {
        /// What the bus was doing.
        context: Cow<'static, str>,
        /// iceoryx2's error.
        #[source]
        source: IceoryxError,
    },
    /// A system call the bus makes itself (beside iceoryx2) failed.
    #[error("{context}: {source}")]
    Os {
        /// What the bus was doing.
        context: &'static str,
        /// The OS's error number.
        #[source]
        source: Errno,
    },
}

/// An iceoryx2 error, one variant per iceoryx2 error type the bus meets. Every one is
/// iceoryx2's own `Copy` enum, so this is `Copy` too and costs nothing to build on a
/// real-time thread; its text is iceoryx2's.
#[derive(Debug, Error, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum IceoryxError {
    /// A node, file or path name iceoryx2 does not accept.
    #[error(transparent)]
    Name(#[from] SemanticStringError),
    /// A service name iceoryx2 does not accept.
    #[error(transparent)]
    ServiceName(#[from] ServiceNameError),
    /// Joining the domain as a node.
    #[error(transparent)]
    NodeCreation(#[from] NodeCreationFailure),
    /// Listing the domain's nodes.
    #[error(transparent)]
    NodeList(#[from] NodeListFailure),
    /// Listing the domain's services.
    #[error(transparent)]
    ServiceList(#[from] ServiceListError),
    /// Reading a service's static record.
    #[error(transparent)]
    ServiceDetails(#[from] ServiceDetailsError),
    /// Creating a publish-subscribe service.
    #[error(transparent)]
    PublishSubscribeCreate(#[from] PublishSubscribeCreateError),
    /// Opening a publish-subscribe service.
    #[error(transparent)]
    PublishSubscribeOpen(#[from] PublishSubscribeOpenError),
    /// Opening or creating an event service.
    #[error(transparent)]
    EventOpenOrCreate(#[from] EventOpenOrCreateError),
    /// Defining a service attribute.
    #[error(transparent)]
    AttributeDefinition(#[from] AttributeDefinitionError),
    /// Creating a publisher port.
    #[error(transparent)]
    PublisherCreate(#[from] PublisherCreateError),
    /// Creating a subscriber port.
    #[error(transparent)]
    SubscriberCreate(#[from] SubscriberCreateError),
    /// Creating a notifier port.
    #[error(transparent)]
    NotifierCreate(#[from] NotifierCreateError),
    /// Creating a listener port.
    #[error(transparent)]
    ListenerCreate(#[from] ListenerCreateError),
    /// Loaning a sample from a publisher.
    #[error(transparent)]
    Loan(#[from] LoanError),
    /// Sending a sample.
    #[error(transparent)]
    Send(#[from] SendError),
    /// Receiving a sample.
    #[error(transparent)]
    Receive(#[from] ReceiveError),
    /// Notifying an event.
    #[error(transparent)]
    Notify(#[from] NotifierNotifyError),
    /// Waiting on a listener.
    #[error(transparent)]
    ListenerWait(#[from] ListenerWaitError),
    /// Connecting a port to a service's other ports.
    #[error(transparent)]
    Connection(#[from] ConnectionFailure),
}

fn hint(known: &[String]) -> String {
    if known.is_empty() {
        " (no states are published there: is the executor running, in this domain?)".into()
    } else {
        format!("; known states: {}", known.join(", "))
    }
}

impl BusError {
    /// Wraps an iceoryx2 error with what we were doing. With a literal `context` nothing is
    /// allocated (the real-time paths use literals).
    pub fn iceoryx(context: impl Into<Cow<'static, str>>, e: impl Into<IceoryxError>) -> Self {
        BusError::Iceoryx {
            context: context.into(),
            source: e.into(),
        }
    }

    /// The iceoryx2 error underneath, if this is one.
    pub fn iceoryx_source(&self) -> Option<IceoryxError> {
        match self {
            BusError::Iceoryx { source, .. } => Some(*source),
            _ => None,
        }
    }
}

/// Result alias of the bus API.
pub type Result<T, E = BusError> = core::result::Result<T, E>;
