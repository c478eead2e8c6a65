//! The three communication stages (thesis §2.4) as traits, and [`Link`], the pairing of a
//! protocol with the hardware it runs on.
//!
//! The executor calls every method here on its real-time thread: implementations must not
//! block, allocate or lock. Buffers are sized when a component is built.

use crate::message::{Credential, Reply, Request, Update};
use crate::queue::Bounded;

/// Timing of the current call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TickCtx {
    /// Executor base tick.
    pub tick: u64,
    /// CLOCK_MONOTONIC now, ns.
    pub now_ns: u64,
}

/// Errors a hardware transport reports; each is counted as a bus error by the executor.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum HwError {
    /// The OS refused the I/O (errno text).
    #[error("I/O error: {0}")]
    Io(String),
    /// The transmit side is full: words were not sent this tick.
    #[error("transmit buffer full ({dropped} words not sent)")]
    TxFull {
        /// Words that did not go out.
        dropped: usize,
    },
    /// The device vanished (unplugged adapter, closed pty).
    #[error("device disconnected")]
    Disconnected,
}

/// Gatekeeper to a physical (or simulated) bus: moves words, never interprets them.
///
/// `Word` is the bus's unit: `u8` for UARTs, a CAN frame for CAN, a simulation record for the
/// built-in simulated hardware.
pub trait Hardware {
    /// Unit of transfer.
    type Word: Copy;
    /// Queues `words` for the bus without blocking; returns how many were accepted.
    fn transmit(&mut self, words: &[Self::Word], ctx: TickCtx) -> Result<usize, HwError>;
    /// Copies whatever the bus has delivered (up to `out.len()`) without blocking.
    fn receive(&mut self, out: &mut [Self::Word], ctx: TickCtx) -> Result<usize, HwError>;
    /// Puts the bus in a quiet state on shutdown (flush, close).
    fn shutdown(&mut self) {}
}

/// Counters a protocol keeps about its bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ProtocolCounters {
    /// Packets (or frames) sent.
    pub packets_out: u64,
    /// Words sent.
    pub words_out: u64,
    /// Valid packets received.
    pub packets_in: u64,
    /// Words received.
    pub words_in: u64,
    /// Words discarded by the scanner (garbage, bad CRC, truncated, ...).
    pub discarded_words: u64,
    /// Packets rejected (bad CRC, bad header, truncated, ...).
    pub rejected_packets: u64,
    /// Requests that got no valid reply before their deadline.
    pub missing_replies: u64,
    /// Replies from devices reporting an error.
    pub device_errors: u64,
    /// Requests that could not be encoded (e.g. more than fit in a packet this tick).
    pub dropped_requests: u64,
}

impl ProtocolCounters {
    /// What the executor reports as bus errors: rejected packets, missing replies and requests
    /// that could not be sent. (Discarded words are reported separately: one corrupted packet
    /// discards many.)
    pub fn bus_errors(&self) -> u64 {
        self.rejected_packets + self.missing_replies + self.dropped_requests
    }
}

/// A vendor's packet format: bundles requests into the fewest packets, and scans received words
/// back into typed replies.
pub trait Protocol {
    /// Unit of transfer; must match the hardware's.
    type Word: Copy;
    /// Every request queued since the last protocol tick, in order. Encode them into as few
    /// packets as the protocol allows (one SYNC WRITE for all goal writes, ...), appending the
    /// words to `out`.
    fn encode(&mut self, requests: &[Request], out: &mut Bounded<Self::Word>, ctx: TickCtx);
    /// Words the hardware received since the last protocol tick; decode into replies.
    fn decode(&mut self, words: &[Self::Word], out: &mut Bounded<Reply>, ctx: TickCtx);
    /// Called after `decode` each protocol tick: report requests whose replies are overdue as
    /// [`crate::ReplyData::Missing`] (never invent a value).
    fn expire(&mut self, out: &mut Bounded<Reply>, ctx: TickCtx);
    /// Counters since start.
    fn counters(&self) -> ProtocolCounters;
}

/// One physical quantity a device offers (a state attaches to one channel).
#[derive(Debug, Clone, PartialEq)]
pub struct Channel {
    /// Name used in the manifest (`position`, `current`, ...).
    pub name: &'static str,
    /// Physical units of the device-side value (before calibration).
    pub units: &'static str,
    /// Whether the channel can be sampled.
    pub readable: bool,
    /// Whether the channel accepts setpoints.
    pub writable: bool,
}

impl Channel {
    /// A channel that is sampled and accepts setpoints.
    pub const fn read_write(name: &'static str, units: &'static str) -> Self {
        Self::new(name, units, true, true)
    }

    /// A channel that is only sampled.
    pub const fn read_only(name: &'static str, units: &'static str) -> Self {
        Self::new(name, units, true, false)
    }

    /// A channel that only accepts setpoints.
    pub const fn write_only(name: &'static str, units: &'static str) -> Self {
        Self::new(name, units, false, true)
    }

    const fn new(name: &'static str, units: &'static str, readable: bool, writable: bool) -> Self {
        Self {
            name,
            units,
            readable,
            writable,
        }
    }
}

