//! What the stream scanners share: the discard accounting, the byte window every scanner
//! buffers in and the `feed`/`expire_with` loops over it, and [`PacketScanner`], the scanner of
//! both Dynamixel protocols (each supplies only its [`Framing`]).
//!
//! # The accounting invariant
//!
//! Every byte a scanner accepts ends up in exactly one place:
//!
//! ```text
//! stats.bytes_in == stats.packet_bytes + stats.discarded_bytes() + scanner.buffered()
//! ```
//!
//! and the counts do not depend on how the input was chunked (feeding a stream one byte at a
//! time or all at once gives the same packets and the same [`ScanStats`]), provided `expire` is
//! called at the same points of the stream.
//!
//! # How the binary scanners decide
//!
//! A *candidate* is a position where the protocol header (`FF FF FD 00` for 2.0, `FF FF` for 1.0)
//! starts. Bytes before the first position that could start a header are **garbage**. At a
//! candidate the scanner reads the ID and length fields:
//!
//! * invalid ID or length → **bad_header**;
//! * a total length above the scanner's maximum → **oversize**;
//! * otherwise it waits for the whole packet and checks its CRC/checksum: a mismatch is
//!   **bad_crc**, a match is yielded as a packet.
//!
//! A rejected candidate discards its *examined* bytes (the header fields for bad_header and
//! oversize, the whole claimed packet for bad_crc), but never past the next position inside them
//! where a complete header starts: a reply whose predecessor lost a byte is still found. When the
//! decision depends on bytes that have not arrived yet, the scanner waits for them.
//!
//! `expire()` tells the scanner that the line has gone quiet (the reply timeout passed): a
//! candidate (a complete header) still waiting for bytes is then discarded as **truncated**,
//! and scanning resumes after it, so complete packets behind a truncated one are still
//! yielded. A trailing fragment shorter than the header is garbage.

/// Bytes and occurrences discarded for one cause.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Tally {
    /// Number of bytes discarded.
    pub bytes: u64,
    /// Number of discard events: one per rejected candidate (or malformed line); for garbage,
    /// one per maximal run of consecutive garbage bytes in the stream.
    pub events: u64,
}

impl Tally {
    pub(crate) fn add(&mut self, bytes: usize, new_event: bool) {
        self.bytes += bytes as u64;
        if new_event {
            self.events += 1;
        }
    }
}

/// Counters of a binary packet scanner ([`PacketScanner`]: [`dynamixel2::Scanner`](crate::dynamixel2::Scanner),
/// [`dynamixel1::Scanner`](crate::dynamixel1::Scanner)). See the [module docs](self) for the
/// exact meaning of each cause and the accounting invariant.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ScanStats {
    /// Bytes accepted by `push`/`feed`.
    pub bytes_in: u64,
    /// Packets yielded (integrity check passed).
    pub packets: u64,
    /// Wire bytes of the yielded packets.
    pub packet_bytes: u64,
    /// Bytes that cannot be the start of a packet (noise, or the tail of a packet whose header
    /// was lost).
    pub garbage: Tally,
    /// Header bytes of candidates whose ID or length field is invalid.
    pub bad_header: Tally,
    /// Header bytes of candidates whose length exceeds the scanner's maximum packet size.
    pub oversize: Tally,
    /// Bytes of complete candidates whose CRC (2.0) or checksum (1.0) did not match.
    pub bad_crc: Tally,
    /// Bytes of candidates still incomplete when `expire()` was called.
    pub truncated: Tally,
}

impl ScanStats {
    /// Total bytes discarded, all causes.
    pub fn discarded_bytes(&self) -> u64 {
        self.garbage.bytes
            + self.bad_header.bytes
            + self.oversize.bytes
            + self.bad_crc.bytes
            + self.truncated.bytes
    }

