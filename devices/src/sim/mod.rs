//! Simulators.
//!
//! * [`SineHardware`], [`LoopbackHardware`], [`SimProtocol`], [`SimDevice`]: the built-in
//!   simulated bus of the executor's stress test (no wire protocol).
//! * [`dxl`]: a Dynamixel Protocol 2.0 bus of X-series servos speaking the real wire protocol.
//! * [`can_motors`]: MIT-mode motors and ODrive axes answering real CAN frames.
//! * [`slcan_adapter`]: an SLCAN USB-CAN adapter with CAN motors behind it.
//! * [`fault`]: seeded fault injection (corrupt, drop, delay, truncate) on any byte stream.
//! * [`hardware`]: the simulators as in-process [`crate::Hardware`], for tests and manifests.
//! * [`runner`]: the simulators on a pseudo-terminal or UDP socket, as a separate process
//!   (`conductor-sim`).
//! * [`socketcan_bus`]: the CAN motors on a real SocketCAN interface (vcan0 in the CAN VM).

pub(crate) mod basic;
pub mod can_motors;
pub mod dxl;
pub mod fault;
pub mod hardware;
pub mod runner;
pub mod slcan_adapter;
pub mod socketcan_bus;
mod worker;

pub use basic::{LoopbackHardware, SimDevice, SimKind, SimProtocol, SimWord, SineHardware};
