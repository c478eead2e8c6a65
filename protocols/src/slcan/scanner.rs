//! Line scanners: bytes in any chunking → lines → responses (host) or commands (adapter).
//!
//! Accounting, as for the binary scanners:
//! `bytes_in == line_bytes + discarded_bytes() + buffered()`, independent of chunking
//! (given the same `expire` points). A line's bytes include its terminator.

use super::response::{parse, Parsed};
use super::{Command, Dialect, Response, SlcanError, BEL, CR};
use crate::scan::{self, Scan, Tally, Window};

/// One line: its body and the terminator that ended it (CR or BEL).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Line<'a> {
    /// Bytes before the terminator.
    pub body: &'a [u8],
    /// [`CR`] or [`BEL`].
    pub terminator: u8,
}

/// Counters of the SLCAN scanners.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LineStats {
    /// Bytes accepted.
    pub bytes_in: u64,
    /// Lines delivered (as a response, a command, or a raw line).
    pub lines: u64,
    /// Bytes of the delivered lines, terminators included.
    pub line_bytes: u64,
    /// Lines whose first character is known but whose syntax is wrong (bad hex, length, DLC,
    /// ID range, bitrate digit), and text before a BEL (the BEL itself is delivered as
    /// [`Response::Error`]).
    pub malformed: Tally,
    /// Lines starting with a character this side does not know (e.g. CAN FD frames).
    pub unknown: Tally,
    /// Lines longer than the scanner's capacity, discarded up to and including their
    /// terminator (one event per line).
    pub overlong: Tally,
    /// An unterminated line still buffered when `expire()` was called.
    pub truncated: Tally,
}

impl LineStats {
    /// All bytes discarded.
    pub fn discarded_bytes(&self) -> u64 {
        self.malformed.bytes + self.unknown.bytes + self.overlong.bytes + self.truncated.bytes
    }
}

/// Splits a byte stream into CR- or BEL-terminated lines of at most `N - 1` body bytes.
pub struct LineScanner<const N: usize = 64> {
    win: Window<N>,
    /// Inside an overlong line: drop bytes up to the next terminator.
    skipping: bool,
    stats: LineStats,
}

impl<const N: usize> Default for LineScanner<N> {
    fn default() -> Self {
        Self::new()
    }
}

fn is_terminator(b: u8) -> bool {
    b == CR || b == BEL
}

impl<const N: usize> LineScanner<N> {
    const MIN_CAPACITY: () = assert!(N >= 2, "line scanner capacity must be at least 2");

    /// An empty scanner.
    pub fn new() -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::MIN_CAPACITY;
        Self {
            win: Window::new(),
            skipping: false,
            stats: LineStats::default(),
        }
    }

    /// Copies as many bytes as fit; returns how many were taken. After
    /// [`next_line`](Self::next_line) has returned `None` at least one byte always fits.
    pub fn push(&mut self, data: &[u8]) -> usize {
        let n = self.win.push(data);
        self.stats.bytes_in += n as u64;
        n
    }

    /// No more bytes are coming for the buffered partial line: it is discarded as truncated
    /// by the next [`next_line`](Self::next_line). The next `push` ends this.
    pub fn expire(&mut self) {
        self.win.expire();
    }

    /// The next complete line as (body range, terminator); the line is consumed by the next
    /// call.
    pub(crate) fn next_range(&mut self) -> Option<(core::ops::Range<usize>, u8)> {
        self.win.consume_pending();
        loop {
            let data = self.win.data();
            let term = data.iter().position(|&b| is_terminator(b));
            if self.skipping {
                let n = term.map_or(data.len(), |i| i + 1);
                self.stats.overlong.bytes += n as u64;
                self.win.drop_front(n);
                term?;
                self.skipping = false;
                continue;
            }
            match term {
                Some(i) => {
                    let t = data[i];
                    self.stats.lines += 1;
                    self.stats.line_bytes += i as u64 + 1;
                    let line = self.win.yield_front(i + 1);
                    return Some((line.start..line.end - 1, t));
                }
                None if data.len() >= N => {
                    self.stats.overlong.events += 1;
                    self.skipping = true;
                }
                None if self.win.flushing() && !data.is_empty() => {
                    self.stats.truncated.add(data.len(), true);
                    let n = data.len();
                    self.win.drop_front(n);
                    return None;
                }
                None => return None,
            }
        }
    }

    /// The next complete line, borrowed until the next call.
    pub fn next_line(&mut self) -> Option<Line<'_>> {
        let (r, terminator) = self.next_range()?;
        Some(Line {
            body: &self.win.buf()[r],
            terminator,
        })
    }

    /// Counters since creation.
    pub fn stats(&self) -> &LineStats {
        &self.stats
    }

    /// Bytes accepted but not yet delivered or discarded.
    pub fn buffered(&self) -> usize {
        self.win.buffered()
    }

    /// Moves a delivered line into a discard cause (used by the parsing scanners).
    fn reclassify(&mut self, bytes: usize, malformed: bool) {
        self.stats.lines -= 1;
        self.stats.line_bytes -= bytes as u64;
        if malformed {
            self.stats.malformed.add(bytes, true);
        } else {
            self.stats.unknown.add(bytes, true);
        }
    }
}

