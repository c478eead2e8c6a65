//! SLCAN (LAWICEL) USB-CAN adapters — CANable, CANUSB, CAN232 and clones — spoken in user
//! space over any byte transport (a serial port, a pty, an in-memory pipe).
//!
//! Frames go out as `t…\r` lines; the adapter acknowledges each command with CR (or `z`/`Z`)
//! or BEL, interleaved with the frames it received from the bus. Acknowledgements are matched
//! to commands in order ([`PendingAcks`]); refused and unacknowledged frames are counted.
//!
//! * **Causality.** A frame the adapter reports before it acknowledged one of ours cannot be the
//!   answer to it: every received frame carries how many of our frames were still unacknowledged
//!   when its line arrived ([`Hardware::rx_unconfirmed`]), the fence the protocol stage matches
//!   replies with. A stalled adapter that catches up (ack k, reply k, ack k+1, reply k+1) is
//!   matched exactly.
//! * **Flow control.** At most 64 frames go unacknowledged; more wait in the link. An adapter
//!   that never acknowledges frames (some firmware does not) is detected after 8 acknowledgement
//!   timeouts without a single acknowledgement, counted, and from then on not waited for.
//! * **Urgent frames** (a safe action) are not held back by the window: [`Hardware::preempt`]
//!   drops the lines not yet written (a half-written line is finished first).
//! * **Timestamps** are accepted only if they were switched on (`Z1`, never sent here): a frame
//!   line with 4 extra digits is malformed, never a timestamp.

use std::time::{Duration, Instant};

use conductor_protocols::can::CanFrame;
use conductor_protocols::slcan::{
    open_sequence, Bitrate, Command, CommandKind, Dialect, HostScanner, PendingAcks, Response,
    MAX_FRAME_LINE,
};

use crate::component::{Hardware, HwCounters, HwError, TickCtx};
use crate::queue::Bounded;

/// How to talk to the adapter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlcanOptions {
    /// CAN bitrate (`Sn`).
    pub bitrate: Bitrate,
    /// Which SLCAN variant the adapter speaks (meaning of `S7`).
    pub dialect: Dialect,
    /// A frame not acknowledged within this time is counted as lost.
    pub ack_timeout: Duration,
    /// How long [`SlcanHardware::open`] waits for the adapter to answer the open sequence.
    pub open_timeout: Duration,
}

impl Default for SlcanOptions {
    fn default() -> Self {
        Self {
            bitrate: Bitrate::M1,
            dialect: Dialect::CANABLE,
            ack_timeout: Duration::from_millis(100),
            open_timeout: Duration::from_secs(2),
        }
    }
}

/// Counters of an SLCAN link.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SlcanStats {
    /// Frames handed to the adapter.
    pub frames_out: u64,
    /// Frames received from the bus.
    pub frames_in: u64,
    /// Commands the adapter refused (BEL).
    pub nacks: u64,
    /// Frames never acknowledged within the timeout.
    pub ack_timeouts: u64,
    /// Acknowledgements with no command waiting for them.
    pub stray_acks: u64,
    /// Bytes from the adapter that were not a valid line.
    pub discarded_bytes: u64,
    /// The adapter does not acknowledge frames: acknowledgements are no longer waited for.
    pub no_acks: bool,
}

/// Why the adapter could not be opened.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SlcanOpenError {
    /// The transport failed.
    #[error("transport: {0}")]
    Transport(#[from] HwError),
    /// The bitrate cannot be expressed in the dialect (`S7`).
    #[error("bitrate {0:?} has no Sn code in this SLCAN dialect")]
    Bitrate(Bitrate),
    /// The adapter did not acknowledge the open sequence in time.
    #[error("the adapter did not answer the open sequence (C, S, O) within {0:?}")]
    NoAnswer(Duration),
    /// The adapter refused to open the channel.
    #[error("the adapter refused to open the channel (BEL)")]
    Refused,
}

/// Most frames in flight (sent, not yet acknowledged).
const ACK_WINDOW: usize = 64;
/// Bytes read from the transport per call.
const RX_CHUNK: usize = 512;
/// Received frames buffered.
const RX_FRAMES: usize = 256;
/// Acknowledgement timeouts without any acknowledgement before the adapter counts as one that
/// does not acknowledge frames.
const NO_ACK_AFTER: u64 = 8;

