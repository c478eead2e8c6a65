//! # score-gateway
//!
//! Puts a Score board on the Conductor bus. It speaks `score_link` (from
//! `conductor-protocols`) on the board's second USB CDC-ACM port and publishes each of the
//! board's variables as a State `conductor/score-<board>/<variable>`, with its unit, rate and
//! writability as service attributes; setpoints sent to `conductor/score-<board>/commands` (a
//! [`conductor_bus::Controller`]) on writable variables are forwarded to the board. Samples are
//! stamped with the board's own clock, mapped to the host's `CLOCK_MONOTONIC` ([`clock`]).
//! The gateway survives unplug/replug: it reopens the port, re-lists and re-subscribes, and
//! restores the board's configuration if it came back empty ([`gateway`]).

#[cfg(feature = "cli")]
pub mod cli;
pub mod client;
pub mod clock;
pub mod error;
pub mod gateway;

#[cfg(feature = "cli")]
pub use cli::main_with_args;
pub use error::GatewayError;
pub use gateway::{Gateway, Options, Stats};
