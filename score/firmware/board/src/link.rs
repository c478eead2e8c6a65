//! The `score_link` server: bytes from the host in, reply frames out.

use core::fmt::Write as _;

use conductor_protocols::score_link::{
    decode_request, ErrorCode, FrameScanner, Hello, LinkStats, Reply, Request, VarEntry, MAX_FRAME,
    MAX_TEXT, VERSION,
};
use score_core::hal::Hal;
use score_core::{Real, VarId, VarKind};

use crate::board::{Board, Extra};
use crate::out::{FrameOut, TextOut};
use crate::sampler::MAX_SUBSCRIPTIONS;

/// Terminal text one `Exec` may produce (longer output is cut and says so).
pub const EXEC_TEXT: usize = 3072;

/// Decodes requests from the byte stream and answers them.
pub struct LinkServer {
    scanner: FrameScanner<MAX_FRAME>,
}

impl Default for LinkServer {
    fn default() -> Self {
        Self::new()
    }
}

impl LinkServer {
    /// A fresh server.
    pub const fn new() -> Self {
        Self {
            scanner: FrameScanner::new(),
        }
    }

    /// Framing counters.
    pub fn stats(&self) -> &LinkStats {
        self.scanner.stats()
    }

    /// Forgets a partial frame (the host went away).
    pub fn reset(&mut self) {
        self.scanner.reset();
    }

    /// Feeds received bytes; every complete request is answered into `out`. Returns true if a
    /// request changed the table, a value or a subscription (the port wakes its update loop).
    pub fn feed<N: Real, H: Hal, const O: usize>(
        &mut self,
        bytes: &[u8],
        board: &mut Board<N, H>,
        now_us: u64,
        out: &mut FrameOut<O>,
        extra: Extra<'_>,
    ) -> bool {
        let mut woke = false;
        self.scanner.feed(bytes, |msg| {
            woke |= handle(msg, board, now_us, out, &mut *extra);
        });
        woke
    }
}

fn kind_name(k: VarKind) -> &'static str {
    match k {
        VarKind::Undefined => "Undefined",
        VarKind::Constant => "Constant",
        VarKind::Expression => "Expression",
        VarKind::Scale => "Scale",
        VarKind::Saturation => "Saturation",
        VarKind::Integral => "Integral",
        VarKind::AntiWindupIntegral => "AntiWindupIntegral",
        VarKind::Derivative => "Derivative",
        VarKind::LowPass => "LowPass",
        VarKind::Pid => "Pid",
        VarKind::AdcRaw => "AdcRaw",
        VarKind::AdcVolts => "AdcVolts",
        VarKind::Pwm => "Pwm",
        VarKind::PwmFollow => "PwmFollow",
        VarKind::GpioIn => "GpioIn",
        VarKind::GpioOut => "GpioOut",
        VarKind::Playback => "Playback",
        VarKind::Log => "Log",
    }
}

fn error<const O: usize>(out: &mut FrameOut<O>, seq: u16, code: ErrorCode, text: &str) {
    out.push(seq, &Reply::Error { code, text });
}

