//! The single combined reply to FAST SYNC READ and FAST BULK READ.
//!
//! After `FF FF FD 00 FE LEN_L LEN_H 55` each device contributes `ERR ID DATA CRC`, where CRC is
//! the running CRC-16 of every packet byte before it (earlier slice CRCs included). The last
//! slice's CRC is the packet CRC, which the scanner already checked; the others are checked
//! here. The reply is not byte-stuffed.

use super::packet::{ErrorByte, Packet};
use super::{crc, Instruction, BROADCAST_ID, HEADER};

/// Why a fast reply could not be split into device slices.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FastReplyError {
    /// Not a status packet from ID 0xFE.
    #[error("not a fast read reply")]
    NotFastReply,
    /// The reply ends inside a slice.
    #[error("reply shorter than the requested lengths")]
    Short,
    /// An embedded (running) CRC does not match.
    #[error("embedded CRC mismatch in the slice of ID {id}")]
    EmbeddedCrc {
        /// ID in the slice whose CRC failed.
        id: u8,
    },
    /// Bytes remain after the slices of every requested length.
    #[error("reply longer than the requested lengths")]
    TrailingBytes,
}

/// One device's part of a fast reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FastSlice<'a> {
    /// The device's error byte.
    pub error: ErrorByte,
    /// Device ID.
    pub id: u8,
    /// The bytes read.
    pub data: &'a [u8],
}

/// A fast read reply, ready to be split with the lengths that were requested.
#[derive(Debug, Clone, Copy)]
pub struct FastReply<'a> {
    body: &'a [u8],
}

impl<'a> FastReply<'a> {
    /// Checks that `p` is a fast read reply (status from 0xFE).
    pub fn from_packet(p: &Packet<'a>) -> Result<Self, FastReplyError> {
        if p.id != BROADCAST_ID || p.instruction != Instruction::Status as u8 {
            return Err(FastReplyError::NotFastReply);
        }
        Ok(Self { body: p.params })
    }

    /// Splits the reply given each device's data length, in request order: the same length
    /// repeated for FAST SYNC READ (`core::iter::repeat(len)`), the per-entry lengths for FAST
    /// BULK READ. Iteration ends when the reply is consumed.
    pub fn slices<I: IntoIterator<Item = usize>>(&self, lens: I) -> FastSlices<'a, I::IntoIter> {
        let len = (self.body.len() + 3) as u16;
        let [lo, hi] = len.to_le_bytes();
        let mut head = [0u8; 8];
        head[..4].copy_from_slice(&HEADER);
        head[4..].copy_from_slice(&[BROADCAST_ID, lo, hi, Instruction::Status as u8]);
        FastSlices {
            body: self.body,
            pos: 0,
            crc: crc::crc16(&head),
            lens: lens.into_iter(),
            done: false,
        }
    }
}

/// Iterator over the slices of a [`FastReply`].
pub struct FastSlices<'a, I> {
    body: &'a [u8],
    pos: usize,
    crc: u16,
    lens: I,
    done: bool,
}

impl<'a, I: Iterator<Item = usize>> Iterator for FastSlices<'a, I> {
    type Item = Result<FastSlice<'a>, FastReplyError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done || self.pos == self.body.len() {
            return None;
        }
        let Some(len) = self.lens.next() else {
            self.done = true;
            return Some(Err(FastReplyError::TrailingBytes));
        };
        let rest = &self.body[self.pos..];
        let Some(slice) = len.checked_add(2).and_then(|n| rest.get(..n)) else {
            self.done = true;
            return Some(Err(FastReplyError::Short));
        };
        let (error, id, data) = (ErrorByte(slice[0]), slice[1], &slice[2..]);
        self.crc = crc::update(self.crc, slice);
        self.pos += slice.len();
        if self.pos < self.body.len() {
            // Not the last slice: a running CRC follows.
            let Some(c) = self.body.get(self.pos..self.pos + 2) else {
                self.done = true;
                return Some(Err(FastReplyError::Short));
            };
            if u16::from_le_bytes([c[0], c[1]]) != self.crc {
                self.done = true;
                return Some(Err(FastReplyError::EmbeddedCrc { id }));
            }
            self.crc = crc::update(self.crc, c);
            self.pos += 2;
        }
        Some(Ok(FastSlice { error, id, data }))
    }
}
