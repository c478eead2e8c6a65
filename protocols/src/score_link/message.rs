//! The messages of the link and their byte layouts (all integers little-endian, `f64` as IEEE
//! 754 bits, strings as a length byte and UTF-8).

use super::frame::{encode_frame, FrameError};
use super::wire::Reader;
use super::{MAX_MESSAGE, MAX_TEXT, VERSION};
use crate::code_table::code_table;
use crate::writer::Writer;

/// Most samples in one [`Reply::Samples`] message (9 bytes each after a 16-byte head).
pub const MAX_SAMPLES: usize = (MAX_MESSAGE - HEADER - 13) / 9;

const HEADER: usize = 4;

// Longest strings of each field, in bytes; the encoder refuses and the decoder rejects longer.
const FIRMWARE_MAX: usize = 64;
const BOARD_MAX: usize = 64;
const NUMBER_TYPE_MAX: usize = 16;
const KIND_MAX: usize = 32;
const UNIT_MAX: usize = 16;
const NAME_MAX: usize = 64;

/// A message could not be encoded or decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum MessageError {
    /// Shorter than its fields.
    #[error("message truncated")]
    Truncated,
    /// Written by another protocol version.
    #[error("protocol version {found}, this side speaks {VERSION}")]
    Version {
        /// The version byte received.
        found: u8,
    },
    /// The kind byte names no message of this direction.
    #[error("unknown message kind 0x{0:02x}")]
    UnknownKind(u8),
    /// A field holds a value outside its range.
    #[error("bad {field}: {value}")]
    BadField {
        /// Which field.
        field: &'static str,
        /// The value received.
        value: u32,
    },
    /// A string is not UTF-8.
    #[error("text is not UTF-8")]
    BadUtf8,
    /// Bytes after the last field.
    #[error("{extra} bytes after the message")]
    TrailingBytes {
        /// How many.
        extra: usize,
    },
    /// The message would exceed [`MAX_MESSAGE`] or a string its limit.
    #[error("message too long")]
    TooLong,
}

/// What the host asks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Request<'a> {
    /// Who are you? Answered by [`Reply::Hello`].
    Hello,
    /// Every variable: [`Reply::Var`] per variable, then [`Reply::ListEnd`].
    ListVars,
    /// Send variable `id` every `period_us` µs in [`Reply::Samples`] (0 stops it). [`Reply::Ack`].
    Subscribe {
        /// Variable slot.
        id: u8,
        /// Sampling period in microseconds; 0 unsubscribes.
        period_us: u32,
        /// Table generation the host listed `id` in; refused with [`ErrorCode::Stale`] if the
        /// table has changed since (the slot may hold another variable now).
        generation: u32,
    },
    /// Stop every subscription. [`Reply::Ack`].
    UnsubscribeAll,
    /// Write a writable variable. [`Reply::SetDone`] with the value it took.
    Set {
        /// Variable slot.
        id: u8,
        /// New value.
        value: f64,
        /// Table generation the host listed `id` in (see [`Request::Subscribe`]).
        generation: u32,
    },
    /// Run one command line as if typed on the terminal: [`Reply::Output`] chunks, then
    /// [`Reply::ExecDone`].
    Exec {
        /// The line (at most [`MAX_TEXT`] bytes).
        line: &'a str,
    },
    /// The board's clock now: [`Reply::Time`].
    Time,
}

code_table! {
    /// Why the board refused a request.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum ErrorCode {
        /// The request could not be decoded.
        BadRequest = 1,
        /// No variable in that slot.
        UnknownVariable = 2,
        /// The variable cannot be written.
        NotWritable = 3,
        /// The engine refused (the text says why).
        Refused = 4,
        /// No free subscription slot.
        TooManySubscriptions = 5,
        /// The table changed since the host listed it: list again.
        Stale = 6,
    }
}

