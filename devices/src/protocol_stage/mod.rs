//! Protocol stages: bundle a tick's requests into the fewest packets, scan received words into
//! replies matched to the requests by credential, and report what never came as missing.
//!
//! | Type | Word | Bundling |
//! |---|---|---|
//! | [`Dxl2Protocol`] | `u8` | goal writes → one SYNC WRITE per register; reads → one SYNC READ / FAST SYNC READ (BULK / FAST BULK READ for mixed spans) |
//! | [`Dxl1Protocol`] | `u8` | writes → SYNC WRITE per register; reads → one BULK READ (MX) or one READ per bus window (AX) |
//! | [`CanMotorProtocol`] | CAN frame | one frame per device and tick (MIT command, ODrive message or RTR request), all sent together |
//!
//! The two Dynamixel stages are one stage (`register_bus`) over one bus core (`transactions`:
//! queues, coalescing, transactions, deadlines, reply matching); each protocol adds only its
//! dialect: the encoders, the read instruction, the scanner and how its error byte reads.

pub(crate) mod can_motors;
pub(crate) mod dxl1;
pub(crate) mod dxl2;
mod register_bus;
mod transactions;

pub use can_motors::{
    mit_limits, mit_model, odrive_get, parse_model_table, CanMotorProtocol, ModelTableError,
    MIT_MODELS, MIT_MODEL_NAMES,
};
pub use dxl1::{Dxl1Protocol, Dxl1ReadMode};
pub use dxl2::{fast_read_fits, fast_reply_len, Dxl2Protocol, Dxl2ReadMode};
pub use transactions::{wire_ns, Timing};
