//! Typed decoding of instruction packets: what a servo (or a simulator) makes of a packet from
//! the host.

use super::packet::Packet;
use super::{Instruction, BROADCAST_ID};

/// Why an instruction packet's parameters do not fit its instruction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum RequestError {
    /// The instruction code is not one of Protocol 2.0's (a servo answers Instruction Error).
    #[error("unknown instruction {0:#04x}")]
    UnknownInstruction(u8),
    /// A status packet, not an instruction.
    #[error("status packet, not an instruction")]
    Status,
    /// The parameters have the wrong length for the instruction (Data Length Error).
    #[error("parameter length {0} does not fit the instruction")]
    Length(usize),
    /// A sync/bulk instruction not sent to the broadcast ID.
    #[error("sync and bulk instructions must be broadcast")]
    NotBroadcast,
    /// Clear or Control Table Backup without its fixed key.
    #[error("missing or wrong fixed key")]
    Key,
}

/// A decoded instruction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request<'a> {
    /// PING.
    Ping,
    /// READ `len` bytes at `addr`.
    Read {
        /// Start address.
        addr: u16,
        /// Bytes to read.
        len: u16,
    },
    /// WRITE `data` at `addr`.
    Write {
        /// Start address.
        addr: u16,
        /// Bytes to write.
        data: &'a [u8],
    },
    /// REG WRITE `data` at `addr`.
    RegWrite {
        /// Start address.
        addr: u16,
        /// Bytes to stage.
        data: &'a [u8],
    },
    /// ACTION.
    Action,
    /// FACTORY RESET with the mode byte as sent (0xFF, 0x01 or 0x02).
    FactoryReset(u8),
    /// REBOOT.
    Reboot,
    /// CLEAR of the multi-turn count (key checked).
    ClearMultiTurn,
    /// CONTROL TABLE BACKUP, operation byte as sent (0x01 store, 0x02 restore; key checked).
    ControlTableBackup(u8),
    /// SYNC READ (or FAST SYNC READ when `fast`).
    SyncRead {
        /// Combined reply requested.
        fast: bool,
        /// Start address.
        addr: u16,
        /// Bytes per device.
        len: u16,
        /// Devices, in reply order.
        ids: &'a [u8],
    },
    /// SYNC WRITE.
    SyncWrite {
        /// Start address.
        addr: u16,
        /// Bytes per device.
        len: u16,
        /// `[id data(len)]…`, iterate with [`Request::sync_write_entries`].
        body: &'a [u8],
    },
    /// BULK READ (or FAST BULK READ when `fast`): `[id addr len]…`, iterate with
    /// [`Request::bulk_read_entries`].
    BulkRead {
        /// Combined reply requested.
        fast: bool,
        /// The raw entries.
        body: &'a [u8],
    },
    /// BULK WRITE: `[id addr len data]…`, iterate with [`Request::bulk_write_entries`].
    BulkWrite {
        /// The raw entries.
        body: &'a [u8],
    },
}

fn u16_at(p: &[u8], i: usize) -> u16 {
    u16::from_le_bytes([p[i], p[i + 1]])
}

