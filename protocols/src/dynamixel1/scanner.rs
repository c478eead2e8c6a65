//! Stream scanner for Protocol 1.0.

use super::packet::{decode_checked, Packet};
use super::{checksum, HEADER, MAX_DEVICE_ID, MAX_PACKET};
use crate::dynamixel_common::addressable;
use crate::scan::{self, Engine, Framing, Scan, ScanStats};

struct Dxl1;

impl Framing for Dxl1 {
    const HEADER: &'static [u8] = &HEADER;
    const FIELDS_LEN: usize = 4;

    fn total_len(f: &[u8]) -> Option<usize> {
        (addressable(f[2], MAX_DEVICE_ID) && f[3] >= 2).then_some(4 + f[3] as usize)
    }

    fn check(p: &[u8]) -> bool {
        let n = p.len();
        checksum(&p[2..n - 1]) == p[n - 1]
    }
}

/// Fixed-capacity Protocol 1.0 stream scanner with discard counters (see [`crate::scan`]).
///
/// The header `FF FF` is weak (it appears in data), so the checksum does most of the work;
/// a run of `FF`s before a packet is counted as `bad_header` (ID 0xFF) byte by byte.
pub struct Scanner<const N: usize = 512> {
    engine: Engine<N>,
}

impl<const N: usize> Default for Scanner<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> Scanner<N> {
    const MIN_CAPACITY: () = assert!(N >= 16, "scanner capacity must be at least 16 bytes");

    /// A scanner accepting packets up to `min(N - 1, 259)` bytes.
    pub fn new() -> Self {
        Self::with_max_packet(MAX_PACKET)
    }

    /// A scanner accepting packets up to `max_packet` bytes (clamped to `N - 1`).
    pub fn with_max_packet(max_packet: usize) -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::MIN_CAPACITY;
        Self {
            engine: Engine::new(max_packet.clamp(6, MAX_PACKET), HEADER.len()),
        }
    }

    /// Copies as many bytes as fit; returns how many were taken.
    pub fn push(&mut self, bytes: &[u8]) -> usize {
        self.engine.push(bytes)
    }

    /// The next checksum-verified packet (borrowed until the next call).
    pub fn next_packet(&mut self) -> Option<Packet<'_>> {
        let range = self.engine.next_frame::<Dxl1>()?;
        Some(decode_checked(&self.engine.buf_mut()[range]))
    }

    /// No more bytes are coming for what is buffered: see
    /// [`dynamixel2::Scanner::expire`](crate::dynamixel2::Scanner::expire).
    pub fn expire(&mut self) {
        self.engine.expire();
    }

    /// Pushes all of `bytes`, calling `on_packet` for every packet completed.
    pub fn feed(&mut self, bytes: &[u8], on_packet: impl FnMut(Packet<'_>)) {
        scan::feed(self, bytes, on_packet);
    }

    /// [`expire`](Self::expire), then drain.
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
