//! Packet encoders: each writes one complete packet into `buf` and returns its length.

use super::{checksum, ErrorBits, Instruction, BROADCAST_ID, MAX_DEVICE_ID};
use crate::writer::Writer;
use crate::BufferTooSmall;

/// Why a packet could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// The output buffer cannot hold the packet.
    #[error("output buffer too small")]
    BufferTooSmall,
    /// The ID is not valid here.
    #[error("invalid ID {0:#04x}")]
    InvalidId(u8),
    /// An entry's data length differs from the declared one.
    #[error("data length {got} where {expected} is required")]
    DataLength {
        /// Declared length.
        expected: usize,
        /// Supplied length.
        got: usize,
    },
    /// Sync write / bulk read without entries.
    #[error("no entries")]
    NoEntries,
    /// An ID appears twice.
    #[error("ID {0} listed twice")]
    DuplicateId(u8),
    /// More than 253 parameter bytes (LEN is one byte).
    #[error("packet too long for the length field")]
    TooLong,
}

impl From<BufferTooSmall> for EncodeError {
    fn from(_: BufferTooSmall) -> Self {
        EncodeError::BufferTooSmall
    }
}

struct Builder<'a> {
    w: Writer<'a>,
}

impl<'a> Builder<'a> {
    fn new(buf: &'a mut [u8], id: u8, inst: u8) -> Result<Self, EncodeError> {
        let mut w = Writer::new(buf);
        w.put_all(&[0xFF, 0xFF, id, 0, inst])?;
        Ok(Self { w })
    }

    fn bytes(&mut self, b: &[u8]) -> Result<(), EncodeError> {
        Ok(self.w.put_all(b)?)
    }

    fn finish(mut self) -> Result<usize, EncodeError> {
        let len = u8::try_from(self.w.pos() - 4 + 1).map_err(|_| EncodeError::TooLong)?;
        self.w.set(3, len);
        let chk = checksum(&self.w.written()[2..]);
        self.w.put(chk)?;
        Ok(self.w.pos())
    }
}

fn device_id(id: u8) -> Result<u8, EncodeError> {
    if id <= MAX_DEVICE_ID {
        Ok(id)
    } else {
        Err(EncodeError::InvalidId(id))
    }
}

fn device_or_broadcast(id: u8) -> Result<u8, EncodeError> {
    if id <= BROADCAST_ID {
        Ok(id)
    } else {
        Err(EncodeError::InvalidId(id))
    }
}

fn simple(buf: &mut [u8], id: u8, inst: Instruction, params: &[u8]) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, id, inst as u8)?;
    b.bytes(params)?;
    b.finish()
}

/// PING.
pub fn ping(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    simple(buf, device_or_broadcast(id)?, Instruction::Ping, &[])
}

/// READ `len` bytes at `addr`.
pub fn read(buf: &mut [u8], id: u8, addr: u8, len: u8) -> Result<usize, EncodeError> {
    simple(buf, device_id(id)?, Instruction::Read, &[addr, len])
}

fn write_like(
    buf: &mut [u8],
    inst: Instruction,
    id: u8,
    addr: u8,
    data: &[u8],
) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, device_or_broadcast(id)?, inst as u8)?;
    b.bytes(&[addr])?;
    b.bytes(data)?;
    b.finish()
}

/// WRITE `data` at `addr`.
pub fn write(buf: &mut [u8], id: u8, addr: u8, data: &[u8]) -> Result<usize, EncodeError> {
    write_like(buf, Instruction::Write, id, addr, data)
}

/// REG_WRITE `data` at `addr` (applied by [`action`]).
pub fn reg_write(buf: &mut [u8], id: u8, addr: u8, data: &[u8]) -> Result<usize, EncodeError> {
    write_like(buf, Instruction::RegWrite, id, addr, data)
}

/// ACTION.
pub fn action(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    simple(buf, device_or_broadcast(id)?, Instruction::Action, &[])
}

/// RESET (factory settings).
pub fn reset(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    simple(buf, device_or_broadcast(id)?, Instruction::Reset, &[])
}

/// SYNC WRITE of `len` bytes at `addr`; entries are `(id, data)` with `data.len() == len`.
pub fn sync_write<'d>(
    buf: &mut [u8],
    addr: u8,
    len: u8,
    entries: impl IntoIterator<Item = (u8, &'d [u8])>,
) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, BROADCAST_ID, Instruction::SyncWrite as u8)?;
    b.bytes(&[addr, len])?;
    let mut seen = [false; 256];
    let mut any = false;
    for (id, data) in entries {
        device_id(id)?;
        if core::mem::replace(&mut seen[id as usize], true) {
            return Err(EncodeError::DuplicateId(id));
        }
        if data.len() != len as usize {
            return Err(EncodeError::DataLength {
                expected: len as usize,
                got: data.len(),
            });
        }
        b.bytes(&[id])?;
        b.bytes(data)?;
        any = true;
    }
    if !any {
        return Err(EncodeError::NoEntries);
    }
    b.finish()
}

/// One device's part of a BULK READ (MX series).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BulkReadEntry {
    /// Bytes to read.
    pub len: u8,
    /// Device ID.
    pub id: u8,
    /// Start address.
    pub addr: u8,
}

/// BULK READ (MX only): `0x00, [len id addr]…`.
pub fn bulk_read(
    buf: &mut [u8],
    entries: impl IntoIterator<Item = BulkReadEntry>,
) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, BROADCAST_ID, Instruction::BulkRead as u8)?;
    b.bytes(&[0x00])?;
    let mut any = false;
    for e in entries {
        device_id(e.id)?;
        b.bytes(&[e.len, e.id, e.addr])?;
        any = true;
    }
    if !any {
        return Err(EncodeError::NoEntries);
    }
    b.finish()
}

/// A status packet (what a servo or simulator sends).
pub fn status(
    buf: &mut [u8],
    id: u8,
    error: ErrorBits,
    params: &[u8],
) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, device_id(id)?, error.0)?;
    b.bytes(params)?;
    b.finish()
}
