//! Packet encoders. Each writes one complete packet (stuffed, with CRC) into `buf` and returns
//! its length.

use super::crc;
use super::stuffing::Stuffer;
use super::{Instruction, BROADCAST_ID, HEADER, MAX_DEVICE_ID};
use crate::dynamixel_common::{self as common, EncodeError, IdSet};
use crate::writer::Writer;

/// Writes header, ID, placeholder length and instruction, then stuffed parameters; `finish`
/// patches the length and appends the CRC.
struct Builder<'a> {
    w: Writer<'a>,
    stuffer: Stuffer,
    stuff: bool,
}

impl<'a> Builder<'a> {
    fn new(buf: &'a mut [u8], id: u8, inst: u8, stuff: bool) -> Result<Self, EncodeError> {
        let mut w = Writer::new(buf);
        w.put_all(&HEADER)?;
        w.put_all(&[id, 0, 0, inst])?;
        Ok(Self {
            w,
            stuffer: Stuffer::default(),
            stuff,
        })
    }

    fn byte(&mut self, b: u8) -> Result<(), EncodeError> {
        if self.stuff {
            self.stuffer.put(&mut self.w, b)?;
        } else {
            self.w.put(b)?;
        }
        Ok(())
    }

    fn bytes(&mut self, bs: &[u8]) -> Result<(), EncodeError> {
        bs.iter().try_for_each(|&b| self.byte(b))
    }

    fn u16(&mut self, v: u16) -> Result<(), EncodeError> {
        self.bytes(&v.to_le_bytes())
    }

    fn finish(mut self) -> Result<usize, EncodeError> {
        // LEN counts INST + (stuffed) params + CRC.
        let len = self.w.pos() - 7 + 2;
        let len = u16::try_from(len).map_err(|_| EncodeError::TooLong)?;
        let [lo, hi] = len.to_le_bytes();
        self.w.set(5, lo);
        self.w.set(6, hi);
        let crc = crc::crc16(self.w.written());
        self.w.put_all(&crc.to_le_bytes())?;
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
    let mut b = Builder::new(buf, id, inst as u8, true)?;
    b.bytes(params)?;
    b.finish()
}

/// PING `id` (or broadcast: every device answers).
pub fn ping(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    simple(buf, device_or_broadcast(id)?, Instruction::Ping, &[])
}

/// READ `len` bytes at `addr` from device `id`.
pub fn read(buf: &mut [u8], id: u8, addr: u16, len: u16) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, device_id(id)?, Instruction::Read as u8, true)?;
    b.u16(addr)?;
    b.u16(len)?;
    b.finish()
}

fn write_like(
    buf: &mut [u8],
    inst: Instruction,
    id: u8,
    addr: u16,
    data: &[u8],
) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, device_or_broadcast(id)?, inst as u8, true)?;
    b.u16(addr)?;
    b.bytes(data)?;
    b.finish()
}

/// WRITE `data` at `addr` on device `id` (broadcast allowed; then nobody answers).
pub fn write(buf: &mut [u8], id: u8, addr: u16, data: &[u8]) -> Result<usize, EncodeError> {
    write_like(buf, Instruction::Write, id, addr, data)
}

/// REG WRITE: stage `data` at `addr`, applied by [`action`].
pub fn reg_write(buf: &mut [u8], id: u8, addr: u16, data: &[u8]) -> Result<usize, EncodeError> {
    write_like(buf, Instruction::RegWrite, id, addr, data)
}

/// ACTION: run the registered writes.
pub fn action(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    simple(buf, device_or_broadcast(id)?, Instruction::Action, &[])
}

/// What FACTORY RESET restores.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum FactoryResetMode {
    /// 0xFF: everything (ignored for broadcast on firmware ≥ 42).
    All = 0xFF,
    /// 0x01: everything except the ID.
    ExceptId = 0x01,
    /// 0x02: everything except the ID and the baud rate.
    ExceptIdAndBaud = 0x02,
}