/// An SLCAN adapter on byte transport `B`.
pub struct SlcanHardware<B: Hardware<Word = u8>> {
    port: B,
    opts: SlcanOptions,
    scanner: HostScanner<64>,
    acks: PendingAcks<ACK_WINDOW>,
    /// Encoded lines not yet accepted by the transport.
    tx: Bounded<u8>,
    /// Frames decoded but not yet handed out, with the number of our frames still
    /// unacknowledged when each arrived.
    rx: Bounded<CanFrame>,
    rx_behind: Bounded<u32>,
    /// The unacknowledged counts of the frames the last `receive` returned.
    out_behind: [u32; RX_FRAMES],
    out_n: usize,
    rx_chunk: [u8; RX_CHUNK],
    stats: SlcanStats,
    acks_seen: u64,
    /// Bytes of the first line in `tx` already written (a half-sent line).
    head_written: usize,
    /// The next frames bypass the acknowledgement window (a safe action).
    urgent: bool,
    t0: Instant,
}

impl<B: Hardware<Word = u8>> SlcanHardware<B> {
    /// Sends the open sequence (`C`, `Sn`, `O`) and waits, blocking up to
    /// `opts.open_timeout`, for the adapter's three answers (the first, closing a closed
    /// channel, may be a BEL). Call at start-up, not on the real-time thread.
    pub fn open(mut port: B, opts: SlcanOptions) -> Result<Self, SlcanOpenError> {
        let mut seq = [0u8; 16];
        let n = open_sequence(opts.bitrate, false, &opts.dialect, &mut seq)
            .map_err(|_| SlcanOpenError::Bitrate(opts.bitrate))?;
        let t0 = Instant::now();
        let ctx = TickCtx { tick: 0, now_ns: 0 };
        let mut sent = 0;
        let mut scanner = HostScanner::<64>::new();
        let mut answers = [None::<bool>; 3];
        let mut got = 0;
        let mut buf = [0u8; 256];
        let mut rx = Bounded::with_capacity(256);
        while got < 3 {
            if t0.elapsed() > opts.open_timeout {
                return Err(SlcanOpenError::NoAnswer(opts.open_timeout));
            }
            if sent < n {
                sent += port.transmit(&seq[sent..n], ctx)?;
            }
            let k = port.receive(&mut buf, ctx)?;
            scanner.feed(&buf[..k], |r| match r {
                Response::Ok | Response::TxAck { .. } if got < 3 => {
                    answers[got] = Some(true);
                    got += 1;
                }
                Response::Error if got < 3 => {
                    answers[got] = Some(false);
                    got += 1;
                }
                Response::Frame { frame, .. } => {
                    let _ = rx.push(frame);
                }
                _ => {}
            });
            if k == 0 {
                std::thread::sleep(Duration::from_millis(1));
            }
        }
        // The answer to `O` decides; `C` on a closed channel may legitimately be refused.
        if answers[2] != Some(true) {
            return Err(SlcanOpenError::Refused);
        }
        let mut hw = Self {
            port,
            opts,
            scanner,
            acks: PendingAcks::new(),
            tx: Bounded::with_capacity(2 * ACK_WINDOW * MAX_FRAME_LINE),
            rx: Bounded::with_capacity(RX_FRAMES),
            rx_behind: Bounded::with_capacity(RX_FRAMES),
            out_behind: [0; RX_FRAMES],
            out_n: 0,
            rx_chunk: [0; RX_CHUNK],
            stats: SlcanStats::default(),
            acks_seen: 0,
            head_written: 0,
            urgent: false,
            t0,
        };
        for f in rx.as_slice() {
            let _ = hw.rx.push(*f);
            let _ = hw.rx_behind.push(0);
        }
        Ok(hw)
    }

    /// Counters since opening.
    pub fn stats(&self) -> SlcanStats {
        SlcanStats {
            discarded_bytes: self.scanner.stats().discarded_bytes(),
            ..self.stats
        }
    }

    /// The underlying transport.
    pub fn port(&self) -> &B {
        &self.port
    }

    fn now_us(&self) -> u32 {
        // Wrapping microseconds: ack ages are compared with wrapping arithmetic.
        self.t0.elapsed().as_micros() as u32
    }