    /// Total rejected candidates (bad_header + oversize + bad_crc + truncated events): each is
    /// a packet, or something that looked like one, that was not yielded.
    pub fn rejected_packets(&self) -> u64 {
        self.bad_header.events + self.oversize.events + self.bad_crc.events + self.truncated.events
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Cause {
    Garbage,
    BadHeader,
    Oversize,
    BadCrc,
    Truncated,
}

mod sealed {
    pub trait Sealed {}
}

/// What a binary packet protocol tells [`PacketScanner`] about its framing: header, length
/// field, integrity check and how a checked frame reads. Implemented by
/// [`Dxl2Framing`](crate::dynamixel2::Dxl2Framing) and
/// [`Dxl1Framing`](crate::dynamixel1::Dxl1Framing); sealed.
pub trait Framing: sealed::Sealed + 'static {
    /// What the scanner yields: a checked packet, borrowed from the scanner's buffer.
    type Packet<'a>;
    /// The fixed bytes every packet starts with.
    const HEADER: &'static [u8];
    /// How many leading bytes determine the total length (header, ID, length field).
    const FIELDS_LEN: usize;
    /// The shortest packet the protocol has (wire bytes).
    const MIN_PACKET: usize;
    /// The longest packet the protocol can have (wire bytes).
    const MAX_PACKET: usize;
    /// Total packet length from the first `FIELDS_LEN` bytes, or `None` if a field is invalid.
    fn total_len(fields: &[u8]) -> Option<usize>;
    /// Integrity check over a complete candidate.
    fn check(packet: &[u8]) -> bool;
    /// Reads a frame whose header, length and integrity were checked (may rewrite it in
    /// place, e.g. to remove byte stuffing).
    fn decode(frame: &mut [u8]) -> Self::Packet<'_>;
}

impl sealed::Sealed for crate::dynamixel1::Dxl1Framing {}
impl sealed::Sealed for crate::dynamixel2::Dxl2Framing {}

/// Fixed-capacity stream scanner for a binary packet protocol `F`, with discard counters:
/// bytes in any chunking → integrity-checked packets. `N` is the buffer capacity (at least 16);
/// the largest packet it yields is `N - (header length - 1)` bytes or the smaller maximum given
/// to [`with_max_packet`](Self::with_max_packet): a longer candidate counts as `oversize`. It
/// yields status and instruction packets alike (a simulator scans instructions); ID and
/// instruction filtering is the caller's business. See the [module docs](self) for the
/// discard causes and the accounting invariant.
pub struct PacketScanner<F, const N: usize> {
    engine: Engine<N>,
    framing: core::marker::PhantomData<F>,
}

impl<F: Framing, const N: usize> Default for PacketScanner<F, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<F: Framing, const N: usize> PacketScanner<F, N> {
    const MIN_CAPACITY: () = assert!(N >= 16, "scanner capacity must be at least 16 bytes");

    /// A scanner accepting the longest packets the protocol and the buffer allow.
    pub fn new() -> Self {
        Self::with_max_packet(F::MAX_PACKET)
    }

    /// A scanner accepting packets up to `max_packet` wire bytes (clamped to what the
    /// protocol and the buffer allow). A tight maximum (the longest reply the caller expects)
    /// makes a corrupted length field cost less.
    pub fn with_max_packet(max_packet: usize) -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::MIN_CAPACITY;
        Self {
            engine: Engine::new(
                max_packet.clamp(F::MIN_PACKET, F::MAX_PACKET),
                F::HEADER.len(),
            ),
            framing: core::marker::PhantomData,
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

    /// The next complete packet whose integrity checked. It borrows the scanner's buffer and
    /// is consumed by the next call.
    pub fn next_packet(&mut self) -> Option<F::Packet<'_>> {
        let range = self.engine.next_frame::<F>()?;
        Some(F::decode(&mut self.engine.buf_mut()[range]))
    }

    /// Declares that no more bytes are coming for what is buffered (reply timeout): incomplete
    /// candidates become `truncated` on the following [`next_packet`](Self::next_packet) calls,
    /// and any complete packets behind them are still yielded. The next `push` ends this.
    pub fn expire(&mut self) {
        self.engine.expire();
    }