/// FACTORY RESET.
pub fn factory_reset(buf: &mut [u8], id: u8, mode: FactoryResetMode) -> Result<usize, EncodeError> {
    simple(
        buf,
        device_or_broadcast(id)?,
        Instruction::FactoryReset,
        &[mode as u8],
    )
}

/// REBOOT.
pub fn reboot(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    simple(buf, device_or_broadcast(id)?, Instruction::Reboot, &[])
}

/// CLEAR (0x10) of the multi-turn revolution count: P1 = 0x01 and the fixed key `44 58 4C 22`.
/// Only honoured while the servo is stopped.
pub fn clear_multi_turn(buf: &mut [u8], id: u8) -> Result<usize, EncodeError> {
    simple(
        buf,
        device_or_broadcast(id)?,
        Instruction::Clear,
        &[0x01, 0x44, 0x58, 0x4C, 0x22],
    )
}

/// Control Table Backup operation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum BackupOp {
    /// 0x01: store the control table to the backup area.
    Store = 0x01,
    /// 0x02: restore it.
    Restore = 0x02,
}

/// CONTROL TABLE BACKUP (0x20) with the fixed key `43 54 52 4C` ("CTRL"). Needs torque off.
pub fn control_table_backup(buf: &mut [u8], id: u8, op: BackupOp) -> Result<usize, EncodeError> {
    simple(
        buf,
        device_or_broadcast(id)?,
        Instruction::ControlTableBackup,
        &[op as u8, 0x43, 0x54, 0x52, 0x4C],
    )
}

fn sync_read_like(
    buf: &mut [u8],
    inst: Instruction,
    addr: u16,
    len: u16,
    ids: &[u8],
) -> Result<usize, EncodeError> {
    if ids.is_empty() {
        return Err(EncodeError::NoEntries);
    }
    let mut b = Builder::new(buf, BROADCAST_ID, inst as u8, true)?;
    b.u16(addr)?;
    b.u16(len)?;
    common::entries(
        ids.iter().copied(),
        MAX_DEVICE_ID,
        |&id| id,
        |id| b.byte(id),
    )?;
    b.finish()
}

/// SYNC READ of `len` bytes at `addr` from each of `ids`; they answer in the order listed.
pub fn sync_read(buf: &mut [u8], addr: u16, len: u16, ids: &[u8]) -> Result<usize, EncodeError> {
    sync_read_like(buf, Instruction::SyncRead, addr, len, ids)
}

/// FAST SYNC READ: as [`sync_read`], answered by one combined packet ([`super::FastReply`]).
pub fn fast_sync_read(
    buf: &mut [u8],
    addr: u16,
    len: u16,
    ids: &[u8],
) -> Result<usize, EncodeError> {
    sync_read_like(buf, Instruction::FastSyncRead, addr, len, ids)
}

/// SYNC WRITE of `len` bytes at `addr`: each entry is `(id, data)` with `data.len() == len`.
pub fn sync_write<'d>(
    buf: &mut [u8],
    addr: u16,
    len: u16,
    entries: impl IntoIterator<Item = (u8, &'d [u8])>,
) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, BROADCAST_ID, Instruction::SyncWrite as u8, true)?;
    b.u16(addr)?;
    b.u16(len)?;
    common::sync_write_entries(entries, MAX_DEVICE_ID, len as usize, |id, data| {
        b.byte(id)?;
        b.bytes(data)
    })?;
    b.finish()
}

/// One device's part of a BULK READ or FAST BULK READ.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BulkReadEntry {
    /// Device ID.
    pub id: u8,
    /// Start address.
    pub addr: u16,
    /// Number of bytes.
    pub len: u16,
}

/// One device's part of a BULK WRITE.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BulkWriteEntry<'d> {
    /// Device ID.
    pub id: u8,
    /// Start address.
    pub addr: u16,
    /// Bytes to write (the length field is `data.len()`).
    pub data: &'d [u8],
}

