//! # conductor-executor
//!
//! What the user runs: a **manifest** (the `conductor-manifest` crate) describes the robot; one **executor** process per
//! subsystem keeps every State current at its rate on a real-time thread; the **launcher**
//! validates the manifest, starts and supervises the executors.
//!
//! * [`stages`] — the tick scheduler over the `conductor-devices` stage traits.
//! * [`executor`] — the stages on the bus, and the absolute-deadline loop.
//! * [`events`] — the log of the hardware edge, fed from the real-time thread without blocking.
//! * [`schedule`], [`rt`], [`signals`] — deadlines, real-time set-up, stop requests.
//! * [`process`] — the `conductor-executor` program.
//! * [`launcher`] — `conductor launch`: start, supervise and stop the executors of a manifest.
//! * [`soak`] — the fault campaign on the simulated robots of deploy/ (`conductor-soak`).
//! * [`cleanup`] — the domain's iceoryx2 nodes, and removing what dead ones left behind.
//!
//! See the crate's README for the data flow of one tick.
#![warn(missing_docs)]

/// `eprintln!` that ignores a closed stderr (a launcher that went away must not make an executor
/// panic while it puts its devices in their safe state).
#[macro_export]
#[doc(hidden)]
macro_rules! note {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($arg)*);
    }};
}

pub mod cleanup;
pub mod events;
pub mod executor;
pub mod launcher;
pub mod process;
pub mod profile;
/// Real-time set-up, shared with the gateways and controllers (it lives in the bus crate).
pub use conductor_bus::rt;
pub mod schedule;
pub mod signals;
pub mod soak;
pub mod stages;