    /// Pushes all of `bytes`, calling `on_packet` for every packet completed.
    pub fn feed(&mut self, bytes: &[u8], on_packet: impl FnMut(F::Packet<'_>)) {
        feed(self, bytes, on_packet);
    }

    /// [`expire`](Self::expire), then drains: calls `on_packet` for packets still complete
    /// behind truncated ones. The buffer is empty afterwards.
    pub fn expire_with(&mut self, on_packet: impl FnMut(F::Packet<'_>)) {
        expire_with(self, on_packet);
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

impl<F: Framing, const N: usize> Scan for PacketScanner<F, N> {
    type Item<'a>
        = F::Packet<'a>
    where
        Self: 'a;

    fn push(&mut self, bytes: &[u8]) -> usize {
        PacketScanner::push(self, bytes)
    }

    fn next_item(&mut self) -> Option<F::Packet<'_>> {
        self.next_packet()
    }

    fn expire(&mut self) {
        PacketScanner::expire(self);
    }
}

/// Where a header could start.
enum HeaderAt {
    /// A complete header starts here.
    Full(usize),
    /// The buffer ends inside a header prefix starting here: undecided until more bytes arrive.
    Partial(usize),
    None,
}

/// First position in `from..limit` where `header` starts, completely or as a prefix cut off by
/// the end of `data`. With `flush`, cut-off prefixes do not count (no more bytes will come).
fn find_header(data: &[u8], header: &[u8], from: usize, limit: usize, flush: bool) -> HeaderAt {
    let limit = limit.min(data.len());
    for i in from..limit {
        let rest = &data[i..];
        let n = rest.len().min(header.len());
        if rest[..n] == header[..n] {
            if n == header.len() {
                return HeaderAt::Full(i);
            }
            if !flush {
                return HeaderAt::Partial(i);
            }
        }
    }
    HeaderAt::None
}

/// The fixed-capacity byte window behind every scanner (binary and line): bytes are appended
/// at the end and consumed from the start; the item last yielded stays in place until the next
/// call (it is borrowed from here), and `expire` holds until the next `push`.
pub(crate) struct Window<const N: usize> {
    buf: [u8; N],
    start: usize,
    end: usize,
    /// Length of the item last yielded.
    pending: usize,
    flush: bool,
}

impl<const N: usize> Window<N> {
    pub(crate) const fn new() -> Self {
        Self {
            buf: [0; N],
            start: 0,
            end: 0,
            pending: 0,
            flush: false,
        }
    }

    /// Drops the item last yielded.
    pub(crate) fn consume_pending(&mut self) {
        let n = self.pending;
        self.pending = 0;
        self.drop_front(n);
    }

    /// Copies as many of `data` as fit (compacting first if needed); returns how many.
    pub(crate) fn push(&mut self, data: &[u8]) -> usize {
        self.consume_pending();
        self.flush = false;
        if self.start > 0 && self.end + data.len() > N {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        let n = data.len().min(N - self.end);
        self.buf[self.end..self.end + n].copy_from_slice(&data[..n]);
        self.end += n;
        n
    }

    /// No more bytes are coming for what is buffered (until the next `push`).
    pub(crate) fn expire(&mut self) {
        self.flush = true;
    }

    pub(crate) fn flushing(&self) -> bool {
        self.flush
    }

    /// The bytes not yet yielded or dropped.
    pub(crate) fn data(&self) -> &[u8] {
        &self.buf[self.start..self.end]
    }

    /// Drops the first `n` buffered bytes (discarded by the scanner).
    pub(crate) fn drop_front(&mut self, n: usize) {
        self.start += n;
        if self.start == self.end {
            self.start = 0;
            self.end = 0;
        }
    }

    /// Yields the first `n` buffered bytes: their range in the buffer, valid until the next
    /// call.
    pub(crate) fn yield_front(&mut self, n: usize) -> core::ops::Range<usize> {
        self.pending = n;
        self.start..self.start + n
    }

    pub(crate) fn buf(&self) -> &[u8; N] {
        &self.buf
    }

    pub(crate) fn buf_mut(&mut self) -> &mut [u8; N] {
        &mut self.buf
    }

    /// Bytes accepted but not yet yielded or dropped.
    pub(crate) fn buffered(&self) -> usize {
        self.end - self.start - self.pending
    }
}

/// A scanner seen as a source of items (packets, lines, responses, commands): what the
/// `feed` loop needs.
pub(crate) trait Scan {
    /// What the scanner yields, borrowed from its buffer.
    type Item<'a>
    where
        Self: 'a;
    /// Copies as many bytes as fit; returns how many were taken.
    fn push(&mut self, bytes: &[u8]) -> usize;
    /// The next item, if one is complete.
    fn next_item(&mut self) -> Option<Self::Item<'_>>;
    /// No more bytes are coming for what is buffered.
    fn expire(&mut self);
}

/// Pushes all of `bytes` into `s`, handing every item completed to `on_item`; a full buffer
/// is drained before more bytes go in.
pub(crate) fn feed<S: Scan>(s: &mut S, mut bytes: &[u8], mut on_item: impl FnMut(S::Item<'_>)) {
    loop {
        let n = s.push(bytes);
        bytes = &bytes[n..];
        while let Some(item) = s.next_item() {
            on_item(item);
        }
        if bytes.is_empty() {
            return;
        }
    }
}

/// Expires `s`, then hands every item still complete behind what is truncated to `on_item`.
pub(crate) fn expire_with<S: Scan>(s: &mut S, mut on_item: impl FnMut(S::Item<'_>)) {
    s.expire();
    while let Some(item) = s.next_item() {
        on_item(item);
    }
}

/// Fixed-capacity framing engine shared by the binary scanners.
pub(crate) struct Engine<const N: usize> {
    win: Window<N>,
    max_packet: usize,
    garbage_run: bool,
    stats: ScanStats,
}

impl<const N: usize> Engine<N> {
    /// `max_packet` is clamped so that every decision fits the buffer: a rejected candidate may
    /// need up to `header_len - 1` bytes past its end to find the next header.
    pub(crate) fn new(max_packet: usize, header_len: usize) -> Self {
        let cap = N.saturating_sub(header_len.saturating_sub(1));
        Self {
            win: Window::new(),
            max_packet: max_packet.min(cap),
            garbage_run: false,
            stats: ScanStats::default(),
        }
    }

    pub(crate) fn max_packet(&self) -> usize {
        self.max_packet
    }

    pub(crate) fn stats(&self) -> &ScanStats {
        &self.stats
    }

    pub(crate) fn buffered(&self) -> usize {
        self.win.buffered()
    }

    pub(crate) fn push(&mut self, data: &[u8]) -> usize {
        let n = self.win.push(data);
        self.stats.bytes_in += n as u64;
        n
    }

    pub(crate) fn expire(&mut self) {
        self.win.expire();
    }

    pub(crate) fn buf_mut(&mut self) -> &mut [u8; N] {
        self.win.buf_mut()
    }

    fn discard(&mut self, n: usize, cause: Cause) {
        let garbage_run = self.garbage_run;
        let s = &mut self.stats;
        match cause {
            Cause::Garbage => s.garbage.add(n, !garbage_run),
            Cause::BadHeader => s.bad_header.add(n, true),
            Cause::Oversize => s.oversize.add(n, true),
            Cause::BadCrc => s.bad_crc.add(n, true),
            Cause::Truncated => s.truncated.add(n, true),
        }
        self.garbage_run = cause == Cause::Garbage;
        self.win.drop_front(n);
    }

    /// Rejects the candidate at the head: discards its first `limit` bytes, or fewer if a
    /// complete header starts inside them. Returns false if that cannot be decided yet.
    fn reject<F: Framing>(&mut self, cause: Cause, limit: usize) -> bool {
        let data = self.win.data();
        let cut = match find_header(data, F::HEADER, 1, limit, self.win.flushing()) {
            HeaderAt::Full(k) => k,
            HeaderAt::Partial(_) => return false,
            HeaderAt::None => limit.min(data.len()),
        };
        self.discard(cut, cause);
        true
    }

    /// Scans for the next complete, checked packet and returns its range in the buffer.
    pub(crate) fn next_frame<F: Framing>(&mut self) -> Option<core::ops::Range<usize>> {
        self.win.consume_pending();
        loop {
            let data = self.win.data();
            let avail = data.len();
            if avail == 0 {
                return None;
            }
            let flush = self.win.flushing();
            match find_header(data, F::HEADER, 0, avail, flush) {
                HeaderAt::Full(0) | HeaderAt::Partial(0) => {}
                HeaderAt::Full(i) | HeaderAt::Partial(i) => {
                    self.discard(i, Cause::Garbage);
                    continue;
                }
                HeaderAt::None => {
                    self.discard(avail, Cause::Garbage);
                    continue;
                }
            }
            if avail < F::FIELDS_LEN {
                if flush {
                    self.discard(avail, Cause::Truncated);
                    continue;
                }
                return None;
            }
            let total = match F::total_len(&data[..F::FIELDS_LEN]) {
                None => {
                    if self.reject::<F>(Cause::BadHeader, F::FIELDS_LEN) {
                        continue;
                    }
                    return None;
                }
                Some(t) if t > self.max_packet => {
                    if self.reject::<F>(Cause::Oversize, F::FIELDS_LEN) {
                        continue;
                    }
                    return None;
                }
                Some(t) => t,
            };
            if avail < total {
                if flush {
                    // Resolved with flush semantics, so this always discards.
                    self.reject::<F>(Cause::Truncated, avail);
                    continue;
                }
                return None;
            }
            if !F::check(&data[..total]) {
                if self.reject::<F>(Cause::BadCrc, total) {
                    continue;
                }
                return None;
            }
            self.stats.packets += 1;
            self.stats.packet_bytes += total as u64;
            self.garbage_run = false;
            return Some(self.win.yield_front(total));
        }
    }
}
