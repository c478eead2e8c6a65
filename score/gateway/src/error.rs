//! What can go wrong.

/// Gateway failures. `Disconnected` and `Timeout` lead to a reconnect; the others are reported.
#[derive(Debug, thiserror::Error)]
pub enum GatewayError {
    /// The serial device could not be opened.
    #[error("cannot open {path}: {error}")]
    Open {
        /// Device path.
        path: String,
        /// Why.
        error: String,
    },
    /// The device went away (unplugged, emulator ended).
    #[error("link lost: {0}")]
    Disconnected(String),
    /// Other I/O error.
    #[error("I/O: {0}")]
    Io(#[from] std::io::Error),
    /// No answer in time.
    #[error("no answer from the board to {0}")]
    Timeout(String),
    /// The board speaks another protocol version or sent nonsense.
    #[error("protocol: {0}")]
    Protocol(String),
    /// The board refused a request.
    #[error("board refused: {message}")]
    Board {
        /// The table changed since it was listed.
        stale: bool,
        /// Code and text.
        message: String,
    },
    /// The bus refused.
    #[error("bus: {0}")]
    Bus(#[from] conductor_bus::BusError),
}

impl GatewayError {
    /// True if the link should be closed and reopened.
    pub fn is_link_loss(&self) -> bool {
        matches!(
            self,
            GatewayError::Disconnected(_)
                | GatewayError::Timeout(_)
                | GatewayError::Io(_)
                | GatewayError::Open { .. }
        )
    }
}
