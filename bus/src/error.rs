//! Typed errors of the bus API.

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
    /// A failure inside iceoryx2, with what we were doing.
    #[error("{context}: {detail}")]
    Iceoryx {
        /// What the bus was doing.
        context: String,
        /// iceoryx2's error.
        detail: String,
    },
}

fn hint(known: &[String]) -> String {
    if known.is_empty() {
        " (no states are published there: is the executor running, in this domain?)".into()
    } else {
        format!("; known states: {}", known.join(", "))
    }
}

impl BusError {
    /// Wraps an iceoryx2 error with what we were doing.
    pub(crate) fn iox(context: impl Into<String>, e: impl core::fmt::Debug) -> Self {
        BusError::Iceoryx {
            context: context.into(),
            detail: format!("{e:?}"),
        }
    }
}

/// Result alias of the bus API.
pub type Result<T, E = BusError> = core::result::Result<T, E>;
