//! Single-packet decoding, status packets and the error bits.

use super::{checksum, HEADER, MAX_DEVICE_ID};
use crate::dynamixel_common::addressable;

/// A checksum-verified packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Packet<'a> {
    /// Device ID.
    pub id: u8,
    /// Instruction (instruction packet) or error byte (status packet): the protocol does not
    /// say which; the direction does.
    pub code: u8,
    /// Parameters, without the checksum.
    pub params: &'a [u8],
}

/// Why bytes are not a valid packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    /// Fewer bytes than needed.
    #[error("incomplete packet: {needed} bytes needed, {got} present")]
    Incomplete {
        /// Bytes needed.
        needed: usize,
        /// Bytes present.
        got: usize,
    },
    /// No `FF FF` header.
    #[error("no packet header")]
    BadHeader,
    /// ID 0xFF.
    #[error("invalid ID {0:#04x}")]
    BadId(u8),
    /// LEN below 2.
    #[error("invalid length field {0}")]
    BadLength(u8),
    /// Checksum mismatch.
    #[error("checksum mismatch: packet says {received:#04x}, bytes give {computed:#04x}")]
    Checksum {
        /// Carried by the packet.
        received: u8,
        /// Computed.
        computed: u8,
    },
}

/// Parses the packet at the start of `buf`; returns it and its wire length.
pub fn parse(buf: &[u8]) -> Result<(Packet<'_>, usize), ParseError> {
    if buf.len() < 4 {
        return Err(ParseError::Incomplete {
            needed: 4,
            got: buf.len(),
        });
    }
    if buf[..2] != HEADER {
        return Err(ParseError::BadHeader);
    }
    if !addressable(buf[2], MAX_DEVICE_ID) {
        return Err(ParseError::BadId(buf[2]));
    }
    if buf[3] < 2 {
        return Err(ParseError::BadLength(buf[3]));
    }
    let total = 4 + buf[3] as usize;
    if buf.len() < total {
        return Err(ParseError::Incomplete {
            needed: total,
            got: buf.len(),
        });
    }
    let computed = checksum(&buf[2..total - 1]);
    if computed != buf[total - 1] {
        return Err(ParseError::Checksum {
            received: buf[total - 1],
            computed,
        });
    }
    Ok((decode_checked(&buf[..total]), total))
}

pub(crate) fn decode_checked(frame: &[u8]) -> Packet<'_> {
    Packet {
        id: frame[2],
        code: frame[4],
        params: &frame[5..frame.len() - 1],
    }
}

/// The status error byte (bit flags).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ErrorBits(pub u8);

impl ErrorBits {
    /// Bit 0: input voltage out of range.
    pub const INPUT_VOLTAGE: u8 = 1 << 0;
    /// Bit 1: goal position outside the angle limits.
    pub const ANGLE_LIMIT: u8 = 1 << 1;
    /// Bit 2: overheating.
    pub const OVERHEATING: u8 = 1 << 2;
    /// Bit 3: command out of range.
    pub const RANGE: u8 = 1 << 3;
    /// Bit 4: checksum of the instruction was wrong.
    pub const CHECKSUM: u8 = 1 << 4;
    /// Bit 5: load exceeds the torque limit.
    pub const OVERLOAD: u8 = 1 << 5;
    /// Bit 6: undefined instruction or ACTION without REG_WRITE.
    pub const INSTRUCTION: u8 = 1 << 6;

    /// No error bit set.
    pub fn is_ok(self) -> bool {
        self.0 == 0
    }
    /// Whether all bits of `mask` are set.
    pub fn has(self, mask: u8) -> bool {
        self.0 & mask == mask
    }
    /// Input voltage error.
    pub fn input_voltage(self) -> bool {
        self.has(Self::INPUT_VOLTAGE)
    }
    /// Angle limit error.
    pub fn angle_limit(self) -> bool {
        self.has(Self::ANGLE_LIMIT)
    }
    /// Overheating error.
    pub fn overheating(self) -> bool {
        self.has(Self::OVERHEATING)
    }
    /// Range error.
    pub fn range(self) -> bool {
        self.has(Self::RANGE)
    }
    /// Checksum error.
    pub fn checksum(self) -> bool {
        self.has(Self::CHECKSUM)
    }
    /// Overload error.
    pub fn overload(self) -> bool {
        self.has(Self::OVERLOAD)
    }
    /// Instruction error.
    pub fn instruction(self) -> bool {
        self.has(Self::INSTRUCTION)
    }
}

/// A packet read as a status packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Status<'a> {
    /// Replying device.
    pub id: u8,
    /// Error flags.
    pub error: ErrorBits,
    /// Data (e.g. the bytes of a READ).
    pub data: &'a [u8],
}

impl<'a> Status<'a> {
    /// Reads `p` as a status packet (its code byte is the error byte).
    pub fn from_packet(p: &Packet<'a>) -> Self {
        Status {
            id: p.id,
            error: ErrorBits(p.code),
            data: p.params,
        }
    }

    /// Data as a little-endian u8 or u16.
    pub fn data_u16(&self) -> Option<u16> {
        match *self.data {
            [a] => Some(a as u16),
            [a, b] => Some(u16::from_le_bytes([a, b])),
            _ => None,
        }
    }
}
