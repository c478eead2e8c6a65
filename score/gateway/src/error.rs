//! What can go wrong.

use std::path::PathBuf;

use conductor_protocols::score_link::FrameError;

use crate::client::Answer;

/// Gateway failures. `Disconnected` and `Timeout` lead to a reconnect; the others are reported.
#[derive(Debug, thiserror::Error)]
pub enum GatewayError {
    /// The serial device could not be opened.
    #[error("cannot open {}: {source}", path.display())]
    Open {
        /// Device path.
        path: PathBuf,
        /// Why, as `serialport` tells it.
        #[source]
        source: serialport::Error,
    },
    /// The device went away (unplugged, emulator ended): end of file, or the OS's error.
    #[error("link lost: {}", lost(.0))]
    Disconnected(#[source] Option<std::io::Error>),
    /// Other I/O error.
    #[error("I/O: {0}")]
    Io(#[from] std::io::Error),
    /// No answer in time.
    #[error("no answer from the board to {0}")]
    Timeout(String),
    /// A request could not be framed (a string over its limit).
    #[error("protocol: {0}")]
    Frame(#[from] FrameError),
    /// The board answered a request with something else.
    #[error("protocol: {request}: unexpected {answer:?}")]
    Unexpected {
        /// The request, by name.
        request: &'static str,
        /// What came back instead.
        answer: Box<Answer>,
    },
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

/// "end of file", or the OS's error.
fn lost(e: &Option<std::io::Error>) -> &dyn std::fmt::Display {
    match e {
        Some(e) => e,
        None => &"end of file",
    }
}