    fn flush_tx(&mut self, ctx: TickCtx) -> Result<(), HwError> {
        if !self.tx.is_empty() {
            let n = self.port.transmit(self.tx.as_slice(), ctx)?;
            // Where the (new) head line starts: after the last CR written.
            match self.tx.as_slice()[..n].iter().rposition(|&b| b == CR) {
                Some(i) => self.head_written = n - i - 1,
                None => self.head_written += n,
            }
            self.tx.consume(n);
        }
        Ok(())
    }

    fn expire_acks(&mut self) {
        let now = self.now_us();
        let limit = self.opts.ack_timeout.as_micros() as u32;
        while let Some((_, sent)) = self.acks.front() {
            if now.wrapping_sub(sent) <= limit {
                break;
            }
            self.acks.pop();
            self.stats.ack_timeouts += 1;
        }
        if !self.stats.no_acks && self.acks_seen == 0 && self.stats.ack_timeouts >= NO_ACK_AFTER {
            self.stats.no_acks = true;
            self.acks.clear();
        }
    }

    /// Whether the adapter does not acknowledge frames (detected, see the module docs).
    pub fn no_acks(&self) -> bool {
        self.stats.no_acks
    }
}

const CR: u8 = b'\r';

impl<B: Hardware<Word = u8>> Hardware for SlcanHardware<B> {
    type Word = CanFrame;

    fn transmit(&mut self, words: &[CanFrame], ctx: TickCtx) -> Result<usize, HwError> {
        self.expire_acks();
        let now = self.now_us();
        let mut line = [0u8; MAX_FRAME_LINE];
        let mut accepted = 0;
        for f in words {
            let Ok(n) = Command::Transmit(*f).encode(&self.opts.dialect, &mut line) else {
                break;
            };
            let window_full = self.acks.len() == ACK_WINDOW && !self.urgent;
            if self.tx.remaining() < n || window_full {
                break;
            }
            self.tx.extend_from_slice(&line[..n]);
            if !self.stats.no_acks && self.acks.push(CommandKind::Transmit, now).is_err() {
                // Past the window (urgent): its acknowledgement cannot be tracked; the oldest
                // expectation goes instead, so the later ones stay in order.
                self.acks.pop();
                let _ = self.acks.push(CommandKind::Transmit, now);
            }
            accepted += 1;
        }
        self.urgent = false;
        self.stats.frames_out += accepted as u64;
        self.flush_tx(ctx)?;
        Ok(accepted)
    }

    fn receive(&mut self, out: &mut [CanFrame], ctx: TickCtx) -> Result<usize, HwError> {
        self.flush_tx(ctx)?;
        loop {
            let k = self.port.receive(&mut self.rx_chunk, ctx)?;
            if k == 0 {
                break;
            }
            let Self {
                scanner,
                acks,
                rx,
                rx_behind,
                stats,
                rx_chunk,
                acks_seen,
                ..
            } = self;
            scanner.feed(&rx_chunk[..k], |r| match r {
                Response::Frame { frame, .. } => {
                    stats.frames_in += 1;
                    if rx.push(frame).is_ok() {
                        let _ = rx_behind.push(acks.len() as u32);
                    }
                }
                other => match acks.resolve(&other) {
                    Some(a) => {
                        *acks_seen += 1;
                        if !a.ok {
                            stats.nacks += 1;
                        }
                    }
                    None if matches!(
                        other,
                        Response::Ok | Response::Error | Response::TxAck { .. }
                    ) =>
                    {
                        stats.stray_acks += 1
                    }
                    None => {}
                },
            });
            if k < RX_CHUNK {
                break;
            }
        }
        self.expire_acks();
        let n = self.rx.pop_into(out);
        self.out_n = self.rx_behind.pop_into(&mut self.out_behind[..n]);
        Ok(n)
    }

    fn rx_unconfirmed(&self) -> &[u32] {
        &self.out_behind[..self.out_n]
    }

    fn preempt(&mut self) {
        // Keep the rest of a half-written line (the adapter would misparse the next one).
        let keep = if self.head_written > 0 {
            self.tx
                .as_slice()
                .iter()
                .position(|&b| b == CR)
                .map_or(self.tx.len(), |i| i + 1)
        } else {
            0
        };
        let dropped = self.tx.as_slice()[keep..]
            .iter()
            .filter(|&&b| b == CR)
            .count();
        for _ in 0..dropped {
            // Their acknowledgements will never come.
            self.acks.pop_back();
        }
        let n = self.tx.len() - keep;
        for _ in 0..n {
            self.tx.pop_back();
        }
        self.urgent = true;
    }