/// The board's identity, answered to [`Request::Hello`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hello<'a> {
    /// Protocol version the board speaks (= [`VERSION`] when the message decoded).
    pub protocol: u8,
    /// Firmware name and version (at most 64 bytes).
    pub firmware: &'a str,
    /// Board name (the gateway's default subsystem is `score-<board>`; at most 64 bytes).
    pub board: &'a str,
    /// The engine's number type (`f32` or `f64`; at most 16 bytes).
    pub number_type: &'a str,
    /// The variable table's generation (changes with every definition or deletion).
    pub generation: u32,
    /// The board's clock when it answered, µs since boot.
    pub t_us: u64,
    /// Subscriptions the board can hold at once.
    pub max_subscriptions: u8,
}

/// One variable of a listing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VarEntry<'a> {
    /// Table generation the listing describes.
    pub generation: u32,
    /// Position in the listing (0-based).
    pub index: u8,
    /// Variables in the listing.
    pub total: u8,
    /// Slot: the address used by [`Request::Subscribe`] and [`Request::Set`].
    pub id: u8,
    /// What the variable is, as `score-core` names it (`AdcVolts`, `Pid`, ...; at most 32 bytes).
    pub kind: &'a str,
    /// Accepts [`Request::Set`].
    pub writable: bool,
    /// Update rate when periodic.
    pub rate_hz: Option<f64>,
    /// Unit (`V`, `count`, `%`, `1`), empty when unitless (at most 16 bytes).
    pub unit: &'a str,
    /// Name (at most 64 bytes).
    pub name: &'a str,
}

/// Samples of subscribed variables taken at one instant of the board's clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleBatch<'a> {
    /// Board clock of the sampling, µs since boot.
    pub t_us: u64,
    /// Samples the board has dropped since boot because the link was too slow.
    pub lost: u32,
    entries: Entries<'a>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Entries<'a> {
    Values(&'a [(u8, f64)]),
    Wire(&'a [u8]),
}

impl<'a> SampleBatch<'a> {
    /// A batch to encode; at most [`MAX_SAMPLES`] entries of `(id, value)`.
    pub fn new(t_us: u64, lost: u32, entries: &'a [(u8, f64)]) -> Self {
        Self {
            t_us,
            lost,
            entries: Entries::Values(entries),
        }
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        match self.entries {
            Entries::Values(v) => v.len(),
            Entries::Wire(b) => b.len() / 9,
        }
    }

    /// True if there are none.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The `(id, value)` pairs.
    pub fn iter(&self) -> SampleIter<'a> {
        SampleIter {
            entries: self.entries,
            pos: 0,
        }
    }
}

/// Iterator over a [`SampleBatch`].
#[derive(Debug, Clone)]
pub struct SampleIter<'a> {
    entries: Entries<'a>,
    pos: usize,
}

impl Iterator for SampleIter<'_> {
    type Item = (u8, f64);
    fn next(&mut self) -> Option<(u8, f64)> {
        let item = match self.entries {
            Entries::Values(v) => *v.get(self.pos)?,
            Entries::Wire(b) => {
                let e = b.get(self.pos * 9..self.pos * 9 + 9)?;
                let mut bits = [0u8; 8];
                bits.copy_from_slice(&e[1..]);
                (e[0], f64::from_bits(u64::from_le_bytes(bits)))
            }
        };
        self.pos += 1;
        Some(item)
    }
}