/// What a device does when commands stop (watchdog) or the executor shuts down.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SafeAction {
    /// Keep the current position (write present position as the goal).
    Hold,
    /// Disable torque / exit motor mode.
    TorqueOff,
    /// Command `value` (device units) on `channel`.
    Setpoint {
        /// Channel index.
        channel: usize,
        /// Value in device units.
        value: f64,
    },
}

/// A node on a bus: tags requests with its credential, and interprets replies that carry it.
pub trait Device {
    /// The device's address on its bus.
    fn credential(&self) -> Credential;
    /// The quantities it offers.
    fn channels(&self) -> &[Channel];
    /// Queues the request(s) that sample `channel`.
    fn sample(&mut self, channel: usize, ctx: TickCtx, out: &mut Bounded<Request>);
    /// Records a setpoint (device units) for `channel`; the request goes out at [`flush`](Self::flush).
    fn write(&mut self, channel: usize, value: f64, ctx: TickCtx);
    /// Called once per device tick after `sample`/`write`: emits the write requests (a device
    /// may combine several channels into one request, as MIT-mode motors do).
    fn flush(&mut self, ctx: TickCtx, out: &mut Bounded<Request>);
    /// Interprets a reply addressed to this device, pushing channel updates.
    fn reply(&mut self, reply: &Reply, out: &mut Bounded<Update>);
    /// Queues the requests that carry out `action`.
    fn safe(&mut self, action: SafeAction, ctx: TickCtx, out: &mut Bounded<Request>);
}

/// A protocol bound to its hardware, with the queues between them: what the executor schedules.
pub trait Link {
    /// Protocol tick, downstream: bundle the queued requests into words for the hardware.
    fn encode(&mut self, requests: &[Request], ctx: TickCtx);
    /// Hardware tick: send pending words, collect received ones.
    fn exchange(&mut self, ctx: TickCtx) -> Result<(), HwError>;
    /// Protocol tick, upstream: decode received words and expire overdue requests.
    fn decode(&mut self, out: &mut Bounded<Reply>, ctx: TickCtx);
    /// Protocol counters.
    fn counters(&self) -> ProtocolCounters;
    /// Quiets the hardware.
    fn shutdown(&mut self);
}

/// [`Link`] over any protocol/hardware pair that share a word type.
pub struct LinkOf<P: Protocol, H: Hardware<Word = P::Word>> {
    protocol: P,
    hardware: H,
    tx: Bounded<P::Word>,
    rx: Bounded<P::Word>,
    rx_buf: Vec<P::Word>,
}

impl<P: Protocol, H: Hardware<Word = P::Word>> LinkOf<P, H>
where
    P::Word: Default,
{
    /// Binds `protocol` to `hardware` with room for `words` words each way per tick.
    pub fn new(protocol: P, hardware: H, words: usize) -> Self {
        Self::with_fill(protocol, hardware, words, P::Word::default())
    }
}

impl<P: Protocol, H: Hardware<Word = P::Word>> LinkOf<P, H> {
    /// As [`new`](Self::new), for word types without a `Default` (CAN frames): `fill`
    /// initialises the receive buffer.
    pub fn with_fill(protocol: P, hardware: H, words: usize, fill: P::Word) -> Self {
        Self {
            protocol,
            hardware,
            tx: Bounded::with_capacity(words),
            rx: Bounded::with_capacity(words),
            rx_buf: vec![fill; words],
        }
    }

    /// The protocol (for tests and diagnostics).
    pub fn protocol(&self) -> &P {
        &self.protocol
    }

    /// The hardware (for tests and diagnostics).
    pub fn hardware(&self) -> &H {
        &self.hardware
    }
}

impl<P: Protocol, H: Hardware<Word = P::Word>> Link for LinkOf<P, H> {
    fn encode(&mut self, requests: &[Request], ctx: TickCtx) {
        self.protocol.encode(requests, &mut self.tx, ctx);
    }

    fn exchange(&mut self, ctx: TickCtx) -> Result<(), HwError> {
        let mut result = Ok(());
        if !self.tx.is_empty() {
            match self.hardware.transmit(self.tx.as_slice(), ctx) {
                Ok(n) => self.tx.consume(n),
                Err(e) => {
                    self.tx.clear();
                    result = Err(e);
                }
            }
        }
        let room = self.rx.remaining().min(self.rx_buf.len());
        if room > 0 {
            match self.hardware.receive(&mut self.rx_buf[..room], ctx) {
                Ok(n) => {
                    self.rx.extend_from_slice(&self.rx_buf[..n]);
                }
                Err(e) => result = result.and(Err(e)),
            }
        }
        result
    }

    fn decode(&mut self, out: &mut Bounded<Reply>, ctx: TickCtx) {
        self.protocol.decode(self.rx.as_slice(), out, ctx);
        self.rx.clear();
        self.protocol.expire(out, ctx);
    }

    fn counters(&self) -> ProtocolCounters {
        self.protocol.counters()
    }

    fn shutdown(&mut self) {
        self.hardware.shutdown();
    }
}
