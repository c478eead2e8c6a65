//! Packet encoders: each writes one complete packet into `buf` and returns its length.

use super::{checksum, ErrorBits, Instruction, BROADCAST_ID, HEADER, MAX_DEVICE_ID};
use crate::dynamixel_common::{self as common, EncodeError};
use crate::writer::Writer;

struct Builder<'a> {
    w: Writer<'a>,
}

impl<'a> Builder<'a> {
    fn new(buf: &'a mut [u8], id: u8, inst: u8) -> Result<Self, EncodeError> {
        let mut w = Writer::new(buf);
        w.put_all(&HEADER)?;
        w.put_all(&[id, 0, inst])?;
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
    common::device_id(id, MAX_DEVICE_ID)
}

fn device_or_broadcast(id: u8) -> Result<u8, EncodeError> {
    common::device_or_broadcast(id, MAX_DEVICE_ID)
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
    common::sync_write_entries(entries, MAX_DEVICE_ID, len as usize, |id, data| {
        b.bytes(&[id])?;
        b.bytes(data)
    })?;
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