/// What the board sends.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Reply<'a> {
    /// Answer to [`Request::Hello`].
    Hello(Hello<'a>),
    /// One variable of a listing.
    Var(VarEntry<'a>),
    /// End of a listing.
    ListEnd {
        /// Generation listed.
        generation: u32,
        /// Variables listed.
        count: u8,
    },
    /// A request without other result succeeded.
    Ack,
    /// [`Request::Set`] succeeded; the variable now holds `value` (after quantisation).
    SetDone {
        /// The value taken.
        value: f64,
    },
    /// Terminal text produced by [`Request::Exec`] (one chunk of at most [`MAX_TEXT`] bytes).
    Output {
        /// The text.
        text: &'a str,
    },
    /// [`Request::Exec`] finished.
    ExecDone {
        /// False if the engine refused the line (the error text was sent as output).
        ok: bool,
        /// Table generation after the line.
        generation: u32,
    },
    /// Answer to [`Request::Time`].
    Time {
        /// Board clock, µs since boot.
        t_us: u64,
    },
    /// A request was refused.
    Error {
        /// Why, as a code.
        code: ErrorCode,
        /// Why, in words.
        text: &'a str,
    },
    /// Unsolicited (seq 0): samples of subscribed variables.
    Samples(SampleBatch<'a>),
    /// Unsolicited (seq 0): the table changed; list again.
    TableChanged {
        /// The new generation.
        generation: u32,
    },
}

mod kind {
    pub const HELLO: u8 = 0x01;
    pub const LIST: u8 = 0x02;
    pub const SUBSCRIBE: u8 = 0x03;
    pub const UNSUBSCRIBE_ALL: u8 = 0x04;
    pub const SET: u8 = 0x05;
    pub const EXEC: u8 = 0x06;
    pub const TIME: u8 = 0x07;

    pub const R_HELLO: u8 = 0x81;
    pub const R_VAR: u8 = 0x82;
    pub const R_LIST_END: u8 = 0x83;
    pub const R_ACK: u8 = 0x84;
    pub const R_SET_DONE: u8 = 0x85;
    pub const R_OUTPUT: u8 = 0x86;
    pub const R_EXEC_DONE: u8 = 0x87;
    pub const R_TIME: u8 = 0x88;
    pub const R_ERROR: u8 = 0x8f;
    pub const E_SAMPLES: u8 = 0xc0;
    pub const E_TABLE_CHANGED: u8 = 0xc1;
}

struct Out<'a>(Writer<'a>);

impl Out<'_> {
    fn u8(&mut self, v: u8) -> Result<(), MessageError> {
        self.0.put(v).map_err(|_| MessageError::TooLong)
    }
    fn bytes(&mut self, v: &[u8]) -> Result<(), MessageError> {
        self.0.put_all(v).map_err(|_| MessageError::TooLong)
    }
    fn u16(&mut self, v: u16) -> Result<(), MessageError> {
        self.bytes(&v.to_le_bytes())
    }
    fn u32(&mut self, v: u32) -> Result<(), MessageError> {
        self.bytes(&v.to_le_bytes())
    }
    fn u64(&mut self, v: u64) -> Result<(), MessageError> {
        self.bytes(&v.to_le_bytes())
    }
    fn f64(&mut self, v: f64) -> Result<(), MessageError> {
        self.u64(v.to_bits())
    }
    fn str(&mut self, s: &str, max: usize) -> Result<(), MessageError> {
        if s.len() > max.min(255) {
            return Err(MessageError::TooLong);
        }
        self.u8(s.len() as u8)?;
        self.bytes(s.as_bytes())
    }
}

fn header(w: &mut Out<'_>, kind: u8, seq: u16) -> Result<(), MessageError> {
    w.u8(VERSION)?;
    w.u8(kind)?;
    w.u16(seq)
}

fn write_request(seq: u16, req: &Request<'_>, w: &mut Out<'_>) -> Result<(), MessageError> {
    match *req {
        Request::Hello => header(w, kind::HELLO, seq),
        Request::ListVars => header(w, kind::LIST, seq),
        Request::Subscribe {
            id,
            period_us,
            generation,
        } => {
            header(w, kind::SUBSCRIBE, seq)?;
            w.u8(id)?;
            w.u32(period_us)?;
            w.u32(generation)
        }
        Request::UnsubscribeAll => header(w, kind::UNSUBSCRIBE_ALL, seq),
        Request::Set {
            id,
            value,
            generation,
        } => {
            header(w, kind::SET, seq)?;
            w.u8(id)?;
            w.f64(value)?;
            w.u32(generation)
        }
        Request::Exec { line } => {
            header(w, kind::EXEC, seq)?;
            w.str(line, MAX_TEXT)
        }
        Request::Time => header(w, kind::TIME, seq),
    }
}