/// Host side: adapter bytes → [`Response`]s. Lines that do not parse are counted and skipped.
///
/// ```
/// use conductor_protocols::slcan::{HostScanner, Response};
/// let mut s = HostScanner::<64>::new();
/// s.push(b"\rt1230\rz\r\x07");
/// assert_eq!(s.next_response(), Some(Response::Ok));
/// assert!(matches!(s.next_response(), Some(Response::Frame { .. })));
/// assert_eq!(s.next_response(), Some(Response::TxAck { extended: false }));
/// assert_eq!(s.next_response(), Some(Response::Error));
/// assert_eq!(s.next_response(), None);
/// ```
pub struct HostScanner<const N: usize = 64> {
    lines: LineScanner<N>,
    timestamps: bool,
}

impl<const N: usize> Default for HostScanner<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> HostScanner<N> {
    /// An empty scanner. Received frames with a timestamp are malformed until
    /// [`set_timestamps`](Self::set_timestamps) says the adapter was told to send them.
    pub fn new() -> Self {
        Self {
            lines: LineScanner::new(),
            timestamps: false,
        }
    }

    /// Whether received frames carry a timestamp (the host sent `Z1`).
    pub fn set_timestamps(&mut self, on: bool) {
        self.timestamps = on;
    }

    /// See [`LineScanner::push`].
    pub fn push(&mut self, data: &[u8]) -> usize {
        self.lines.push(data)
    }

    /// See [`LineScanner::expire`].
    pub fn expire(&mut self) {
        self.lines.expire();
    }

    /// The next well-formed response, borrowed until the next call.
    pub fn next_response(&mut self) -> Option<Response<'_>> {
        let (range, parsed) = loop {
            let (r, term) = self.lines.next_range()?;
            let line = super::Line {
                body: &self.lines.win.buf()[r.clone()],
                terminator: term,
            };
            match parse(line, self.timestamps) {
                Ok(p) => break (r, p),
                Err(SlcanError::Bel) => {
                    // Text before a BEL is malformed; the BEL itself is the error reply.
                    let n = r.len();
                    self.lines.stats.line_bytes -= n as u64;
                    self.lines.stats.malformed.add(n, true);
                    break (r.end..r.end, Parsed::Error);
                }
                Err(e) => self
                    .lines
                    .reclassify(r.len() + 1, !matches!(e, SlcanError::Unknown(_))),
            }
        };
        Some(parsed.resolve(&self.lines.win.buf()[range]))
    }

    /// Pushes all of `bytes`, calling `on_response` for each response.
    pub fn feed(&mut self, bytes: &[u8], on_response: impl FnMut(Response<'_>)) {
        scan::feed(self, bytes, on_response);
    }

    /// Counters since creation.
    pub fn stats(&self) -> &LineStats {
        self.lines.stats()
    }

    /// Bytes accepted but not yet delivered or discarded.
    pub fn buffered(&self) -> usize {
        self.lines.buffered()
    }
}

/// Adapter side (simulators): host bytes → [`Command`]s. A line that does not parse is
/// returned as `Err` (the adapter answers BEL) and counted as malformed/unknown.
pub struct DeviceScanner<const N: usize = 64> {
    lines: LineScanner<N>,
    dialect: Dialect,
}

impl<const N: usize> DeviceScanner<N> {
    /// An empty scanner decoding `Sn` in `dialect`.
    pub fn new(dialect: Dialect) -> Self {
        Self {
            lines: LineScanner::new(),
            dialect,
        }
    }

    /// See [`LineScanner::push`].
    pub fn push(&mut self, data: &[u8]) -> usize {
        self.lines.push(data)
    }

    /// See [`LineScanner::expire`].
    pub fn expire(&mut self) {
        self.lines.expire();
    }

    /// The next command line, decoded.
    pub fn next_command(&mut self) -> Option<Result<Command, SlcanError>> {
        let (r, term) = self.lines.next_range()?;
        let body = &self.lines.win.buf()[r.clone()];
        let result = if term == BEL {
            Err(SlcanError::Bel)
        } else {
            Command::decode(body, &self.dialect)
        };
        if let Err(e) = result {
            self.lines
                .reclassify(r.len() + 1, !matches!(e, SlcanError::Unknown(_)));
        }
        Some(result)
    }

    /// Pushes all of `bytes`, calling `on_command` for each line.
    pub fn feed(&mut self, bytes: &[u8], on_command: impl FnMut(Result<Command, SlcanError>)) {
        scan::feed(self, bytes, on_command);
    }

    /// Counters since creation.
    pub fn stats(&self) -> &LineStats {
        self.lines.stats()
    }

    /// Bytes accepted but not yet delivered or discarded.
    pub fn buffered(&self) -> usize {
        self.lines.buffered()
    }
}

impl<const N: usize> Scan for HostScanner<N> {
    type Item<'a> = Response<'a>;

    fn push(&mut self, bytes: &[u8]) -> usize {
        HostScanner::push(self, bytes)
    }

    fn next_item(&mut self) -> Option<Response<'_>> {
        self.next_response()
    }

    fn expire(&mut self) {
        HostScanner::expire(self);
    }
}

impl<const N: usize> Scan for DeviceScanner<N> {
    type Item<'a> = Result<Command, SlcanError>;

    fn push(&mut self, bytes: &[u8]) -> usize {
        DeviceScanner::push(self, bytes)
    }

    fn next_item(&mut self) -> Option<Result<Command, SlcanError>> {
        self.next_command()
    }

    fn expire(&mut self) {
        DeviceScanner::expire(self);
    }
}
