//! Framing: CRC-16 appended, COBS-encoded, terminated by `0x00`; and the scanner that undoes it.

use super::message::MessageError;
use super::MAX_MESSAGE;
use crate::dynamixel2::crc::crc16;

/// Longest frame on the wire: the COBS encoding of a maximal message and its CRC, plus the
/// terminating zero.
pub const MAX_FRAME: usize = cobs::max_encoding_length(MAX_MESSAGE + 2) + 1;

/// A frame could not be produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// The message itself was invalid (too long, a string over its limit).
    #[error(transparent)]
    Message(#[from] MessageError),
    /// The output buffer cannot hold the frame ([`MAX_FRAME`] always can).
    #[error("output buffer too small for the frame")]
    BufferTooSmall,
}

/// Frames `message` (at most [`MAX_MESSAGE`] bytes) into `out`: returns the frame length.
pub fn encode_frame(message: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    if message.len() > MAX_MESSAGE {
        return Err(MessageError::TooLong.into());
    }
    let mut checked = [0u8; MAX_MESSAGE + 2];
    let n = message.len();
    checked[..n].copy_from_slice(message);
    checked[n..n + 2].copy_from_slice(&crc16(message).to_le_bytes());
    let len = cobs::try_encode(&checked[..n + 2], out).map_err(|_| FrameError::BufferTooSmall)?;
    *out.get_mut(len).ok_or(FrameError::BufferTooSmall)? = 0;
    Ok(len + 1)
}

/// What a [`FrameScanner`] has seen. Every byte fed ends up in exactly one count or is still
/// buffered: `bytes_in == frame_bytes + discarded_bytes + buffered()`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Bytes fed.
    pub bytes_in: u64,
    /// Bytes of frames that passed every check (including their terminators).
    pub frame_bytes: u64,
    /// Bytes of rejected frames (including their terminators) and lone terminators.
    pub discarded_bytes: u64,
    /// Frames that passed.
    pub frames: u64,
    /// Frames longer than the scanner's buffer.
    pub oversize: u64,
    /// Frames whose COBS encoding was invalid.
    pub bad_cobs: u64,
    /// Frames whose CRC did not match (or too short to hold one).
    pub bad_crc: u64,
}

/// Turns bytes arriving in any chunking into checked messages (CRC removed), borrowed from a
/// fixed buffer of `N` bytes (use [`MAX_FRAME`]). A damaged or over-long frame is dropped and
/// counted; scanning resumes at the next terminator.
#[derive(Debug, Clone)]
pub struct FrameScanner<const N: usize> {
    buf: [u8; N],
    len: usize,
    /// Bytes of the current frame beyond the buffer (the frame is oversize).
    spilled: usize,
    stats: LinkStats,
}

impl<const N: usize> Default for FrameScanner<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameScanner<N> {
    /// An empty scanner.
    pub const fn new() -> Self {
        Self {
            buf: [0; N],
            len: 0,
            spilled: 0,
            stats: LinkStats {
                bytes_in: 0,
                frame_bytes: 0,
                discarded_bytes: 0,
                frames: 0,
                oversize: 0,
                bad_cobs: 0,
                bad_crc: 0,
            },
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> &LinkStats {
        &self.stats
    }

    /// Bytes of an unfinished frame held.
    pub fn buffered(&self) -> usize {
        self.len + self.spilled
    }

    /// Forgets an unfinished frame (after a reconnect), counting it as discarded.
    pub fn reset(&mut self) {
        self.stats.discarded_bytes += self.buffered() as u64;
        self.len = 0;
        self.spilled = 0;
    }

    /// Feeds received bytes; calls `on_message` with each checked message, in order.
    pub fn feed(&mut self, bytes: &[u8], mut on_message: impl FnMut(&[u8])) {
        for &b in bytes {
            self.stats.bytes_in += 1;
            if b != 0 {
                if self.len < N {
                    self.buf[self.len] = b;
                    self.len += 1;
                } else {
                    self.spilled += 1;
                }
                continue;
            }
            let total = (self.len + self.spilled + 1) as u64;
            if self.len == 0 && self.spilled == 0 {
                // A lone terminator (senders may start with one to flush a partial frame).
                self.stats.discarded_bytes += 1;
            } else if self.spilled > 0 {
                self.stats.oversize += 1;
                self.stats.discarded_bytes += total;
            } else {
                match cobs::decode_in_place(&mut self.buf[..self.len]) {
                    Err(_) => {
                        self.stats.bad_cobs += 1;
                        self.stats.discarded_bytes += total;
                    }
                    Ok(n) if n < 2 || !crc_ok(&self.buf[..n]) => {
                        self.stats.bad_crc += 1;
                        self.stats.discarded_bytes += total;
                    }
                    Ok(n) => {
                        self.stats.frames += 1;
                        self.stats.frame_bytes += total;
                        on_message(&self.buf[..n - 2]);
                    }
                }
            }
            self.len = 0;
            self.spilled = 0;
        }
    }
}

fn crc_ok(checked: &[u8]) -> bool {
    let (msg, crc) = checked.split_at(checked.len() - 2);
    crc16(msg).to_le_bytes() == [crc[0], crc[1]]
}
