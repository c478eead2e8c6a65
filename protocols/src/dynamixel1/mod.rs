//! ROBOTIS Dynamixel Protocol 1.0 (AX-12, MX on P1 firmware, RX).
//!
//! Instruction `FF FF ID LEN INST params… CHK`, status `FF FF ID LEN ERR params… CHK`,
//! `LEN = params + 2`, `CHK = !(ID + LEN + INST/ERR + Σparams)` (low byte). No stuffing, no
//! reserved byte; IDs 0–253, broadcast 0xFE.
//!
//! Encoders: [`ping`], [`read`], [`write()`], [`reg_write`], [`action`], [`reset`],
//! [`sync_write`], [`bulk_read`] (MX only), and [`status`] for simulators. Decoding:
//! [`Scanner`] (byte stream → checked [`Packet`]s), [`parse`] (one packet),
//! [`Status`] and [`ErrorBits`].

mod encode;
mod packet;
mod scanner;

use crate::code_table::code_table;
pub use crate::dynamixel_common::EncodeError;
pub use encode::{
    action, bulk_read, ping, read, reg_write, reset, status, sync_write, write, BulkReadEntry,
};
pub use packet::{parse, ErrorBits, Packet, ParseError, Status};
pub use scanner::{Dxl1Framing, Scanner};

/// The two bytes every packet starts with.
pub const HEADER: [u8; 2] = [0xFF, 0xFF];
/// The broadcast ID.
pub const BROADCAST_ID: u8 = crate::dynamixel_common::BROADCAST_ID;
/// The largest device ID.
pub const MAX_DEVICE_ID: u8 = 0xFD;
/// Largest packet: LEN is one byte.
pub const MAX_PACKET: usize = 4 + 255;

code_table! {
    /// Instruction codes.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum Instruction {
        /// 0x01.
        Ping = 0x01,
        /// 0x02: read (addr, len).
        Read = 0x02,
        /// 0x03: write (addr, data…).
        Write = 0x03,
        /// 0x04: staged write.
        RegWrite = 0x04,
        /// 0x05: run staged writes.
        Action = 0x05,
        /// 0x06: factory reset.
        Reset = 0x06,
        /// 0x83: same address/length on many IDs, no reply.
        SyncWrite = 0x83,
        /// 0x92: bulk read (MX only).
        BulkRead = 0x92,
    }
}

/// The 1.0 checksum over ID, LEN, INST/ERR and parameters (the bytes after the header).
pub fn checksum(body: &[u8]) -> u8 {
    !body.iter().fold(0u8, |a, &b| a.wrapping_add(b))
}