fn write_reply(seq: u16, reply: &Reply<'_>, w: &mut Out<'_>) -> Result<(), MessageError> {
    match *reply {
        Reply::Hello(h) => {
            header(w, kind::R_HELLO, seq)?;
            w.u8(h.protocol)?;
            w.str(h.firmware, FIRMWARE_MAX)?;
            w.str(h.board, BOARD_MAX)?;
            w.str(h.number_type, NUMBER_TYPE_MAX)?;
            w.u32(h.generation)?;
            w.u64(h.t_us)?;
            w.u8(h.max_subscriptions)
        }
        Reply::Var(v) => {
            header(w, kind::R_VAR, seq)?;
            w.u32(v.generation)?;
            w.u8(v.index)?;
            w.u8(v.total)?;
            w.u8(v.id)?;
            w.str(v.kind, KIND_MAX)?;
            w.u8(v.writable as u8)?;
            // No rate is sent as NaN: a periodic variable's rate is always finite and positive.
            w.f64(v.rate_hz.unwrap_or(f64::NAN))?;
            w.str(v.unit, UNIT_MAX)?;
            w.str(v.name, NAME_MAX)
        }
        Reply::ListEnd { generation, count } => {
            header(w, kind::R_LIST_END, seq)?;
            w.u32(generation)?;
            w.u8(count)
        }
        Reply::Ack => header(w, kind::R_ACK, seq),
        Reply::SetDone { value } => {
            header(w, kind::R_SET_DONE, seq)?;
            w.f64(value)
        }
        Reply::Output { text } => {
            header(w, kind::R_OUTPUT, seq)?;
            w.str(text, MAX_TEXT)
        }
        Reply::ExecDone { ok, generation } => {
            header(w, kind::R_EXEC_DONE, seq)?;
            w.u8(ok as u8)?;
            w.u32(generation)
        }
        Reply::Time { t_us } => {
            header(w, kind::R_TIME, seq)?;
            w.u64(t_us)
        }
        Reply::Error { code, text } => {
            header(w, kind::R_ERROR, seq)?;
            w.u8(code as u8)?;
            w.str(text, MAX_TEXT)
        }
        Reply::Samples(b) => {
            header(w, kind::E_SAMPLES, seq)?;
            if b.len() > MAX_SAMPLES {
                return Err(MessageError::TooLong);
            }
            w.u64(b.t_us)?;
            w.u32(b.lost)?;
            w.u8(b.len() as u8)?;
            for (id, v) in b.iter() {
                w.u8(id)?;
                w.f64(v)?;
            }
            Ok(())
        }
        Reply::TableChanged { generation } => {
            header(w, kind::E_TABLE_CHANGED, seq)?;
            w.u32(generation)
        }
    }
}

/// Encodes `req` with sequence number `seq` as a whole frame (COBS, CRC, terminating 0) into
/// `out`; returns the frame length. `out` needs at most [`super::MAX_FRAME`] bytes.
pub fn encode_request(seq: u16, req: &Request<'_>, out: &mut [u8]) -> Result<usize, FrameError> {
    let mut msg = [0u8; MAX_MESSAGE];
    let mut w = Out(Writer::new(&mut msg));
    write_request(seq, req, &mut w)?;
    let n = w.0.pos();
    encode_frame(&msg[..n], out)
}

/// Encodes `reply` with sequence number `seq` (0 for unsolicited messages) as a whole frame.
pub fn encode_reply(seq: u16, reply: &Reply<'_>, out: &mut [u8]) -> Result<usize, FrameError> {
    let mut msg = [0u8; MAX_MESSAGE];
    let mut w = Out(Writer::new(&mut msg));
    write_reply(seq, reply, &mut w)?;
    let n = w.0.pos();
    encode_frame(&msg[..n], out)
}

