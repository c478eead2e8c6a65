//! The host end of `score_link`: requests out, replies matched by sequence number, unsolicited
//! samples and table changes queued as [`Event`]s.

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::path::Path;
use std::time::{Duration, Instant};

use conductor_protocols::score_link::{
    decode_reply, encode_request, ErrorCode, FrameScanner, Reply, Request, MAX_FRAME,
};
use serialport::{SerialPort as _, TTYPort};

use crate::error::GatewayError;

/// How long a request may take (a board answers in a few ms; `save` of a full table in tens).
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(3);

/// A request that can be repeated without effect (all but `Exec`) and has no answer after this
/// long is sent again with the same sequence number: a frame damaged on the link (its CRC
/// fails, the receiver drops it) costs this instead of [`REPLY_TIMEOUT`] and a reconnection.
/// The board answers within a few ms; a duplicate `Set` writes the same value twice and its
/// late answer is ignored (its sequence number is no longer awaited).
pub const RESEND_AFTER: Duration = Duration::from_millis(20);

/// How long a read that finds nothing waits before the gateway's loop goes on: the pace of
/// an idle gateway (its watchdog and command checks run between reads).
pub const IDLE_WAIT: Duration = Duration::from_millis(1);

/// The same while an answer is awaited (a board answers within a fraction of a millisecond:
/// every command is one round trip).
pub const REPLY_WAIT: Duration = Duration::from_micros(50);

/// A variable as the board lists it.
#[derive(Debug, Clone, PartialEq)]
pub struct BoardVar {
    /// Slot.
    pub id: u8,
    /// Name.
    pub name: String,
    /// score-core's kind name.
    pub kind: String,
    /// Accepts `Set`.
    pub writable: bool,
    /// Update rate of a periodic variable.
    pub rate_hz: Option<f64>,
    /// Unit (empty when none).
    pub unit: String,
}

/// Unsolicited messages from the board.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// Samples taken at one board instant.
    Samples {
        /// Board µs.
        t_us: u64,
        /// Samples the board dropped so far.
        lost: u32,
        /// `(slot, value)`.
        values: Vec<(u8, f64)>,
    },
    /// The table changed.
    TableChanged(u32),
}

/// What a request produced.
#[derive(Debug, Clone, PartialEq)]
pub enum Answer {
    /// Hello: firmware, board, number type, generation, board µs.
    Hello {
        /// Firmware name/version.
        firmware: String,
        /// Board name.
        board: String,
        /// f32/f64.
        number_type: String,
        /// Table generation.
        generation: u32,
    },
    /// A listing and its generation.
    Vars(Vec<BoardVar>, u32),
    /// Ack.
    Ack,
    /// Set done: the value taken.
    Set(f64),
    /// Exec: the text, whether it succeeded, the generation after it.
    Exec(String, bool, u32),
    /// The board's clock.
    Time(u64),
}

/// The host end of one board's `score_link` serial port (a client of the board; not a
/// `conductor_devices` link).
pub struct BoardClient {
    port: TTYPort,
    scanner: FrameScanner<MAX_FRAME>,
    seq: u16,
    events: VecDeque<Event>,
}

impl BoardClient {
    /// Opens the serial device (a PTY works as well) and drops what is already buffered.
    pub fn open(path: &Path) -> Result<Self, GatewayError> {
        let port = serialport::new(path.to_string_lossy(), 115_200)
            .timeout(Duration::from_millis(5))
            .open_native()
            .map_err(|source| GatewayError::Open {
                path: path.to_path_buf(),
                source,
            })?;
        // Sequence numbers start somewhere new each time, so a late reply to a previous host
        // (or a previous connection) cannot be taken for an answer.
        let seed = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(1, |d| d.subsec_nanos() as u16);
        let mut l = Self {
            port,
            scanner: FrameScanner::new(),
            seq: seed,
            events: VecDeque::new(),
        };
        // Drop what is already buffered (bounded: a board may still be streaming samples).
        let end = Instant::now() + Duration::from_millis(50);
        let mut sink = [0u8; 1024];
        while Instant::now() < end && matches!(l.port.read(&mut sink), Ok(n) if n > 0) {}
        // A lone terminator ends whatever partial frame the board may hold from a previous host.
        l.port.write_all(&[0]).map_err(GatewayError::Io)?;
        Ok(l)
    }

    /// Next queued event, if any.
    pub fn next_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    /// Reads what the port has into the event queue (waiting [`IDLE_WAIT`] when it has
    /// nothing).
    pub fn poll(&mut self) -> Result<(), GatewayError> {
        self.read_into(IDLE_WAIT, &mut |_, _| false)
    }