    fn flushed(&self) -> bool {
        self.tx.is_empty() && (self.acks.is_empty() || self.stats.no_acks)
    }

    fn counters(&self) -> HwCounters {
        HwCounters {
            nacks: self.stats.nacks,
            ack_timeouts: self.stats.ack_timeouts,
            error_frames: 0,
            tx_full: 0,
            discarded: self.scanner.stats().discarded_bytes(),
        }
    }

    fn shutdown(&mut self) {
        let ctx = TickCtx { tick: 0, now_ns: 0 };
        // Everything queued goes out and is acknowledged first (bounded), then the channel
        // closes: closing with frames still queued would drop them.
        let until = Instant::now() + Duration::from_millis(200);
        let mut sink = [CanFrame::standard(0, &[]).expect("an empty frame"); 16];
        while !self.flushed() && Instant::now() < until {
            if self.flush_tx(ctx).is_err() || self.receive(&mut sink, ctx).is_err() {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        let mut close = [0u8; 4];
        if let Ok(n) = Command::Close.encode(&self.opts.dialect, &mut close) {
            let _ = self.port.transmit(&close[..n], ctx);
        }
        self.port.shutdown();
    }
}

use crate::hw::{SerialHardware, SerialOptions};
use crate::kinds::{
    Build, BuildError, Capacity, HardwareBuild, Invalid, KindSpec, OpenError, OpenedHardware,
    ParamSpec, Params,
};

/// The SLCAN variant an adapter speaks, as the manifest names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SlcanDialect {
    /// CANable firmware: CR acknowledges a frame, `S7` is 750 kbit/s.
    Canable,
    /// LAWICEL CANUSB: `z` acknowledges a frame, `S7` is 800 kbit/s.
    Lawicel,
}

crate::choices!(SlcanDialect { Canable = "canable", Lawicel = "lawicel" });

impl SlcanDialect {
    /// The codec's description of this variant.
    pub fn dialect(self) -> Dialect {
        match self {
            SlcanDialect::Canable => Dialect::CANABLE,
            SlcanDialect::Lawicel => Dialect::LAWICEL,
        }
    }
}

/// The `slcan` hardware kind.
pub const KIND: KindSpec = KindSpec {
    kind: "slcan",
    params: &[
        ParamSpec::text(
            "port",
            None,
            "serial device of the USB-CAN adapter, e.g. /dev/ttyACM0",
        ),
        ParamSpec::int(
            "baud",
            Some(115_200),
            1200.0,
            12_000_000.0,
            "serial line speed (ignored by USB CDC adapters)",
        ),
        ParamSpec::int(
            "bitrate",
            Some(1_000_000),
            10_000.0,
            1_000_000.0,
            "CAN bitrate (a standard Sn rate)",
        ),
        ParamSpec::choice::<SlcanDialect>(
            "dialect",
            "canable",
            "SLCAN variant: canable (CR acks, S7 = 750k) or lawicel (z acks, S7 = 800k)",
        ),
    ],
    doc: "An SLCAN (LAWICEL) USB-CAN adapter (CANable, CANUSB, ...) spoken in user space over \
          its serial port: no kernel CAN support needed.",
    build: Build::Hardware {
        resource: Some("port"),
        open: HardwareBuild::Can(open_kind),
    },
};

fn open_kind(p: &Params, _: Capacity) -> Result<OpenedHardware<CanFrame>, BuildError> {
    let port = p.str("port")?;
    let bps = p.int("bitrate")?;
    let bitrate = u32::try_from(bps)
        .ok()
        .and_then(Bitrate::from_bps)
        .ok_or(BuildError::invalid("bitrate", Invalid::Bitrate(bps)))?;
    let opts = SlcanOptions {
        bitrate,
        dialect: p.choice::<SlcanDialect>("dialect")?.dialect(),
        ..SlcanOptions::default()
    };
    let serial = SerialOptions {
        baud: crate::kinds::baud(p)?,
        low_latency: true,
        exclusive: true,
    };
    let baud = serial.baud;
    let open = move |port: &str| -> Result<SlcanHardware<SerialHardware>, OpenError> {
        Ok(SlcanHardware::open(
            SerialHardware::open(port, &serial)?,
            opts,
        )?)
    };
    let hw = open(port).map_err(|e| BuildError::open(port, e))?;
    Ok(OpenedHardware::new(hw)
        .at_baud(baud)
        .reopening_node(port, open))
}
