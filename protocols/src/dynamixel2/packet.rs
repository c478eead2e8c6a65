//! Decoding of single packets, status packets and the status error byte.

use super::stuffing::unstuff_in_place;
use super::{crc, Instruction, BROADCAST_ID, HEADER, MAX_DEVICE_ID};
use crate::code_table::code_table;
use crate::dynamixel_common::addressable;

/// A CRC-checked packet with stuffing removed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Packet<'a> {
    /// Device ID (0xFE for broadcast instructions and fast read replies).
    pub id: u8,
    /// Instruction byte (0x55 for a status packet).
    pub instruction: u8,
    /// Bytes after the instruction byte, unstuffed, without the CRC. For a status packet the
    /// first byte is the error byte.
    pub params: &'a [u8],
    /// Bytes the packet occupied on the wire (stuffed, header and CRC included).
    pub wire_len: usize,
}

impl Packet<'_> {
    /// True for a status packet (servo → host).
    pub fn is_status(&self) -> bool {
        self.instruction == Instruction::Status as u8
    }

    /// The instruction, if the code is a known one.
    pub fn instruction_kind(&self) -> Option<Instruction> {
        Instruction::from_code(self.instruction)
    }
}

/// Why bytes are not a valid packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    /// Fewer bytes than the header or the length field requires.
    #[error("incomplete packet: {needed} bytes needed, {got} present")]
    Incomplete {
        /// Bytes needed to proceed.
        needed: usize,
        /// Bytes present.
        got: usize,
    },
    /// The bytes do not start with `FF FF FD 00`.
    #[error("no packet header")]
    BadHeader,
    /// ID 0xFD or 0xFF.
    #[error("invalid ID {0:#04x}")]
    BadId(u8),
    /// LEN below 3 (instruction + CRC).
    #[error("invalid length field {0}")]
    BadLength(u16),
    /// The CRC does not match.
    #[error("CRC mismatch: packet says {received:#06x}, bytes give {computed:#06x}")]
    Crc {
        /// CRC carried by the packet.
        received: u16,
        /// CRC computed over the packet.
        computed: u16,
    },
}

pub(crate) fn id_is_valid(id: u8) -> bool {
    addressable(id, MAX_DEVICE_ID)
}

/// Checks the packet at the start of `buf` (header, ID, length, CRC) without modifying it and
/// returns its wire length. Bytes after the packet are ignored.
pub fn check_frame(buf: &[u8]) -> Result<usize, ParseError> {
    if buf.len() < 7 {
        return Err(ParseError::Incomplete {
            needed: 7,
            got: buf.len(),
        });
    }
    if buf[..4] != HEADER {
        return Err(ParseError::BadHeader);
    }
    if !id_is_valid(buf[4]) {
        return Err(ParseError::BadId(buf[4]));
    }
    let len = u16::from_le_bytes([buf[5], buf[6]]);
    if len < 3 {
        return Err(ParseError::BadLength(len));
    }
    let total = 7 + len as usize;
    if buf.len() < total {
        return Err(ParseError::Incomplete {
            needed: total,
            got: buf.len(),
        });
    }
    let received = u16::from_le_bytes([buf[total - 2], buf[total - 1]]);
    let computed = crc::crc16(&buf[..total - 2]);
    if received != computed {
        return Err(ParseError::Crc { received, computed });
    }
    Ok(total)
}

/// Checks the packet at the start of `buf` and removes its stuffing in place.
///
/// Fast read replies (status from ID 0xFE) are not stuffed and are left as they are.
pub fn parse_in_place(buf: &mut [u8]) -> Result<Packet<'_>, ParseError> {
    let total = check_frame(buf)?;
    Ok(decode_checked(&mut buf[..total]))
}

/// Builds a [`Packet`] from a frame whose header, length and CRC were already checked
/// (`frame.len() >= 10`).
pub(crate) fn decode_checked(frame: &mut [u8]) -> Packet<'_> {
    let wire_len = frame.len();
    let id = frame[4];
    let instruction = frame[7];
    let body = &mut frame[8..wire_len - 2];
    let fast_reply = id == BROADCAST_ID && instruction == Instruction::Status as u8;
    let n = if fast_reply {
        body.len()
    } else {
        unstuff_in_place(body)
    };
    Packet {
        id,
        instruction,
        params: &body[..n],
        wire_len,
    }
}