fn handle<N: Real, H: Hal, const O: usize>(
    msg: &[u8],
    board: &mut Board<N, H>,
    now_us: u64,
    out: &mut FrameOut<O>,
    extra: Extra<'_>,
) -> bool {
    let (seq, req) = match decode_request(msg) {
        Ok(r) => r,
        Err(e) => {
            let seq = msg
                .get(2..4)
                .map_or(0, |b| u16::from_le_bytes([b[0], b[1]]));
            let mut t = TextOut::<96>::new(false);
            let _ = write!(t, "{e}");
            error(out, seq, ErrorCode::BadRequest, t.as_str());
            return false;
        }
    };
    let generation = board.engine.generation();
    match req {
        Request::Hello => {
            out.push(
                seq,
                &Reply::Hello(Hello {
                    protocol: VERSION,
                    firmware: board.info.firmware,
                    board: board.info.board,
                    number_type: N::NAME,
                    generation,
                    t_us: now_us,
                    max_subscriptions: MAX_SUBSCRIPTIONS as u8,
                }),
            );
            false
        }
        Request::ListVars => {
            let total = board
                .engine
                .vars()
                .filter(|v| v.kind != VarKind::Undefined)
                .count() as u8;
            let mut index = 0u8;
            for v in board.engine.vars().filter(|v| v.kind != VarKind::Undefined) {
                out.push(
                    seq,
                    &Reply::Var(VarEntry {
                        generation,
                        index,
                        total,
                        id: v.id.0,
                        kind: kind_name(v.kind),
                        writable: v.writable,
                        rate_hz: v.rate_hz,
                        unit: v.unit.unwrap_or(""),
                        name: v.name,
                    }),
                );
                index += 1;
            }
            out.push(
                seq,
                &Reply::ListEnd {
                    generation,
                    count: index,
                },
            );
            false
        }
        Request::Subscribe {
            id,
            period_us,
            generation: g,
        } => {
            if g != generation {
                error(out, seq, ErrorCode::Stale, "the table changed: list again");
            } else if board.engine.info(VarId(id)).is_none() {
                error(
                    out,
                    seq,
                    ErrorCode::UnknownVariable,
                    "no variable in that slot",
                );
            } else if period_us == 0 {
                board.sampler.unsubscribe(VarId(id));
                out.push(seq, &Reply::Ack);
            } else if board
                .sampler
                .subscribe(VarId(id), period_us, generation, now_us)
                .is_err()
            {
                error(
                    out,
                    seq,
                    ErrorCode::TooManySubscriptions,
                    "no free subscription",
                );
            } else {
                out.push(seq, &Reply::Ack);
            }
            true
        }
        Request::UnsubscribeAll => {
            board.sampler.clear();
            out.push(seq, &Reply::Ack);
            true
        }
        Request::Set {
            id,
            value,
            generation: g,
        } => {
            let id = VarId(id);
            match board.engine.info(id) {
                _ if g != generation => {
                    error(out, seq, ErrorCode::Stale, "the table changed: list again")
                }
                None => error(
                    out,
                    seq,
                    ErrorCode::UnknownVariable,
                    "no variable in that slot",
                ),
                Some(i) if !i.writable => error(
                    out,
                    seq,
                    ErrorCode::NotWritable,
                    "the variable is read-only",
                ),
                Some(_) => match board.engine.set(id, N::from_f64(value), &mut board.hal) {
                    Ok(()) => {
                        let v = board.engine.value(id).map_or(f64::NAN, |v| v.to_f64());
                        out.push(seq, &Reply::SetDone { value: v });
                    }
                    Err(e) => {
                        let mut t = TextOut::<MAX_TEXT>::new(false);
                        let _ = write!(t, "{e}");
                        error(out, seq, ErrorCode::Refused, t.as_str());
                    }
                },
            }
            true
        }
        Request::Exec { line } => {
            let mut text = TextOut::<EXEC_TEXT>::new(false);
            let ok = board.run_line(line, now_us, &mut text, extra);
            let mut rest = text.as_str();
            while !rest.is_empty() {
                let mut cut = rest.len().min(MAX_TEXT);
                while !rest.is_char_boundary(cut) {
                    cut -= 1;
                }
                out.push(seq, &Reply::Output { text: &rest[..cut] });
                rest = &rest[cut..];
            }
            if text.truncated() {
                out.push(
                    seq,
                    &Reply::Output {
                        text: "\n(output cut)\n",
                    },
                );
            }
            out.push(
                seq,
                &Reply::ExecDone {
                    ok,
                    generation: board.engine.generation(),
                },
            );
            true
        }
        Request::Time => {
            out.push(seq, &Reply::Time { t_us: now_us });
            false
        }
    }
}
