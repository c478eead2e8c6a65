//! # conductor-cli-formats
//!
//! The formats the `conductor` CLI reads from outside the process, kept apart from the bus so
//! that they build (and fuzz) on their own:
//!
//! * [`recording`]: the MCAP layout `record` writes and the reader `replay` and `plot` use
//!   ([`recording::Recording`]);
//! * [`udp`]: the thesis' plain-text protocol `udp-gateway` answers, one datagram per request.
//!
//! `conductor-cli` re-exports both (`conductor_cli::recording`, `conductor_cli::udp::protocol`)
//! and adds what needs the bus (a bus sample as a message, a state's channel metadata).

pub mod recording;
pub mod udp;
