//! SLCAN / LAWICEL ASCII serial-line CAN, both directions.
//!
//! * Host side: [`Command::encode`] (and [`open_sequence`]) writes commands; [`HostScanner`]
//!   splits what the adapter sends into [`Response`]s (acks, nacks, received frames, query
//!   replies), in whatever order they interleave; [`PendingAcks`] matches acks to commands.
//! * Adapter side (simulators): [`DeviceScanner`] parses host commands ([`Command::decode`]);
//!   [`Response::encode`] writes acks and frames.
//!
//! Every line ends with CR; the adapter acknowledges with CR (OK) or BEL (error). Devices
//! differ ([`Dialect`]):
//!
//! * **S7** means 800 kbit/s for LAWICEL, the Linux kernel and CanHacker, but 750 kbit/s for
//!   CANable firmware and python-can. [`Bitrate`] has both values and only the dialect's one
//!   encodes to (or decodes from) `S7`; the other is refused rather than silently sent at the
//!   wrong speed. The default dialect is [`Dialect::LAWICEL`], the protocol's definition.
//! * After a successful `t`/`T` (and `r`/`R`) LAWICEL CAN232/CANUSB answer `z\r`/`Z\r`; CANable
//!   answers `\r`. The host scanner accepts both whatever the dialect; the dialect only selects
//!   what a simulator sends.
//!
//! SLCAN has no checksum: the scanners guarantee syntax, not integrity.

mod acks;
mod command;
mod response;
mod scanner;

pub use acks::{Acked, CommandKind, PendingAcks, QueueFull};
pub use command::{open_sequence, Command};
pub use response::Response;
pub use scanner::{DeviceScanner, HostScanner, Line, LineScanner, LineStats};

use crate::can::CanFrame;
use crate::writer::Writer;
use crate::BufferTooSmall;
use embedded_can::{ExtendedId, Frame, Id, StandardId};

/// Carriage return: end of every line, and the OK acknowledgement.
pub const CR: u8 = b'\r';
/// Bell: the error acknowledgement.
pub const BEL: u8 = 0x07;
/// Longest standard line: `T1111222281122334455667788EA5F\r` (SLC_MTU without the NUL).
pub const MAX_FRAME_LINE: usize = 31;

/// What `S7` means.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum S7 {
    /// 800 kbit/s (LAWICEL, Linux kernel, CanHacker).
    Kbit800,
    /// 750 kbit/s (CANable firmware, python-can).
    Kbit750,
}

/// How a device acknowledges a transmitted frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TxAck {
    /// `\r`, like any other command (CANable, CanHacker document).
    Cr,
    /// `z\r` after `t`/`r`, `Z\r` after `T`/`R` (LAWICEL CAN232/CANUSB).
    Z,
}

/// Device-variant choices of the SLCAN dialect.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dialect {
    /// Meaning of `S7`.
    pub s7: S7,
    /// Acknowledgement of transmitted frames (used when encoding adapter replies).
    pub tx_ack: TxAck,
}

impl Dialect {
    /// LAWICEL CAN232/CANUSB and the Linux kernel: S7 = 800k, `z`/`Z` acks.
    pub const LAWICEL: Dialect = Dialect {
        s7: S7::Kbit800,
        tx_ack: TxAck::Z,
    };
    /// CANable (candlelight `slcan` firmware) and python-can: S7 = 750k, CR acks.
    pub const CANABLE: Dialect = Dialect {
        s7: S7::Kbit750,
        tx_ack: TxAck::Cr,
    };
}

impl Default for Dialect {
    fn default() -> Self {
        Dialect::LAWICEL
    }
}

/// The standard bitrates of the `Sn` command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Bitrate {
    /// S0.
    K10,
    /// S1.
    K20,
    /// S2.
    K50,
    /// S3.
    K100,
    /// S4.
    K125,
    /// S5.
    K250,
    /// S6.
    K500,
    /// S7 in the CANable dialect.
    K750,
    /// S7 in the LAWICEL dialect.
    K800,
    /// S8.
    M1,
    /// S9 (83.3 kbit/s, only some adapters).
    K83_3,
}

impl Bitrate {
    /// Bits per second (83 333 for S9).
    pub fn bps(self) -> u32 {
        use Bitrate::*;
        match self {
            K10 => 10_000,
            K20 => 20_000,
            K50 => 50_000,
            K100 => 100_000,
            K125 => 125_000,
            K250 => 250_000,
            K500 => 500_000,
            K750 => 750_000,
            K800 => 800_000,
            M1 => 1_000_000,
            K83_3 => 83_333,
        }
    }

    /// The bitrate for a bits-per-second value, if standard (83 333 or 83 300 for S9).
    pub fn from_bps(bps: u32) -> Option<Self> {
        use Bitrate::*;
        Some(match bps {
            10_000 => K10,
            20_000 => K20,
            50_000 => K50,
            100_000 => K100,
            125_000 => K125,
            250_000 => K250,
            500_000 => K500,
            750_000 => K750,
            800_000 => K800,
            1_000_000 => M1,
            83_300 | 83_333 => K83_3,
            _ => return None,
        })
    }

    /// The `Sn` digit in `dialect`; `None` for the S7 value the dialect does not mean.
    pub fn code(self, dialect: &Dialect) -> Option<u8> {
        use Bitrate::*;
        Some(match self {
            K10 => 0,
            K20 => 1,
            K50 => 2,
            K100 => 3,
            K125 => 4,
            K250 => 5,
            K500 => 6,
            K750 if dialect.s7 == S7::Kbit750 => 7,
            K800 if dialect.s7 == S7::Kbit800 => 7,
            K750 | K800 => return None,
            M1 => 8,
            K83_3 => 9,
        })
    }

