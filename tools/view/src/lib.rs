#![doc = include_str!("../README.md")]

pub mod messages;
mod requests;
mod view;

use std::net::{Ipv4Addr, SocketAddr};
use std::time::Duration;

use conductor_bus::BusError;

pub use view::{View, ViewReport};

/// Default address: loopback only, Foxglove's usual port.
pub const DEFAULT_LISTEN: SocketAddr =
    SocketAddr::new(std::net::IpAddr::V4(Ipv4Addr::LOCALHOST), 8765);

/// How to run a view.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewOptions {
    /// Where the WebSocket server listens (default [`DEFAULT_LISTEN`]; port 0: any free port).
    pub listen: SocketAddr,
    /// Send the nearest limit for a setpoint outside a state's limits (as `conductor set
    /// --clamp`) instead of refusing it.
    pub clamp: bool,
    /// The server's name, shown by Foxglove.
    pub name: String,
    /// How often the domain is searched for new states and executors.
    pub discover_every: Duration,
    /// How long a setpoint waits for the sample that carries the executor's verdict.
    pub verdict_timeout: Duration,
}

impl Default for ViewOptions {
    fn default() -> Self {
        Self {
            listen: DEFAULT_LISTEN,
            clamp: false,
            name: "conductor".into(),
            discover_every: Duration::from_millis(500),
            verdict_timeout: Duration::from_secs(1),
        }
    }
}

/// Why a view cannot run.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    /// The bus failed (discovery, a subscriber).
    #[error(transparent)]
    Bus(#[from] BusError),
    /// The server could not listen.
    #[error("cannot listen on {addr}: {reason}")]
    Listen {
        /// The address asked for.
        addr: SocketAddr,
        /// Why (the address is in use, not this machine's, ...).
        reason: String,
    },
    /// A channel could not be created.
    #[error("cannot create the channel {topic}: {reason}")]
    Channel {
        /// Its topic.
        topic: String,
        /// Why.
        reason: String,
    },
    /// A message could not be encoded.
    #[error("encoding a message: {0}")]
    Encode(String),
}
