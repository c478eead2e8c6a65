//! # conductor-devices
//!
//! The communication section of Conductor (thesis §2.4): **Device** (a node on a bus: tags
//! requests with its credential, interprets replies), **Protocol** (a vendor's packet format:
//! bundles a tick's requests into the fewest packets, scans received words into replies) and
//! **Hardware** (the gatekeeper that moves words on and off the bus without blocking).
//!
//! Data flow, per executor tick (each stage at its own divisor of the base rate):
//!
//! ```text
//! downstream: State ─sample/write→ Device ─Request→ Protocol ─words→ Hardware ─→ bus
//! upstream:   bus ─→ Hardware ─words→ Protocol ─Reply→ Device ─Update→ State
//! ```
//!
//! Stages exchange work through fixed-capacity [`Bounded`] queues sized at start-up; nothing here
//! allocates, locks or blocks once built. Components are chosen by `kind` in the manifest through
//! [`kinds`], whose parameter specs also drive manifest validation.
//!
//! | Module | Contents |
//! |---|---|
//! | [`hw`] | transports: serial, UDP, SocketCAN, SLCAN, in-memory byte pipe and CAN bus |
//! | [`protocol_stage`] | protocol stages: Dynamixel 2.0 and 1.0 (bundling), CAN motors (MIT, ODrive) |
//! | [`device`] | devices: Dynamixel X-series, Dynamixel 1.0 (AX/MX), MIT-mode motor, ODrive axis |
//! | [`sim`] | simulators speaking the real wire protocols, fault injection, pty/UDP runners |
//! | [`kinds`] | the registry of manifest kinds: each driver declares its own entry (parameters, typed builder, safe actions) |
//! | [`lifecycle`] | bring-up, enable, trips, faults and safe-action confirmation of a device |

#![warn(missing_docs)]

/// Implements `Debug` for a type by the fields named, in that order: the transports and
/// simulators hold OS handles, threads and buffers with nothing to read in a log, so each
/// shows only what identifies it.
macro_rules! debug_fields {
    ($ty:ident { $($field:ident),+ $(,)? }) => {
        impl std::fmt::Debug for $ty {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.debug_struct(stringify!($ty))
                    $(.field(stringify!($field), &self.$field))+
                    .finish()
            }
        }
    };
}

mod component;
pub mod device;
pub mod hw;
pub mod kinds;
pub mod lifecycle;
mod link;
mod message;
mod outstanding;
pub mod protocol_stage;
mod queue;
pub mod sim;

pub use component::{
    BusCondition, Channel, ControllerState, Device, Hardware, HwCounters, HwError, Protocol,
    ProtocolCounters, SafeAction, TickCtx,
};
pub use lifecycle::{DeviceStatus, Failure, Phase, SafeProgress, Startup};
pub use link::{Link, LinkCounters, LinkOf, LinkState, Opener};
pub use message::{Credential, MitSpecial, Op, Reply, ReplyData, Request, Update};
pub use nix::errno::Errno;
pub use outstanding::{Outstanding, Pending};
pub use queue::{Bounded, Full};
