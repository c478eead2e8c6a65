//! Adapter → host lines: acknowledgements, received frames, query replies.

use super::{parse_frame, parse_hex, put_frame, put_hex, Line, SlcanError, BEL, CR};
use crate::can::CanFrame;
use crate::writer::Writer;

/// Something the adapter sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Response<'a> {
    /// A bare CR: the oldest pending command succeeded.
    Ok,
    /// BEL: the oldest pending command failed.
    Error,
    /// `z` (`extended == false`) or `Z`: LAWICEL's acknowledgement of a transmitted frame.
    TxAck {
        /// `Z` (after `T`/`R`).
        extended: bool,
    },
    /// A received frame, with its timestamp (ms, 0–59 999) if timestamps are on.
    Frame {
        /// The frame.
        frame: CanFrame,
        /// Timestamp, if present.
        timestamp: Option<u16>,
    },
    /// `Fxx`: status flags.
    Status(u8),
    /// `V…`/`v…`: version text after the letter.
    Version(&'a [u8]),
    /// `N…`: serial number text after the letter.
    Serial(&'a [u8]),
    /// `e…`: Linux-slcan error-frame extension, text after the letter.
    ErrorFrame(&'a [u8]),
    /// `s…`: Linux-slcan bus-state extension, text after the letter.
    BusState(&'a [u8]),
}

/// A parsed response with text given as an offset into the line, so a scanner can decide on a
/// line before borrowing it for the caller.
#[derive(Clone, Copy)]
pub(crate) enum Parsed {
    Ok,
    Error,
    TxAck(bool),
    Frame(CanFrame, Option<u16>),
    Status(u8),
    /// Text kind (the line's first byte); the text is `line[1..]`.
    Text(u8),
}

/// Parses one adapter line. Received frames may carry a 4-digit timestamp only when
/// `timestamps` is on (the host sent `Z1`): otherwise extra digits make the line malformed,
/// never a timestamp.
pub(crate) fn parse(line: Line<'_>, timestamps: bool) -> Result<Parsed, SlcanError> {
    if line.terminator == BEL {
        return if line.body.is_empty() {
            Ok(Parsed::Error)
        } else {
            Err(SlcanError::Bel)
        };
    }
    let body = line.body;
    let Some((&c, rest)) = body.split_first() else {
        return Ok(Parsed::Ok);
    };
    match c {
        b'z' | b'Z' if rest.is_empty() => Ok(Parsed::TxAck(c == b'Z')),
        b't' | b'T' | b'r' | b'R' => {
            let (f, ts) = parse_frame(body, timestamps)?;
            Ok(Parsed::Frame(f, ts))
        }
        b'F' => match rest.len() {
            2 => Ok(Parsed::Status(parse_hex(rest)? as u8)),
            _ => Err(SlcanError::Length),
        },
        b'V' | b'v' | b'N' | b'e' | b's' => Ok(Parsed::Text(c)),
        other => Err(SlcanError::Unknown(other)),
    }
}

impl Parsed {
    pub(crate) fn resolve(self, body: &[u8]) -> Response<'_> {
        let text = body.get(1..).unwrap_or(&[]);
        match self {
            Parsed::Ok => Response::Ok,
            Parsed::Error => Response::Error,
            Parsed::TxAck(extended) => Response::TxAck { extended },
            Parsed::Frame(frame, timestamp) => Response::Frame { frame, timestamp },
            Parsed::Status(s) => Response::Status(s),
            Parsed::Text(b'N') => Response::Serial(text),
            Parsed::Text(b'e') => Response::ErrorFrame(text),
            Parsed::Text(b's') => Response::BusState(text),
            Parsed::Text(_) => Response::Version(text),
        }
    }
}

impl<'a> Response<'a> {
    /// Parses one line as the host does; frame timestamps are accepted only with
    /// `timestamps` (the host enabled them with `Z1`).
    pub fn decode(line: Line<'a>, timestamps: bool) -> Result<Self, SlcanError> {
        Ok(parse(line, timestamps)?.resolve(line.body))
    }

    /// Writes the response with its terminator (adapter/simulator side); returns the length.
    pub fn encode(&self, buf: &mut [u8]) -> Result<usize, SlcanError> {
        let mut w = Writer::new(buf);
        let text = |w: &mut Writer<'_>, c: u8, t: &[u8]| -> Result<(), SlcanError> {
            if t.iter().any(|&b| b == CR || b == BEL) {
                return Err(SlcanError::Length);
            }
            w.put(c)?;
            Ok(w.put_all(t)?)
        };
        match *self {
            Response::Ok => {}
            Response::Error => {
                w.put(BEL)?;
                return Ok(w.pos());
            }
            Response::TxAck { extended } => w.put(if extended { b'Z' } else { b'z' })?,
            Response::Frame {
                ref frame,
                timestamp,
            } => put_frame(&mut w, frame, timestamp)?,
            Response::Status(s) => {
                w.put(b'F')?;
                put_hex(&mut w, s as u32, 2)?;
            }
            Response::Version(t) => text(&mut w, b'V', t)?,
            Response::Serial(t) => text(&mut w, b'N', t)?,
            Response::ErrorFrame(t) => text(&mut w, b'e', t)?,
            Response::BusState(t) => text(&mut w, b's', t)?,
        }
        w.put(CR)?;
        Ok(w.pos())
    }
}
