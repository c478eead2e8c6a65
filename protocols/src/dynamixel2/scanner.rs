//! Stream scanner: bytes in any chunking → CRC-checked, unstuffed packets.

use super::packet::{decode_checked, id_is_valid, Packet};
use super::{crc, HEADER};
use crate::scan::{self, Engine, Framing, Scan, ScanStats};

struct Dxl2;

impl Framing for Dxl2 {
    const HEADER: &'static [u8] = &HEADER;
    const FIELDS_LEN: usize = 7;

    fn total_len(f: &[u8]) -> Option<usize> {
        let len = u16::from_le_bytes([f[5], f[6]]);
        (id_is_valid(f[4]) && len >= 3).then_some(7 + len as usize)
    }

    fn check(p: &[u8]) -> bool {
        let n = p.len();
        crc::crc16(&p[..n - 2]) == u16::from_le_bytes([p[n - 2], p[n - 1]])
    }
}

/// Fixed-capacity Dynamixel 2.0 stream scanner with discard counters.
///
/// `N` is the buffer capacity; the largest packet it yields is `N - 3` bytes (or the smaller
/// maximum given to [`Scanner::with_max_packet`]): a longer candidate counts as `oversize`.
/// It yields status and instruction packets alike (a simulator scans instructions); ID and
/// instruction filtering is the caller's business. See [`crate::scan`] for the discard causes
/// and the accounting invariant.
///
/// ```
/// use conductor_protocols::dynamixel2::{Scanner, Status};
/// let mut s = Scanner::<256>::new();
/// let wire = [0x00, 0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x04, 0x00, 0x55, 0x00, 0xA1, 0x0C];
/// let mut ids = [0u8; 1];
/// s.feed(&wire, |p| ids[0] = Status::from_packet(&p).unwrap().id);
/// assert_eq!(ids, [1]);
/// assert_eq!(s.stats().garbage.bytes, 1);
/// ```
pub struct Scanner<const N: usize = 1024> {
    engine: Engine<N>,
}

impl<const N: usize> Default for Scanner<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> Scanner<N> {
    const MIN_CAPACITY: () = assert!(N >= 16, "scanner capacity must be at least 16 bytes");

    /// A scanner accepting packets up to `N - 3` bytes.
    pub fn new() -> Self {
        Self::with_max_packet(N)
    }

    /// A scanner accepting packets up to `max_packet` wire bytes (clamped to `N - 3`). A tight
    /// maximum (the longest reply the caller expects) makes a corrupted length field cost less.
    pub fn with_max_packet(max_packet: usize) -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::MIN_CAPACITY;
        Self {
            engine: Engine::new(max_packet.max(10), HEADER.len()),
        }
    }

    /// Largest packet (wire bytes) this scanner yields.
    pub fn max_packet(&self) -> usize {
        self.engine.max_packet()
    }

    /// Copies as many bytes as fit into the buffer; returns how many were taken. After
    /// [`next_packet`](Self::next_packet) has returned `None` at least one byte always fits.
    pub fn push(&mut self, bytes: &[u8]) -> usize {
        self.engine.push(bytes)
    }

    /// The next complete packet whose CRC checked, stuffing removed. It borrows the scanner's
    /// buffer and is consumed by the next call.
    pub fn next_packet(&mut self) -> Option<Packet<'_>> {
        let range = self.engine.next_frame::<Dxl2>()?;
        Some(decode_checked(&mut self.engine.buf_mut()[range]))
    }

    /// Declares that no more bytes are coming for what is buffered (reply timeout): incomplete
    /// candidates become `truncated` on the following [`next_packet`](Self::next_packet) calls,
    /// and any complete packets behind them are still yielded. The next `push` ends this.
    pub fn expire(&mut self) {
        self.engine.expire();
    }

    /// Pushes all of `bytes`, calling `on_packet` for every packet completed.
    pub fn feed(&mut self, bytes: &[u8], on_packet: impl FnMut(Packet<'_>)) {
        scan::feed(self, bytes, on_packet);
    }

    /// [`expire`](Self::expire), then drains: calls `on_packet` for packets still complete
    /// behind truncated ones. The buffer is empty afterwards.
    pub fn expire_with(&mut self, on_packet: impl FnMut(Packet<'_>)) {
        scan::expire_with(self, on_packet);
    }

    /// Discard counters since creation.
    pub fn stats(&self) -> &ScanStats {
        self.engine.stats()
    }

    /// Bytes accepted but not yet yielded or discarded.
    pub fn buffered(&self) -> usize {
        self.engine.buffered()
    }
}

impl<const N: usize> Scan for Scanner<N> {
    type Item<'a> = Packet<'a>;

    fn push(&mut self, bytes: &[u8]) -> usize {
        Scanner::push(self, bytes)
    }

    fn next_item(&mut self) -> Option<Packet<'_>> {
        self.next_packet()
    }

    fn expire(&mut self) {
        Scanner::expire(self);
    }
}