fn bulk_read_like(
    buf: &mut [u8],
    inst: Instruction,
    entries: impl IntoIterator<Item = BulkReadEntry>,
) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, BROADCAST_ID, inst as u8, true)?;
    common::entries(
        entries,
        MAX_DEVICE_ID,
        |e| e.id,
        |e| {
            b.byte(e.id)?;
            b.u16(e.addr)?;
            b.u16(e.len)
        },
    )?;
    b.finish()
}

/// BULK READ: per-device address and length; one status packet per device, in order.
pub fn bulk_read(
    buf: &mut [u8],
    entries: impl IntoIterator<Item = BulkReadEntry>,
) -> Result<usize, EncodeError> {
    bulk_read_like(buf, Instruction::BulkRead, entries)
}

/// FAST BULK READ: as [`bulk_read`], answered by one combined packet.
pub fn fast_bulk_read(
    buf: &mut [u8],
    entries: impl IntoIterator<Item = BulkReadEntry>,
) -> Result<usize, EncodeError> {
    bulk_read_like(buf, Instruction::FastBulkRead, entries)
}

/// BULK WRITE: per-device address and data; no reply.
pub fn bulk_write<'d>(
    buf: &mut [u8],
    entries: impl IntoIterator<Item = BulkWriteEntry<'d>>,
) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, BROADCAST_ID, Instruction::BulkWrite as u8, true)?;
    common::entries(
        entries,
        MAX_DEVICE_ID,
        |e| e.id,
        |e| {
            let len = u16::try_from(e.data.len()).map_err(|_| EncodeError::TooLong)?;
            b.byte(e.id)?;
            b.u16(e.addr)?;
            b.u16(len)?;
            b.bytes(e.data)
        },
    )?;
    b.finish()
}

/// A status packet from device `id` with error byte `error` and parameters `params`
/// (what a servo, or a simulator, sends).
pub fn status(buf: &mut [u8], id: u8, error: u8, params: &[u8]) -> Result<usize, EncodeError> {
    let mut b = Builder::new(buf, device_id(id)?, Instruction::Status as u8, true)?;
    b.byte(error)?;
    b.bytes(params)?;
    b.finish()
}

/// One device's slice of a fast (sync or bulk) read reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FastStatusSlice<'d> {
    /// The device's error byte.
    pub error: u8,
    /// Device ID.
    pub id: u8,
    /// The data read.
    pub data: &'d [u8],
}

/// The combined reply to FAST SYNC READ / FAST BULK READ: ID 0xFE, not stuffed, each slice
/// `ERR ID DATA CRC` where CRC is the running CRC of the whole packet so far; the last slice's
/// CRC is the packet CRC.
pub fn fast_status(buf: &mut [u8], slices: &[FastStatusSlice<'_>]) -> Result<usize, EncodeError> {
    let Some((last, rest)) = slices.split_last() else {
        return Err(EncodeError::NoEntries);
    };
    let mut b = Builder::new(buf, BROADCAST_ID, Instruction::Status as u8, false)?;
    // The running CRCs cover the length field, so it must be known before the first slice.
    let body: usize = slices.iter().map(|s| 4 + s.data.len()).sum();
    let len = u16::try_from(1 + body).map_err(|_| EncodeError::TooLong)?;
    let [lo, hi] = len.to_le_bytes();
    b.w.set(5, lo);
    b.w.set(6, hi);
    let mut seen = IdSet::default();
    for s in rest {
        seen.insert(device_id(s.id)?)?;
        b.bytes(&[s.error, s.id])?;
        b.bytes(s.data)?;
        let running = crc::crc16(b.w.written());
        b.bytes(&running.to_le_bytes())?;
    }
    seen.insert(device_id(last.id)?)?;
    b.bytes(&[last.error, last.id])?;
    b.bytes(last.data)?;
    b.finish()
}