code_table! {
    /// Device errors carried in bits 0–6 of the status error byte.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
    pub enum DeviceError {
        /// 0x01: the instruction could not be processed.
        #[error("result fail")]
        ResultFail = 1,
        /// 0x02: undefined instruction, or Action without Reg Write.
        #[error("instruction error")]
        Instruction = 2,
        /// 0x03: the device saw a CRC mismatch.
        #[error("CRC error")]
        Crc = 3,
        /// 0x04: value outside the address's range.
        #[error("data range error")]
        DataRange = 4,
        /// 0x05: data shorter than the item.
        #[error("data length error")]
        DataLength = 5,
        /// 0x06: value outside the configured limit.
        #[error("data limit error")]
        DataLimit = 6,
        /// 0x07: read-only/write-only/undefined address, or EEPROM write with torque on.
        #[error("access error")]
        Access = 7,
    }
    /// A code the protocol does not define.
    #[error("unknown error number {0:#04x}")]
    other Unknown(u8);
}

/// The status packet's error byte: bit 7 = hardware alert, bits 0–6 = error number.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ErrorByte(pub u8);

impl ErrorByte {
    /// Alert bit: a hardware error is latched (read Hardware Error Status, address 70 on X).
    pub fn alert(self) -> bool {
        self.0 & 0x80 != 0
    }

    /// The error number, if any.
    pub fn error(self) -> Option<DeviceError> {
        match self.0 & 0x7F {
            0 => None,
            n => Some(DeviceError::from(n)),
        }
    }

    /// No alert and no error.
    pub fn is_ok(self) -> bool {
        self.0 == 0
    }
}

/// Why a packet is not the status packet expected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum StatusError {
    /// The instruction byte is not 0x55.
    #[error("not a status packet (instruction {0:#04x})")]
    NotStatus(u8),
    /// No error byte.
    #[error("status packet without error byte")]
    Empty,
    /// The parameters have an unexpected length.
    #[error("status parameters: {got} bytes where {expected} were expected")]
    Length {
        /// Expected parameter bytes (without the error byte).
        expected: usize,
        /// Present parameter bytes.
        got: usize,
    },
}

/// A decoded status packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Status<'a> {
    /// Replying device.
    pub id: u8,
    /// Error byte.
    pub error: ErrorByte,
    /// Data after the error byte (e.g. the bytes of a READ).
    pub data: &'a [u8],
}

impl<'a> Status<'a> {
    /// Interprets a packet as a status packet.
    pub fn from_packet(p: &Packet<'a>) -> Result<Self, StatusError> {
        if !p.is_status() {
            return Err(StatusError::NotStatus(p.instruction));
        }
        let (&err, data) = p.params.split_first().ok_or(StatusError::Empty)?;
        Ok(Status {
            id: p.id,
            error: ErrorByte(err),
            data,
        })
    }

    /// The data as a little-endian unsigned integer of 1, 2 or 4 bytes (`None` otherwise).
    pub fn data_u32(&self) -> Option<u32> {
        match *self.data {
            [a] => Some(a as u32),
            [a, b] => Some(u16::from_le_bytes([a, b]) as u32),
            [a, b, c, d] => Some(u32::from_le_bytes([a, b, c, d])),
            _ => None,
        }
    }
}

/// The answer to PING.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PingInfo {
    /// Replying device.
    pub id: u8,
    /// Model number (e.g. 1020 for XM430-W350).
    pub model: u16,
    /// Firmware version.
    pub firmware: u8,
}

impl PingInfo {
    /// Decodes a PING status (3 data bytes: model LE, firmware).
    pub fn from_status(s: &Status<'_>) -> Result<Self, StatusError> {
        match *s.data {
            [lo, hi, fw] => Ok(PingInfo {
                id: s.id,
                model: u16::from_le_bytes([lo, hi]),
                firmware: fw,
            }),
            _ => Err(StatusError::Length {
                expected: 3,
                got: s.data.len(),
            }),
        }
    }
}