impl<'a> Request<'a> {
    /// Decodes an instruction packet, checking that its parameters are well-formed.
    pub fn from_packet(p: &Packet<'a>) -> Result<Self, RequestError> {
        let inst = Instruction::from_code(p.instruction)
            .ok_or(RequestError::UnknownInstruction(p.instruction))?;
        let prm = p.params;
        let len_is = |n: usize| {
            if prm.len() == n {
                Ok(())
            } else {
                Err(RequestError::Length(prm.len()))
            }
        };
        let at_least = |n: usize| {
            if prm.len() >= n {
                Ok(())
            } else {
                Err(RequestError::Length(prm.len()))
            }
        };
        let broadcast = || {
            if p.id == BROADCAST_ID {
                Ok(())
            } else {
                Err(RequestError::NotBroadcast)
            }
        };
        Ok(match inst {
            Instruction::Status => return Err(RequestError::Status),
            Instruction::Ping => len_is(0).map(|_| Request::Ping)?,
            Instruction::Read => {
                len_is(4)?;
                Request::Read {
                    addr: u16_at(prm, 0),
                    len: u16_at(prm, 2),
                }
            }
            Instruction::Write | Instruction::RegWrite => {
                at_least(2)?;
                let (addr, data) = (u16_at(prm, 0), &prm[2..]);
                if inst == Instruction::Write {
                    Request::Write { addr, data }
                } else {
                    Request::RegWrite { addr, data }
                }
            }
            Instruction::Action => len_is(0).map(|_| Request::Action)?,
            Instruction::FactoryReset => {
                len_is(1)?;
                Request::FactoryReset(prm[0])
            }
            Instruction::Reboot => len_is(0).map(|_| Request::Reboot)?,
            Instruction::Clear => {
                len_is(5)?;
                if prm != [0x01, 0x44, 0x58, 0x4C, 0x22] {
                    return Err(RequestError::Key);
                }
                Request::ClearMultiTurn
            }
            Instruction::ControlTableBackup => {
                len_is(5)?;
                if prm[1..] != [0x43, 0x54, 0x52, 0x4C] {
                    return Err(RequestError::Key);
                }
                Request::ControlTableBackup(prm[0])
            }
            Instruction::SyncRead | Instruction::FastSyncRead => {
                broadcast()?;
                at_least(5)?;
                Request::SyncRead {
                    fast: inst == Instruction::FastSyncRead,
                    addr: u16_at(prm, 0),
                    len: u16_at(prm, 2),
                    ids: &prm[4..],
                }
            }
            Instruction::SyncWrite => {
                broadcast()?;
                at_least(4)?;
                let len = u16_at(prm, 2);
                let body = &prm[4..];
                if body.is_empty() || !body.len().is_multiple_of(1 + len as usize) {
                    return Err(RequestError::Length(prm.len()));
                }
                Request::SyncWrite {
                    addr: u16_at(prm, 0),
                    len,
                    body,
                }
            }
            Instruction::BulkRead | Instruction::FastBulkRead => {
                broadcast()?;
                if prm.is_empty() || !prm.len().is_multiple_of(5) {
                    return Err(RequestError::Length(prm.len()));
                }
                Request::BulkRead {
                    fast: inst == Instruction::FastBulkRead,
                    body: prm,
                }
            }
            Instruction::BulkWrite => {
                broadcast()?;
                // Walk the entries once so iteration later cannot run short.
                let mut rest = prm;
                while !rest.is_empty() {
                    if rest.len() < 5 {
                        return Err(RequestError::Length(prm.len()));
                    }
                    let n = 5 + u16_at(rest, 3) as usize;
                    rest = rest.get(n..).ok_or(RequestError::Length(prm.len()))?;
                }
                if prm.is_empty() {
                    return Err(RequestError::Length(0));
                }
                Request::BulkWrite { body: prm }
            }
        })
    }

    /// For SYNC WRITE: `(id, data)` per device; empty for other requests.
    pub fn sync_write_entries(&self) -> impl Iterator<Item = (u8, &'a [u8])> {
        let (body, len) = match *self {
            Request::SyncWrite { body, len, .. } => (body, len as usize),
            _ => (&[][..], 0),
        };
        body.chunks_exact(1 + len).map(|c| (c[0], &c[1..]))
    }

    /// For BULK READ / FAST BULK READ: `(id, addr, len)` per device; empty otherwise.
    pub fn bulk_read_entries(&self) -> impl Iterator<Item = super::BulkReadEntry> + 'a {
        let body = match *self {
            Request::BulkRead { body, .. } => body,
            _ => &[],
        };
        body.chunks_exact(5).map(|c| super::BulkReadEntry {
            id: c[0],
            addr: u16_at(c, 1),
            len: u16_at(c, 3),
        })
    }

    /// For BULK WRITE: entries with their data; empty otherwise.
    pub fn bulk_write_entries(&self) -> BulkWriteEntries<'a> {
        match *self {
            Request::BulkWrite { body } => BulkWriteEntries { rest: body },
            _ => BulkWriteEntries { rest: &[] },
        }
    }
}

/// Iterator over the entries of a BULK WRITE request.
pub struct BulkWriteEntries<'a> {
    rest: &'a [u8],
}

impl<'a> Iterator for BulkWriteEntries<'a> {
    type Item = super::BulkWriteEntry<'a>;

    fn next(&mut self) -> Option<Self::Item> {
        let head = self.rest.get(..5)?;
        let n = u16_at(head, 3) as usize;
        let data = self.rest.get(5..5 + n)?;
        let e = super::BulkWriteEntry {
            id: head[0],
            addr: u16_at(head, 1),
            data,
        };
        self.rest = &self.rest[5 + n..];
        Some(e)
    }
}
