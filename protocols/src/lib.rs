//! Sans-IO codecs and stream scanners for the actuator buses Conductor drives.
//!
//! Nothing in this crate performs I/O, allocates or panics on bad input. Encoders write into a
//! caller-provided `&mut [u8]` and return the number of bytes written (or a typed error when the
//! buffer is too small or the request is invalid); decoders borrow their input. Each byte-stream
//! protocol has a fixed-capacity *scanner* that turns bytes arriving in any chunking into whole,
//! integrity-checked packets and counts every byte it throws away by cause.
//!
//! | Module | Protocol |
//! |---|---|
//! | [`dynamixel2`] | ROBOTIS Dynamixel Protocol 2.0 (X-series): instructions, stuffing, CRC, status, fast replies, scanner |
//! | [`dynamixel1`] | ROBOTIS Dynamixel Protocol 1.0 (AX/MX/RX): checksum, instructions, status, scanner |
//! | [`can`] | A classic CAN frame type implementing [`embedded_can::Frame`] |
//! | [`mit_can`] | "MIT mode" CAN motors (Ben Katz firmware, CubeMars AK series) |
//! | [`odrive_can`] | ODrive CAN Simple, firmware 0.6.x |
//! | [`score_link`] | The COBS-framed, versioned link between a Score board and its gateway |
//! | [`slcan`] | SLCAN / LAWICEL ASCII serial-line CAN: host and adapter sides, line scanner |
//! | [`scan`] | The discard counters shared by the scanners |
//!
//! See `README.md` for how bytes flow through the crate and which vendor-manual errors it corrects.
#![no_std]
#![forbid(unsafe_code)]

#[cfg(test)]
extern crate std;

pub mod can;
mod code_table;
pub mod dynamixel1;
pub mod dynamixel2;
mod dynamixel_common;
pub mod mit_can;
pub mod odrive_can;
pub mod scan;
pub mod score_link;
pub mod slcan;
mod writer;

pub use writer::BufferTooSmall;
