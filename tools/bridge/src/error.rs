//! [`BridgeError`].

/// Why the bridge cannot start or had to stop.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// The configuration is wrong.
    #[error("bridge configuration: {0}")]
    Config(String),
    /// The configuration neither exports nor imports (a `bridge.toml` that command-line flags
    /// complete is fine until they are merged).
    #[error("bridge configuration: nothing to do: give [export] and/or [[import]]")]
    NothingToDo,
    /// Zenoh refused (open, declare, put).
    #[error("zenoh: {what}: {source}")]
    Zenoh {
        /// What the bridge was doing.
        what: &'static str,
        /// Zenoh's error.
        #[source]
        source: zenoh::Error,
    },
    /// The local bus refused.
    #[error(transparent)]
    Bus(#[from] conductor_bus::BusError),
    /// A thread could not be started.
    #[error("bridge thread: starting {name}: {source}")]
    Spawn {
        /// The thread's name.
        name: &'static str,
        /// The OS's refusal.
        #[source]
        source: std::io::Error,
    },
    /// A thread died.
    #[error("bridge thread: {0}")]
    Thread(String),
}

/// Result with [`BridgeError`].
pub type Result<T> = std::result::Result<T, BridgeError>;

/// Turns a Zenoh error into [`BridgeError::Zenoh`] with what was being done.
pub(crate) fn zenoh(what: &'static str) -> impl FnOnce(zenoh::Error) -> BridgeError {
    move |source| BridgeError::Zenoh { what, source }
}
