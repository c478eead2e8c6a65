//! [`BridgeError`].

/// Why the bridge cannot start or had to stop.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// The configuration is wrong.
    #[error("bridge configuration: {0}")]
    Config(String),
    /// Zenoh refused (open, declare, put).
    #[error("zenoh: {0}")]
    Zenoh(String),
    /// The local bus refused.
    #[error(transparent)]
    Bus(#[from] conductor_bus::BusError),
    /// A thread could not be started or died.
    #[error("bridge thread: {0}")]
    Thread(String),
}

/// Result with [`BridgeError`].
pub type Result<T> = std::result::Result<T, BridgeError>;

/// Turns a Zenoh error into [`BridgeError::Zenoh`] with what was being done.
pub(crate) fn zenoh(what: &str) -> impl FnOnce(zenoh::Error) -> BridgeError + '_ {
    move |e| BridgeError::Zenoh(format!("{what}: {e}"))
}
