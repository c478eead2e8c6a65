//! Host → adapter commands.

use super::{parse_frame, parse_hex, put_frame, put_hex, Bitrate, Dialect, SlcanError, CR};
use crate::can::CanFrame;
use crate::writer::Writer;

/// A host command. [`encode`](Command::encode) is the host side, [`decode`](Command::decode)
/// the adapter (simulator) side.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// `O`: open the channel in normal mode.
    Open,
    /// `L`: open in listen-only mode.
    ListenOnly,
    /// `C`: close the channel.
    Close,
    /// `Sn`: standard bitrate (only while closed).
    Bitrate(Bitrate),
    /// `sxxyy`: SJA1000 BTR0/BTR1 timing.
    Btr {
        /// BTR0.
        btr0: u8,
        /// BTR1.
        btr1: u8,
    },
    /// `t`/`T`/`r`/`R`: transmit a frame.
    Transmit(CanFrame),
    /// `F`: read status flags.
    ReadStatus,
    /// `V`: version.
    Version,
    /// `N`: serial number.
    SerialNumber,
    /// `Zn`: received-frame timestamps off/on.
    Timestamps(bool),
    /// `Mxxxxxxxx`: SJA1000 acceptance code (LAWICEL; CANable uses `M`/`m` for other things).
    AcceptanceCode(u32),
    /// `mxxxxxxxx`: SJA1000 acceptance mask (LAWICEL).
    AcceptanceMask(u32),
}

impl Command {
    /// Writes the command and its CR into `buf`; returns the length.
    pub fn encode(&self, dialect: &Dialect, buf: &mut [u8]) -> Result<usize, SlcanError> {
        let mut w = Writer::new(buf);
        match *self {
            Command::Open => w.put(b'O')?,
            Command::ListenOnly => w.put(b'L')?,
            Command::Close => w.put(b'C')?,
            Command::Bitrate(b) => {
                let code = b.code(dialect).ok_or(SlcanError::Bitrate)?;
                w.put_all(&[b'S', b'0' + code])?;
            }
            Command::Btr { btr0, btr1 } => {
                w.put(b's')?;
                put_hex(&mut w, u32::from(btr0) << 8 | u32::from(btr1), 4)?;
            }
            Command::Transmit(ref f) => put_frame(&mut w, f, None)?,
            Command::ReadStatus => w.put(b'F')?,
            Command::Version => w.put(b'V')?,
            Command::SerialNumber => w.put(b'N')?,
            Command::Timestamps(on) => w.put_all(&[b'Z', if on { b'1' } else { b'0' }])?,
            Command::AcceptanceCode(v) => {
                w.put(b'M')?;
                put_hex(&mut w, v, 8)?;
            }
            Command::AcceptanceMask(v) => {
                w.put(b'm')?;
                put_hex(&mut w, v, 8)?;
            }
        }
        w.put(CR)?;
        Ok(w.pos())
    }

    /// Parses one command line (without its CR), as an adapter does.
    pub fn decode(line: &[u8], dialect: &Dialect) -> Result<Self, SlcanError> {
        let (&c, rest) = line.split_first().ok_or(SlcanError::Unknown(CR))?;
        let bare = |cmd: Command| {
            if rest.is_empty() {
                Ok(cmd)
            } else {
                Err(SlcanError::Length)
            }
        };
        match c {
            b'O' => bare(Command::Open),
            b'L' => bare(Command::ListenOnly),
            b'C' => bare(Command::Close),
            b'F' => bare(Command::ReadStatus),
            b'V' | b'v' => bare(Command::Version),
            b'N' => bare(Command::SerialNumber),
            b'S' => match rest {
                [d @ b'0'..=b'9'] => Bitrate::from_code(d - b'0', dialect)
                    .map(Command::Bitrate)
                    .ok_or(SlcanError::Bitrate),
                [_] => Err(SlcanError::Bitrate),
                _ => Err(SlcanError::Length),
            },
            b's' => match rest.len() {
                4 => {
                    let v = parse_hex(rest)?;
                    Ok(Command::Btr {
                        btr0: (v >> 8) as u8,
                        btr1: v as u8,
                    })
                }
                _ => Err(SlcanError::Length),
            },
            b'Z' => match rest {
                [b'0'] => Ok(Command::Timestamps(false)),
                [b'1'] => Ok(Command::Timestamps(true)),
                _ => Err(SlcanError::Length),
            },
            b'M' | b'm' => {
                if rest.len() != 8 {
                    return Err(SlcanError::Length);
                }
                let v = parse_hex(rest)?;
                Ok(if c == b'M' {
                    Command::AcceptanceCode(v)
                } else {
                    Command::AcceptanceMask(v)
                })
            }
            b't' | b'T' | b'r' | b'R' => Ok(Command::Transmit(parse_frame(line, false)?.0)),
            other => Err(SlcanError::Unknown(other)),
        }
    }
}

/// The usual open sequence `C\r Sn\r O\r` (or `L\r` for listen-only), as the Linux driver and
/// python-can send it. Expect three acknowledgements; the first (closing an already closed
/// channel) may be a BEL on some adapters and is harmless.
pub fn open_sequence(
    bitrate: Bitrate,
    listen_only: bool,
    dialect: &Dialect,
    buf: &mut [u8],
) -> Result<usize, SlcanError> {
    let mut n = Command::Close.encode(dialect, buf)?;
    n += Command::Bitrate(bitrate)
        .encode(dialect, buf.get_mut(n..).ok_or(SlcanError::BufferTooSmall)?)?;
    let open = if listen_only {
        Command::ListenOnly
    } else {
        Command::Open
    };
    n += open.encode(dialect, buf.get_mut(n..).ok_or(SlcanError::BufferTooSmall)?)?;
    Ok(n)
}