    /// The bitrate of `Sn` digit `code` in `dialect`.
    pub fn from_code(code: u8, dialect: &Dialect) -> Option<Self> {
        use Bitrate::*;
        Some(match code {
            0 => K10,
            1 => K20,
            2 => K50,
            3 => K100,
            4 => K125,
            5 => K250,
            6 => K500,
            7 => match dialect.s7 {
                S7::Kbit750 => K750,
                S7::Kbit800 => K800,
            },
            8 => M1,
            9 => K83_3,
            _ => return None,
        })
    }
}

/// Errors of the SLCAN codec.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SlcanError {
    /// The output buffer is too small.
    #[error("output buffer too small")]
    BufferTooSmall,
    /// The line starts with a character this side does not know.
    #[error("unknown command or reply {0:#04x}")]
    Unknown(u8),
    /// A known line with the wrong length for its contents.
    #[error("line length does not match its contents")]
    Length,
    /// A character that should be a hex digit is not.
    #[error("invalid hex digit")]
    Hex,
    /// DLC above 8.
    #[error("invalid DLC")]
    Dlc,
    /// Identifier out of range for its kind (11 or 29 bits).
    #[error("identifier out of range")]
    Id,
    /// Unknown `Sn` digit, or a bitrate the dialect cannot express with `Sn`.
    #[error("bitrate not available in this dialect")]
    Bitrate,
    /// A line (or a CR-terminated command) was expected but a BEL ended it.
    #[error("line ended by BEL")]
    Bel,
}

impl From<BufferTooSmall> for SlcanError {
    fn from(_: BufferTooSmall) -> Self {
        SlcanError::BufferTooSmall
    }
}

const HEX: &[u8; 16] = b"0123456789ABCDEF";

fn put_hex(w: &mut Writer<'_>, v: u32, digits: u32) -> Result<(), BufferTooSmall> {
    for i in (0..digits).rev() {
        w.put(HEX[((v >> (4 * i)) & 0xF) as usize])?;
    }
    Ok(())
}

fn hex_digit(c: u8) -> Result<u32, SlcanError> {
    match c {
        b'0'..=b'9' => Ok((c - b'0') as u32),
        b'a'..=b'f' => Ok((c - b'a' + 10) as u32),
        b'A'..=b'F' => Ok((c - b'A' + 10) as u32),
        _ => Err(SlcanError::Hex),
    }
}

/// Parses hex digits (either case) into a number; at most 8 digits.
fn parse_hex(s: &[u8]) -> Result<u32, SlcanError> {
    s.iter()
        .try_fold(0u32, |acc, &c| Ok((acc << 4) | hex_digit(c)?))
}

/// Writes `t/T/r/R`, ID, DLC, data and the optional timestamp (no terminator).
fn put_frame(
    w: &mut Writer<'_>,
    f: &CanFrame,
    timestamp: Option<u16>,
) -> Result<(), BufferTooSmall> {
    let (letter, digits) = match (f.is_extended(), f.is_remote_frame()) {
        (false, false) => (b't', 3),
        (true, false) => (b'T', 8),
        (false, true) => (b'r', 3),
        (true, true) => (b'R', 8),
    };
    w.put(letter)?;
    put_hex(w, f.raw_id(), digits)?;
    w.put(b'0' + f.dlc() as u8)?;
    for &b in f.data() {
        put_hex(w, b as u32, 2)?;
    }
    if let Some(ts) = timestamp {
        put_hex(w, ts as u32, 4)?;
    }
    Ok(())
}

/// Parses a frame line body (no terminator). With `allow_timestamp`, 4 extra hex digits are a
/// timestamp.
fn parse_frame(line: &[u8], allow_timestamp: bool) -> Result<(CanFrame, Option<u16>), SlcanError> {
    let (&letter, rest) = line.split_first().ok_or(SlcanError::Length)?;
    let (extended, remote) = match letter {
        b't' => (false, false),
        b'T' => (true, false),
        b'r' => (false, true),
        b'R' => (true, true),
        other => return Err(SlcanError::Unknown(other)),
    };
    let digits = if extended { 8 } else { 3 };
    if rest.len() < digits + 1 {
        return Err(SlcanError::Length);
    }
    let raw = parse_hex(&rest[..digits])?;
    let id: Id = if extended {
        ExtendedId::new(raw).ok_or(SlcanError::Id)?.into()
    } else {
        StandardId::new(raw as u16).ok_or(SlcanError::Id)?.into()
    };
    let dlc = match rest[digits] {
        c @ b'0'..=b'8' => (c - b'0') as usize,
        b'9' | b'A'..=b'F' | b'a'..=b'f' => return Err(SlcanError::Dlc),
        _ => return Err(SlcanError::Hex),
    };
    let payload = &rest[digits + 1..];
    let data_chars = if remote { 0 } else { 2 * dlc };
    let timestamp = match payload.len().checked_sub(data_chars) {
        Some(0) => None,
        Some(4) if allow_timestamp => Some(parse_hex(&payload[data_chars..])? as u16),
        _ => return Err(SlcanError::Length),
    };
    let frame = if remote {
        CanFrame::new_remote(id, dlc)
    } else {
        let mut data = [0u8; 8];
        for (i, byte) in data.iter_mut().take(dlc).enumerate() {
            *byte = parse_hex(&payload[2 * i..2 * i + 2])? as u8;
        }
        CanFrame::new(id, &data[..dlc])
    };
    Ok((frame.ok_or(SlcanError::Dlc)?, timestamp))
}
