//! The thesis' plain-text state protocol (§2.5.2), one datagram per request and per reply.
//!
//! | Request | Reply |
//! |---|---|
//! | `SET <float>` | `OK <sent>` or `OK <sent> CLAMPED` (value clamped to the limits) |
//! | `GET` | `<value>` (the newest sample; shortest decimal that reads back exactly) |
//! | `SMP` | `<value> <t_sample_ns> <seq> <status>` of the next sample newer than the request |
//! | `INFO` | `<subsystem/state> <units or -> <rw or ro> <min> <max> <rate_hz>` |
//! | anything else | `ERR <reason>` |
//!
//! Commands are case-insensitive; surrounding whitespace (including `\r\n` and NULs that C
//! clients leave) is ignored.

use std::fmt;

/// Longest datagram accepted (bytes).
pub const MAX_REQUEST: usize = 256;

/// A well-formed request.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Request {
    /// Apply a setpoint.
    Set(f64),
    /// Newest value.
    Get,
    /// Next fresh sample.
    Smp,
    /// Metadata.
    Info,
}

/// Why a datagram is malformed; `Display` is the text after `ERR `.
#[derive(Debug, Clone, PartialEq)]
pub enum Malformed {
    /// Over [`MAX_REQUEST`] bytes (the length seen, possibly truncated by the receive buffer).
    TooLong(usize),
    /// Not UTF-8.
    NotText,
    /// Nothing but whitespace.
    Empty,
    /// Not SET/GET/SMP/INFO.
    UnknownCommand(String),
    /// `SET` without a value.
    MissingValue,
    /// The value does not parse.
    BadNumber(String),
    /// NaN or infinite.
    NotFinite,
    /// Extra words.
    TooManyArguments(&'static str),
}

/// Printable, bounded echo of client text (never reflect control bytes or a whole datagram).
fn quote(s: &str) -> String {
    let mut q: String = s
        .chars()
        .take(24)
        .map(|c| if c.is_ascii_graphic() { c } else { '?' })
        .collect();
    if s.chars().count() > 24 {
        q.push_str("...");
    }
    q
}

impl fmt::Display for Malformed {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Malformed::TooLong(_) => write!(f, "too long (at most {MAX_REQUEST} bytes)"),
            Malformed::NotText => f.write_str("not text (expected ASCII/UTF-8)"),
            Malformed::Empty => {
                f.write_str("empty request (expected SET <float>, GET, SMP or INFO)")
            }
            Malformed::UnknownCommand(c) => write!(
                f,
                "unknown command \"{}\" (expected SET <float>, GET, SMP or INFO)",
                quote(c)
            ),
            Malformed::MissingValue => f.write_str("SET needs a value: SET <float>"),
            Malformed::BadNumber(s) => write!(f, "bad number \"{}\"", quote(s)),
            Malformed::NotFinite => f.write_str("not finite (NaN and inf are refused)"),
            Malformed::TooManyArguments(c) => write!(f, "too many arguments for {c}"),
        }
    }
}

/// Parses one datagram.
pub fn parse(datagram: &[u8]) -> Result<Request, Malformed> {
    if datagram.len() > MAX_REQUEST {
        return Err(Malformed::TooLong(datagram.len()));
    }
    let text = std::str::from_utf8(datagram).map_err(|_| Malformed::NotText)?;
    let text = text.trim_matches(|c: char| c.is_whitespace() || c == '\0');
    let mut words = text.split_whitespace();
    let Some(cmd) = words.next() else {
        return Err(Malformed::Empty);
    };
    let no_args = |name: &'static str, r: Request, mut w: std::str::SplitWhitespace<'_>| {
        if w.next().is_some() {
            Err(Malformed::TooManyArguments(name))
        } else {
            Ok(r)
        }
    };
    if cmd.eq_ignore_ascii_case("SET") {
        let v = words.next().ok_or(Malformed::MissingValue)?;
        if words.next().is_some() {
            return Err(Malformed::TooManyArguments("SET"));
        }
        let x: f64 = v.parse().map_err(|_| Malformed::BadNumber(v.into()))?;
        if !x.is_finite() {
            return Err(Malformed::NotFinite);
        }
        Ok(Request::Set(x))
    } else if cmd.eq_ignore_ascii_case("GET") {
        no_args("GET", Request::Get, words)
    } else if cmd.eq_ignore_ascii_case("SMP") {
        no_args("SMP", Request::Smp, words)
    } else if cmd.eq_ignore_ascii_case("INFO") {
        no_args("INFO", Request::Info, words)
    } else {
        Err(Malformed::UnknownCommand(cmd.into()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn well_formed_requests() {
        assert_eq!(parse(b"SET 1.5"), Ok(Request::Set(1.5)));
        assert_eq!(parse(b"set -2e-3\r\n"), Ok(Request::Set(-2e-3)));
        assert_eq!(parse(b"  GET\n\0"), Ok(Request::Get));
        assert_eq!(parse(b"smp"), Ok(Request::Smp));
        assert_eq!(parse(b"Info"), Ok(Request::Info));
    }

    #[test]
    fn malformed_requests_say_why() {
        assert_eq!(parse(b""), Err(Malformed::Empty));
        assert_eq!(parse(b" \n"), Err(Malformed::Empty));
        assert_eq!(parse(b"SET"), Err(Malformed::MissingValue));
        assert_eq!(parse(b"SET abc"), Err(Malformed::BadNumber("abc".into())));
        assert_eq!(parse(b"SET nan"), Err(Malformed::NotFinite));
        assert_eq!(parse(b"SET inf"), Err(Malformed::NotFinite));
        assert_eq!(parse(b"SET 1 2"), Err(Malformed::TooManyArguments("SET")));
        assert_eq!(parse(b"GET x"), Err(Malformed::TooManyArguments("GET")));
        assert_eq!(parse(b"\xff\xfe"), Err(Malformed::NotText));
        assert_eq!(parse(&[b'A'; 300]), Err(Malformed::TooLong(300)));
        assert!(matches!(parse(b"FOO"), Err(Malformed::UnknownCommand(_))));
    }

    #[test]
    fn error_text_never_reflects_control_bytes_or_long_input() {
        let e = parse(b"\x1b[2Jabcdefghijklmnopqrstuvwxyz0123456789").unwrap_err();
        let s = e.to_string();
        assert!(!s.contains('\x1b'), "{s}");
        assert!(s.contains("..."), "{s}");
        assert!(s.len() < 120, "{s}");
    }
}