fn read_header(r: &mut Reader<'_>) -> Result<(u8, u16), MessageError> {
    let version = r.u8()?;
    if version != VERSION {
        return Err(MessageError::Version { found: version });
    }
    let kind = r.u8()?;
    let seq = r.u16()?;
    Ok((kind, seq))
}

/// Decodes a checked message (as yielded by [`super::FrameScanner`]) sent by the host.
pub fn decode_request(msg: &[u8]) -> Result<(u16, Request<'_>), MessageError> {
    let mut r = Reader::new(msg);
    let (k, seq) = read_header(&mut r)?;
    let req = match k {
        kind::HELLO => Request::Hello,
        kind::LIST => Request::ListVars,
        kind::SUBSCRIBE => Request::Subscribe {
            id: r.u8()?,
            period_us: r.u32()?,
            generation: r.u32()?,
        },
        kind::UNSUBSCRIBE_ALL => Request::UnsubscribeAll,
        kind::SET => Request::Set {
            id: r.u8()?,
            value: r.f64()?,
            generation: r.u32()?,
        },
        kind::EXEC => Request::Exec {
            line: r.str(MAX_TEXT)?,
        },
        kind::TIME => Request::Time,
        other => return Err(MessageError::UnknownKind(other)),
    };
    r.end()?;
    Ok((seq, req))
}

/// Decodes a checked message sent by the board.
pub fn decode_reply(msg: &[u8]) -> Result<(u16, Reply<'_>), MessageError> {
    let mut r = Reader::new(msg);
    let (k, seq) = read_header(&mut r)?;
    let reply = match k {
        kind::R_HELLO => Reply::Hello(Hello {
            protocol: r.u8()?,
            firmware: r.str(FIRMWARE_MAX)?,
            board: r.str(BOARD_MAX)?,
            number_type: r.str(NUMBER_TYPE_MAX)?,
            generation: r.u32()?,
            t_us: r.u64()?,
            max_subscriptions: r.u8()?,
        }),
        kind::R_VAR => Reply::Var(VarEntry {
            generation: r.u32()?,
            index: r.u8()?,
            total: r.u8()?,
            id: r.u8()?,
            kind: r.str(KIND_MAX)?,
            writable: r.bool()?,
            rate_hz: Some(r.f64()?).filter(|v| !v.is_nan()),
            unit: r.str(UNIT_MAX)?,
            name: r.str(NAME_MAX)?,
        }),
        kind::R_LIST_END => Reply::ListEnd {
            generation: r.u32()?,
            count: r.u8()?,
        },
        kind::R_ACK => Reply::Ack,
        kind::R_SET_DONE => Reply::SetDone { value: r.f64()? },
        kind::R_OUTPUT => Reply::Output {
            text: r.str(MAX_TEXT)?,
        },
        kind::R_EXEC_DONE => Reply::ExecDone {
            ok: r.bool()?,
            generation: r.u32()?,
        },
        kind::R_TIME => Reply::Time { t_us: r.u64()? },
        kind::R_ERROR => Reply::Error {
            code: {
                let v = r.u8()?;
                ErrorCode::from_code(v).ok_or(MessageError::BadField {
                    field: "error code",
                    value: v as u32,
                })?
            },
            text: r.str(MAX_TEXT)?,
        },
        kind::E_SAMPLES => {
            let t_us = r.u64()?;
            let lost = r.u32()?;
            let n = r.u8()? as usize;
            if n > MAX_SAMPLES {
                return Err(MessageError::BadField {
                    field: "sample count",
                    value: n as u32,
                });
            }
            let raw = r.bytes(n * 9)?;
            Reply::Samples(SampleBatch {
                t_us,
                lost,
                entries: Entries::Wire(raw),
            })
        }
        kind::E_TABLE_CHANGED => Reply::TableChanged {
            generation: r.u32()?,
        },
        other => return Err(MessageError::UnknownKind(other)),
    };
    r.end()?;
    Ok((seq, reply))
}
