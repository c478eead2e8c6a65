//! ROBOTIS Dynamixel Protocol 2.0 (X-series, MX(2.0), P-series).
//!
//! Packets are `FF FF FD 00 | ID | LEN_L LEN_H | INST | params… | CRC_L CRC_H` with
//! little-endian fields, byte stuffing over the instruction/parameter region and a
//! CRC-16/UMTS over the stuffed bytes ([`crc`]).
//!
//! * Encoding (host side): [`ping`], [`read`], [`write()`], [`reg_write`], [`action`],
//!   [`factory_reset`], [`reboot`], [`clear_multi_turn`], [`control_table_backup`],
//!   [`sync_read`], [`sync_write`], [`fast_sync_read`], [`bulk_read`], [`bulk_write`],
//!   [`fast_bulk_read`].
//! * Encoding (servo/simulator side): [`status`], [`fast_status`].
//! * Decoding: [`Scanner`] turns a byte stream into [`Packet`]s (stuffing removed);
//!   [`parse_in_place`] does the same for one packet in a buffer. [`Status`], [`PingInfo`] and
//!   [`FastReply`] interpret them; [`ErrorByte`] decodes the status error byte; [`Request`]
//!   decodes instruction packets (servo/simulator side).
//! * Wire sizes for timeouts and bus budgets: [`instruction_len`], [`status_len`],
//!   [`fast_reply_len`] (without stuffing, which can only add bytes).

pub mod crc;
mod encode;
mod fast;
mod packet;
mod request;
mod scanner;
pub mod stuffing;

use crate::code_table::code_table;
pub use crate::dynamixel_common::EncodeError;
pub use encode::{
    action, bulk_read, bulk_write, clear_multi_turn, control_table_backup, factory_reset,
    fast_bulk_read, fast_status, fast_sync_read, ping, read, reboot, reg_write, status, sync_read,
    sync_write, write, BackupOp, BulkReadEntry, BulkWriteEntry, FactoryResetMode, FastStatusSlice,
};
pub use fast::{FastReply, FastReplyError, FastSlice, FastSlices};
pub use packet::{
    check_frame, parse_in_place, DeviceError, ErrorByte, Packet, ParseError, PingInfo, Status,
    StatusError,
};
pub use request::{BulkWriteEntries, Request, RequestError};
pub use scanner::{Dxl2Framing, Scanner};

/// The four bytes every packet starts with (`FF FF FD` plus the reserved `00`).
pub const HEADER: [u8; 4] = [0xFF, 0xFF, 0xFD, 0x00];
/// The broadcast ID.
pub const BROADCAST_ID: u8 = crate::dynamixel_common::BROADCAST_ID;
/// The largest ID a device can have.
pub const MAX_DEVICE_ID: u8 = 0xFC;
/// Bytes of a packet that are not parameters: header(4), ID, LEN(2), INST, CRC(2).
pub const OVERHEAD: usize = 10;

/// Wire length of an instruction packet with `params` parameter bytes (before stuffing).
pub const fn instruction_len(params: usize) -> usize {
    OVERHEAD + params
}

/// Wire length of a status packet carrying `data` bytes (error byte included; before stuffing).
/// DynamixelSDK's read timeout uses the same `data + 11`.
pub const fn status_len(data: usize) -> usize {
    OVERHEAD + 1 + data
}

/// Wire length of the combined reply to a fast read of `devices` devices with `data` bytes
/// each (never stuffed).
pub const fn fast_reply_len(devices: usize, data: usize) -> usize {
    if devices == 0 {
        return 0;
    }
    OVERHEAD + devices * (4 + data) - 2
}

code_table! {
    /// Instruction codes (protocol2.md, newest).
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum Instruction {
        /// 0x01: answered with model number and firmware version.
        Ping = 0x01,
        /// 0x02: read `len` bytes from `addr`.
        Read = 0x02,
        /// 0x03: write bytes at `addr`.
        Write = 0x03,
        /// 0x04: stage a write, applied by [`Instruction::Action`].
        RegWrite = 0x04,
        /// 0x05: run the staged writes.
        Action = 0x05,
        /// 0x06: restore factory settings.
        FactoryReset = 0x06,
        /// 0x08: reboot.
        Reboot = 0x08,
        /// 0x10: clear the multi-turn revolution count.
        Clear = 0x10,
        /// 0x20: store or restore the control table backup.
        ControlTableBackup = 0x20,
        /// 0x55: a status packet (servo → host).
        Status = 0x55,
        /// 0x82: one status packet per listed ID.
        SyncRead = 0x82,
        /// 0x83: same address and length on many IDs, no reply.
        SyncWrite = 0x83,
        /// 0x8A: like Sync Read, but one combined reply.
        FastSyncRead = 0x8A,
        /// 0x92: per-ID address and length, one status packet per ID.
        BulkRead = 0x92,
        /// 0x93: per-ID address, length and data, no reply.
        BulkWrite = 0x93,
        /// 0x9A: like Bulk Read, but one combined reply.
        FastBulkRead = 0x9A,
    }
}
