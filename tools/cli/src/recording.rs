//! The MCAP layout of a Conductor recording and its reader (`conductor-cli-formats`, which
//! builds without the bus), and what `record` takes from the bus to write it.

use conductor_bus::StateSample;
pub use conductor_cli_formats::recording::*;

/// The message of a bus sample.
pub fn message_of(s: &StateSample) -> Message {
    Message::of_sample(s.value, s.status, s.t_sample_ns, s.seq, s.tick)
}