    fn read_into(
        &mut self,
        idle: Duration,
        on_reply: &mut dyn FnMut(u16, &Reply<'_>) -> bool,
    ) -> Result<(), GatewayError> {
        // Ask first: a read (or poll) on a tty that finds nothing ready waits for the kernel's
        // receive worker, a normal-priority kworker that a busy machine can keep off the CPU
        // for hundreds of milliseconds, and the command watchdog would wait with it.
        match self.port.bytes_to_read() {
            Ok(0) => {
                std::thread::sleep(idle);
                return Ok(());
            }
            Ok(_) => {}
            Err(e) => return Err(GatewayError::Disconnected(Some(e.into()))),
        }
        let mut buf = [0u8; 4096];
        let n = match self.port.read(&mut buf) {
            Ok(0) => return Err(GatewayError::Disconnected(None)),
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => return Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => return Ok(()),
            Err(e) => return Err(GatewayError::Disconnected(Some(e))),
        };
        let events = &mut self.events;
        self.scanner.feed(&buf[..n], |m| match decode_reply(m) {
            Ok((0, Reply::Samples(b))) => events.push_back(Event::Samples {
                t_us: b.t_us,
                lost: b.lost,
                values: b.iter().collect(),
            }),
            Ok((0, Reply::TableChanged { generation })) => {
                events.push_back(Event::TableChanged(generation))
            }
            Ok((seq, r)) => {
                on_reply(seq, &r);
            }
            Err(_) => {}
        });
        Ok(())
    }

    /// Sends `req` and collects its answer.
    pub fn request(&mut self, req: Request<'_>) -> Result<Answer, GatewayError> {
        self.seq = self.seq.wrapping_add(1).max(1);
        let seq = self.seq;
        let mut frame = [0u8; MAX_FRAME];
        let n = encode_request(seq, &req, &mut frame)?;
        let repeatable = !matches!(req, Request::Exec { .. });
        let end = Instant::now() + REPLY_TIMEOUT;
        let mut vars = Vec::new();
        let mut text = String::new();
        let mut done: Option<Result<Answer, GatewayError>> = None;
        let mut sent: Option<Instant> = None;
        // A listing that ended with fewer entries than it announced lost one on the way.
        let mut short_list = false;
        while done.is_none() {
            if Instant::now() > end {
                return Err(GatewayError::Timeout(format!("{req:?}")));
            }
            let resend = repeatable && sent.is_some_and(|t| t.elapsed() >= RESEND_AFTER);
            if sent.is_none() || resend || short_list {
                vars.clear();
                short_list = false;
                self.port
                    .write_all(&frame[..n])
                    .and_then(|_| self.port.flush())
                    .map_err(|e| GatewayError::Disconnected(Some(e)))?;
                sent = Some(Instant::now());
            }
            self.read_into(REPLY_WAIT, &mut |s, r| {
                if s != seq {
                    return false;
                }
                done = match *r {
                    Reply::Hello(h) => Some(Ok(Answer::Hello {
                        firmware: h.firmware.into(),
                        board: h.board.into(),
                        number_type: h.number_type.into(),
                        generation: h.generation,
                    })),
                    Reply::Var(v) => {
                        vars.push(BoardVar {
                            id: v.id,
                            name: v.name.into(),
                            kind: v.kind.into(),
                            writable: v.writable,
                            rate_hz: v.rate_hz,
                            unit: v.unit.into(),
                        });
                        None
                    }
                    Reply::ListEnd { generation, count } if count as usize == vars.len() => {
                        Some(Ok(Answer::Vars(std::mem::take(&mut vars), generation)))
                    }
                    Reply::ListEnd { .. } => {
                        short_list = true;
                        None
                    }
                    Reply::Ack => Some(Ok(Answer::Ack)),
                    Reply::SetDone { value } => Some(Ok(Answer::Set(value))),
                    Reply::Output { text: t } => {
                        text.push_str(t);
                        None
                    }
                    Reply::ExecDone { ok, generation } => {
                        Some(Ok(Answer::Exec(std::mem::take(&mut text), ok, generation)))
                    }
                    Reply::Time { t_us } => Some(Ok(Answer::Time(t_us))),
                    Reply::Error { code, text } => Some(Err(GatewayError::Board {
                        stale: code == ErrorCode::Stale,
                        message: format!("{code:?}: {text}"),
                    })),
                    Reply::Samples(_) | Reply::TableChanged { .. } => None,
                };
                true
            })?;
        }
        done.expect("loop ends with an answer")
    }
}
